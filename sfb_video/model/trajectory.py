"""A continuous 6-DoF trajectory through a window of frames: where the object is between and
within exposures, for the joint fit of several frames (:mod:`sfb_video.fitting.window`).

Convention:
    Time t is in frame intervals from the start of the window's first exposure: frame k of a
    window that starts at frame k0 is exposed over t in [k - k0, k - k0 + e], e the exposure
    fraction, and exposure time tau in [0, 1] maps to t = k - k0 + tau * e (as the synthetic
    generator's clip time does).

    Translation is piecewise polynomial: piece p spans [b_p, b_p+1] and interpolates its
    ``degree`` + 1 anchors, evenly spaced in time, Lagrange-fashion; neighbouring pieces share
    the anchor at their break, so the path is continuous and its velocity may jump there (a
    bounce). Degree 1 is constant velocity, degree 2 constant acceleration (gravity).

    Rotation is a constant spin about the centre of mass: R(t) = exp(t * spin) @ R0, spin an
    axis-angle per frame interval; the rotation made during one exposure is e * spin.

    Frame k's exposure as the single-frame :class:`Motion` is the chord: x0 = x(t), dx =
    x(t + e) - x(t), R0 = R(t), omega = e * spin (exact for constant velocity; with gravity
    the path bends by |a| e^2 / 8 within an exposure, a small fraction of a pixel here).

Anchors are parametrised in the image, like the single-frame motion: (u, v) in units of a
reference apparent diameter ``ref_px`` from the frame's principal point, and log of the
apparent diameter over ``ref_px`` (which sets depth, the object being one unit across), so
that one Adam step moves an anchor by a similar number of pixels at any depth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.rotation import (
    axis_angle_to_matrix,
    axis_angle_to_quaternion,
    matrix_to_axis_angle,
    quaternion_to_matrix,
)
from sfb_video.model.motion import Motion, cap_rotation

MOTION_MODELS = {"constant_velocity": (1, 1), "constant_acceleration": (2, 1), "bounce": (2, 2)}
"""Name -> (degree of each piece, number of pieces)."""


def anchor_times(breaks: torch.Tensor, degree: int) -> torch.Tensor:
    """(P * degree + 1,) times of the anchors of pieces split at ``breaks`` (P + 1,)."""
    steps = torch.arange(degree, dtype=breaks.dtype, device=breaks.device) / degree
    inner = breaks[:-1, None] + steps * (breaks[1:] - breaks[:-1])[:, None]
    return torch.cat((inner.reshape(-1), breaks[-1:]))


def interpolate(anchors: torch.Tensor, breaks: torch.Tensor, degree: int, t: torch.Tensor) -> torch.Tensor:
    """(T, 3) positions at times ``t`` (T,) on the path through ``anchors`` (P * degree + 1, 3).

    Each time uses the piece it falls in (times outside the window extend the first or last).
    """
    pieces = breaks.shape[0] - 1
    piece = (torch.bucketize(t.detach(), breaks[1:-1], right=True) if pieces > 1 else torch.zeros_like(t)).long()
    start, end = breaks[piece], breaks[piece + 1]
    s = (t - start) / (end - start) * degree  # position within the piece, in anchor steps
    out = torch.zeros(t.shape[0], 3, dtype=anchors.dtype, device=anchors.device)
    for k in range(degree + 1):
        weight = torch.ones_like(s)
        for j in range(degree + 1):
            if j != k:
                weight = weight * (s - j) / (k - j)
        out = out + weight[:, None] * anchors[piece * degree + k]
    return out


@dataclass(frozen=True)
class Trajectory:
    """A recovered trajectory, detached from any optimiser (see the module docstring).

    Attributes:
        first_frame: the frame index at t = 0.
        breaks: (P + 1,) the times that delimit the pieces (the first and last bound the window).
        anchors: (P * degree + 1, 3) camera-space anchor positions, object sizes.
        degree: 1 or 2.
        rot0: (3, 3) rotation at t = 0.
        spin: (3,) axis-angle per frame interval.
        exposure_fraction: e.
        model: the motion model's name (a key of :data:`MOTION_MODELS`).
    """

    first_frame: int
    breaks: torch.Tensor
    anchors: torch.Tensor
    degree: int
    rot0: torch.Tensor
    spin: torch.Tensor
    exposure_fraction: float
    model: str

    def time(self, frame: int, tau: float = 0.0) -> float:
        """The window time of exposure time ``tau`` of frame ``frame``."""
        return frame - self.first_frame + tau * self.exposure_fraction

    def positions(self, t: torch.Tensor) -> torch.Tensor:
        """(T, 3) centre of mass at window times ``t`` (T,)."""
        return interpolate(self.anchors, self.breaks, self.degree, t.to(self.anchors))

    def rotations(self, t: torch.Tensor) -> torch.Tensor:
        """(T, 3, 3) rotations at window times ``t`` (T,)."""
        return axis_angle_to_matrix(t.to(self.spin)[:, None] * self.spin) @ self.rot0

    def frame_motion(self, frame: int) -> Motion:
        """The exposure of frame ``frame`` as a single-frame motion (its chord)."""
        t = torch.tensor([self.time(frame), self.time(frame, 1.0)], dtype=self.anchors.dtype)
        ends = self.positions(t)
        return Motion(ends[0], ends[1] - ends[0], self.rotations(t[:1])[0], self.exposure_fraction * self.spin)

    def speed(self, t: torch.Tensor) -> torch.Tensor:
        """(T,) speed in object sizes per frame interval at window times ``t``, by central differences."""
        h = 1e-3
        return (self.positions(t + h) - self.positions(t - h)).norm(dim=-1) / (2 * h)


class TrajectoryParams(torch.nn.Module):
    """Learnable trajectory through a window of frames (see the module docstring).

    Args:
        camera: the clip's full-frame camera.
        breaks: (P + 1,) the pieces' time bounds.
        degree: 1 or 2.
        ref_px: the apparent diameter the anchors are measured in.
        exposure_fraction: e at the start.
        learn_exposure: whether e is learnt.
        max_rotation_deg: cap on the rotation per frame interval.
    """

    def __init__(
        self,
        camera: PinholeCamera,
        breaks: torch.Tensor,
        degree: int,
        ref_px: float,
        exposure_fraction: float,
        learn_exposure: bool,
        max_rotation_deg: float,
    ) -> None:
        super().__init__()
        self.camera, self.degree, self.ref_px = camera, degree, ref_px
        self.register_buffer("breaks", breaks.float().clone())
        self.register_buffer("times", anchor_times(self.breaks, degree))
        self.anchors_raw = torch.nn.Parameter(torch.zeros(self.times.shape[0], 3))
        self.quat0 = torch.nn.Parameter(torch.tensor([1.0, 0.0, 0.0, 0.0]))
        self.max_angle = math.radians(max_rotation_deg)
        self.spin_raw = torch.nn.Parameter(torch.zeros(3), requires_grad=self.max_angle > 0)
        e = min(max(exposure_fraction, 0.02), 0.98)
        self.exposure_raw = torch.nn.Parameter(torch.tensor(math.log(e / (1 - e))), requires_grad=learn_exposure)

    def exposure(self) -> torch.Tensor:
        return torch.sigmoid(self.exposure_raw)

    def spin(self) -> torch.Tensor:
        return cap_rotation(self.spin_raw, self.max_angle)

    def anchors(self) -> torch.Tensor:
        """(A, 3) camera-space anchors from their image parametrisation."""
        cam, raw = self.camera, self.anchors_raw
        uv = torch.stack((cam.cx + raw[:, 0] * self.ref_px, cam.cy + raw[:, 1] * self.ref_px), -1)
        depth = cam.fy / (self.ref_px * torch.exp(raw[:, 2]))
        return cam.unproject(uv, depth)

    def load_anchors(self, anchors: torch.Tensor) -> None:
        """Set the anchors to (A, 3) camera-space positions."""
        uv, depth = self.camera.project(anchors.to(self.anchors_raw))
        with torch.no_grad():
            self.anchors_raw[:, 0] = (uv[:, 0] - self.camera.cx) / self.ref_px
            self.anchors_raw[:, 1] = (uv[:, 1] - self.camera.cy) / self.ref_px
            self.anchors_raw[:, 2] = torch.log(self.camera.fy / depth / self.ref_px)

    def load_rotation(self, rot0: torch.Tensor, spin: torch.Tensor) -> None:
        """Set R0 (3, 3) and the spin (3,) per frame interval (clamped under the cap)."""
        with torch.no_grad():
            self.quat0.copy_(axis_angle_to_quaternion(matrix_to_axis_angle(rot0.to(self.quat0))))
            if self.max_angle == 0:
                return
            spin = spin.to(self.spin_raw)
            norm = spin.norm().clamp(max=self.max_angle * 0.999)
            scale = torch.atanh(norm / self.max_angle) * self.max_angle / norm.clamp_min(1e-12)
            self.spin_raw.copy_(spin * scale if float(norm) > 1e-9 else spin)

    def forward(self, frame_times: torch.Tensor, taus: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rotations (F, T, 3, 3) and positions (F, T, 3) of frames starting at window times
        ``frame_times`` (F,), at exposure times ``taus`` (T,)."""
        t = (frame_times[:, None] + taus[None, :] * self.exposure()).reshape(-1)
        positions = interpolate(self.anchors(), self.breaks, self.degree, t)
        rot0 = quaternion_to_matrix(self.quat0)
        rotations = axis_angle_to_matrix(t[:, None] * self.spin()) @ rot0
        shape = (frame_times.shape[0], taus.shape[0])
        return rotations.reshape(*shape, 3, 3), positions.reshape(*shape, 3)

    def trajectory(self, first_frame: int, model: str) -> Trajectory:
        with torch.no_grad():
            return Trajectory(
                first_frame=first_frame,
                breaks=self.breaks.detach().cpu().clone(),
                anchors=self.anchors().cpu(),
                degree=self.degree,
                rot0=quaternion_to_matrix(self.quat0).cpu(),
                spin=self.spin().cpu(),
                exposure_fraction=float(self.exposure()),
                model=model,
            )
