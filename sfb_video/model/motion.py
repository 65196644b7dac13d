"""The motion of an object during one exposure, with bounded, well-conditioned parameters.

Convention:
    Positions are parametrised in the crop the fit works in, as the paper does for the image:
    the centre of mass projects to crop NDC tanh(a), tanh(b) in (-1, 1) (so it stays inside
    the crop), and its apparent diameter at the start is a fraction of the crop height between
    ``size_range`` (paper: 5% to 100% of the field of view), which fixes its depth. The end's
    apparent size is the start's times a factor within 1 / ``max_size_ratio`` ..
    ``max_size_ratio``: without that bound a fit can fade an unexplained streak out by sending
    one end far away. The 3D start and end positions follow through the crop camera, and
    x(tau) = x0 + tau * dx.
    R(tau) = exp(tau * omega) @ R0 with R0 a WXYZ quaternion and |omega| smoothly capped at
    ``max_rotation_deg`` (paper: 120 degrees).
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np
import torch

from sfb_video.errors import NoObjectError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.rotation import (
    axis_angle_to_matrix,
    axis_angle_to_quaternion,
    exposure_rotations,
    matrix_to_axis_angle,
    quaternion_to_matrix,
)
from sfb_video.model import complex_step as cs
from sfb_video.render import kernels


@dataclass(frozen=True)
class Motion:
    """A recovered motion in camera coordinates (object sizes), detached from any optimiser.

    Attributes:
        x0: (3,) position of the centre of mass at the start of the exposure.
        dx: (3,) translation during the exposure.
        rot0: (3, 3) rotation at the start of the exposure.
        omega: (3,) axis-angle rotation made during the exposure (radians).
    """

    x0: torch.Tensor
    dx: torch.Tensor
    rot0: torch.Tensor
    omega: torch.Tensor

    def at(self, taus: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rotations (T, 3, 3) and positions (T, 3) at exposure times ``taus`` (T,)."""
        return exposure_rotations(self.rot0, self.omega, taus), self.x0 + taus[:, None] * self.dx

    def reversed(self) -> Motion:
        """The same path travelled backwards: what the time ambiguity of one frame allows."""
        rot1 = exposure_rotations(self.rot0, self.omega, torch.ones(1, device=self.x0.device))[0]
        return Motion(self.x0 + self.dx, -self.dx, rot1, -self.omega)

    def to(self, device: torch.device | str) -> Motion:
        return Motion(self.x0.to(device), self.dx.to(device), self.rot0.to(device), self.omega.to(device))


def continue_motion(motion: Motion, frames_ahead: int, exposure_fraction: float) -> Motion:
    """The motion of the exposure ``frames_ahead`` frames later, at constant velocity and spin.

    One frame interval is 1 / ``exposure_fraction`` exposures, so the next exposure starts that
    many multiples of the exposure's own translation and rotation after this one's start.
    """
    k = frames_ahead / exposure_fraction
    rot0 = axis_angle_to_matrix(k * motion.omega) @ motion.rot0
    return Motion(motion.x0 + k * motion.dx, motion.dx, rot0, motion.omega)


MAX_TURN_DEG = 90.0
"""A path that turned more than this between two exposures is not continued as a turn (a
bounce, or a poor fit)."""


def continue_turning(earlier: Motion, motion: Motion, frames_ahead: int, exposure_fraction: float) -> Motion:
    """As :func:`continue_motion`, with the translation turning as it turned from ``earlier``
    (the exposure one frame before ``motion``'s) to ``motion``: a circular swing is followed,
    a straight track continues straight. A turn over :data:`MAX_TURN_DEG` is not continued.
    """
    axis = torch.linalg.cross(earlier.dx, motion.dx)
    angle = math.atan2(float(axis.norm()), float(earlier.dx @ motion.dx))
    if float(axis.norm()) < 1e-12 or math.degrees(angle) > MAX_TURN_DEG:
        return continue_motion(motion, frames_ahead, exposure_fraction)
    unit = axis / axis.norm()
    n, e = frames_ahead, exposure_fraction
    straight = continue_motion(motion, frames_ahead, exposure_fraction)
    # On a circle at constant speed turning ``angle`` a frame, dx is the chord of e x angle and
    # the next start lies at the end of the chord of n x angle: their directions differ by
    # (n - e) x angle / 2 and their lengths are in the ratio of the half-angles' sines.
    along = axis_angle_to_matrix(unit * ((n - e) * angle / 2))
    ratio = math.sin(n * angle / 2) / math.sin(e * angle / 2)
    turned = axis_angle_to_matrix(unit * (n * angle))
    return Motion(motion.x0 + ratio * (along @ motion.dx), turned @ motion.dx, straight.rot0, motion.omega)


@dataclass(frozen=True)
class Streak:
    """The blur streak seen in a difference mask, in crop pixels.

    Attributes:
        start, end: (2,) the two ends of the path of the object's centre (order arbitrary).
        diameter: apparent object diameter in pixels (the streak's width).
    """

    start: torch.Tensor
    end: torch.Tensor
    diameter: float


MIN_STREAK_PIXELS = 2
"""The fewest mask pixels a streak is fitted to: its axis comes from their second moments."""


def streak_from_mask(mask: torch.Tensor) -> Streak:
    """Fit a capsule (a disc of diameter d swept along a segment) to the (h, w) mask.

    The major axis comes from the second moments. A capsule of extent E along it has area
    A = (E - d) d + pi d^2 / 4, which gives d; the path ends lie d / 2 inside the extent.
    """
    ys, xs = torch.nonzero(mask > 0.5, as_tuple=True)
    if xs.numel() < MIN_STREAK_PIXELS:
        raise NoObjectError(f"the object's mask has {xs.numel()} pixel(s): too few for a streak to start from")
    pts = torch.stack((xs, ys), -1).to(torch.float64)
    centre = pts.mean(0)
    _, evecs = torch.linalg.eigh(torch.cov(pts.T))
    axis = evecs[:, 1]
    along = (pts - centre) @ axis
    # The span of pixel centres, not +1: that matches the area of the sampled shape best.
    extent = float(along.max() - along.min())
    k = 1 - math.pi / 4
    diameter = (extent - math.sqrt(max(extent**2 - 4 * k * pts.shape[0], 0.0))) / (2 * k)
    lo, hi = float(along.min()) + diameter / 2, float(along.max()) - diameter / 2
    # A minimal separation keeps start and end apart, so their gradients differ from the first step.
    mid, half = (lo + hi) / 2, max((hi - lo) / 2, 0.5)
    return Streak((centre + (mid - half) * axis).float(), (centre + (mid + half) * axis).float(), diameter)


def cap_rotation(raw: torch.Tensor, max_angle: float) -> torch.Tensor:
    """Map (3,) unconstrained ``raw`` to an axis-angle of norm < ``max_angle``, smoothly.

    Small vectors pass unchanged (the map's derivative at 0 is the identity); a cap of 0 gives 0.
    """
    if max_angle == 0:
        return torch.zeros_like(raw)
    norm = raw.square().sum().add(1e-12).sqrt()
    return raw * (max_angle * torch.tanh(norm / max_angle) / norm)


def _exposure_chain(
    theta: np.ndarray,
    taus: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    width: float,
    height: float,
    lo: float,
    hi: float,
    log_ratio: float,
    max_angle: float,
    rotations: np.ndarray,
    positions: np.ndarray,
) -> None:
    """:meth:`MotionParams.tensor_forward` for each row of (B, 13) complex parameters (ends,
    quat0, omega_raw) into (B, T, 3, 3) rotations and (B, T, 3) positions, complex-safe."""
    ends = np.empty((2, 3), dtype=np.complex128)
    rot0 = np.empty((3, 3), dtype=np.complex128)
    turn = np.empty((3, 3), dtype=np.complex128)
    for b in range(theta.shape[0]):
        start_px = (lo + (hi - lo) / (1 + cmath.exp(-theta[b, 2]))) * height
        for e in range(2):
            u = (cmath.tanh(theta[b, 3 * e]) + 1) * width / 2 - 0.5
            v = (cmath.tanh(theta[b, 3 * e + 1]) + 1) * height / 2 - 0.5
            diameter = start_px if e == 0 else start_px * cmath.exp(log_ratio * cmath.tanh(theta[b, 5]))
            depth = fy / diameter
            ends[e, 0], ends[e, 1], ends[e, 2] = (u - cx) / fx * depth, (v - cy) / fy * depth, depth
        cs.rotation_from_quaternion(theta[b, 6], theta[b, 7], theta[b, 8], theta[b, 9], rot0)
        ox, oy, oz = cs.cap_rotation(theta[b, 10], theta[b, 11], theta[b, 12], max_angle)
        for t in range(taus.shape[0]):
            tau = taus[t]
            for i in range(3):
                positions[b, t, i] = ends[0, i] + tau * (ends[1, i] - ends[0, i])
            cs.rotation_from_axis_angle(tau * ox, tau * oy, tau * oz, turn)
            for i in range(3):
                for j in range(3):
                    rotations[b, t, i, j] = turn[i, 0] * rot0[0, j] + turn[i, 1] * rot0[1, j] + turn[i, 2] * rot0[2, j]


if kernels.njit is not None:
    _exposure_chain = kernels.compile_kernel(_exposure_chain)


class MotionParams(torch.nn.Module):
    """Learnable motion of one exposure, expressed in a crop camera.

    Args:
        camera: the crop camera the fit renders in.
        size_range: (min, max) apparent diameter at the start, as a fraction of the crop height.
        max_size_ratio: bound on the ratio of the apparent sizes at the end and the start.
        max_rotation_deg: cap on the rotation during the exposure.
        init_size: initial apparent diameter fraction.
    """

    def __init__(
        self,
        camera: PinholeCamera,
        size_range: tuple[float, float],
        max_size_ratio: float,
        max_rotation_deg: float,
        init_size: float,
    ) -> None:
        super().__init__()
        self.camera = camera
        self.size_range = size_range
        self.log_ratio = math.log(max_size_ratio)
        self.max_angle = math.radians(max_rotation_deg)
        lo, hi = size_range
        s = min(max((init_size - lo) / (hi - lo), 1e-3), 1 - 1e-3)
        # Start and end: crop-NDC (a, b) each; row 0 holds the start's size logit, row 1 the
        # end's size ratio (through tanh). Both start at the crop centre, at the same size.
        self.ends = torch.nn.Parameter(torch.tensor([[0.0, 0.0, math.log(s / (1 - s))], [0.0, 0.0, 0.0]]))
        self.quat0 = torch.nn.Parameter(torch.tensor([1.0, 0.0, 0.0, 0.0]))
        self.omega_raw = torch.nn.Parameter(torch.zeros(3), requires_grad=self.max_angle > 0)

    def positions(self) -> torch.Tensor:
        """(2, 3) camera-space centre of mass at the start and the end of the exposure."""
        cam = self.camera
        ndc = torch.tanh(self.ends[:, :2])
        u = (ndc[:, 0] + 1) * cam.width / 2 - 0.5
        v = (ndc[:, 1] + 1) * cam.height / 2 - 0.5
        lo, hi = self.size_range
        start_px = (lo + (hi - lo) * torch.sigmoid(self.ends[0, 2])) * cam.height
        diameter_px = torch.stack((start_px, start_px * torch.exp(self.log_ratio * torch.tanh(self.ends[1, 2]))))
        depth = cam.fy / diameter_px  # a unit-diameter object spans f / z pixels
        return cam.unproject(torch.stack((u, v), -1), depth)

    def omega(self) -> torch.Tensor:
        return cap_rotation(self.omega_raw, self.max_angle)

    def forward(self, taus: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rotations (T, 3, 3) and positions (T, 3) at exposure times ``taus`` (T,).

        On the CPU one autograd node (:mod:`~sfb_video.model.complex_step`); elsewhere the same
        formulas as tensor operations, which stay on the device.
        """
        if self.ends.device.type == "cpu" and kernels.njit is not None:
            rotations, positions = cs.complex_step(self._chain(taus), (self.ends, self.quat0, self.omega_raw))
            return rotations, positions
        return self.tensor_forward(taus)

    def tensor_forward(self, taus: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`forward` as tensor operations on any device (the reference for the CPU's node)."""
        ends = self.positions()
        rot0 = quaternion_to_matrix(self.quat0)
        return exposure_rotations(rot0, self.omega(), taus), ends[0] + taus[:, None] * (ends[1] - ends[0])

    def _chain(self, taus: torch.Tensor) -> cs.Chain:
        """:meth:`forward` as a compiled function of (B, 13) complex parameter vectors."""
        cam, (lo, hi) = self.camera, self.size_range
        times = taus.detach().double().numpy()
        setting = (cam.fx, cam.fy, cam.cx, cam.cy, float(cam.width), float(cam.height), lo, hi, self.log_ratio)

        def chain(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            rotations = np.empty((theta.shape[0], times.shape[0], 3, 3), dtype=np.complex128)
            positions = np.empty((theta.shape[0], times.shape[0], 3), dtype=np.complex128)
            _exposure_chain(theta, times, *setting, self.max_angle, rotations, positions)
            return rotations, positions

        return chain

    def _raw_position(self, uv: torch.Tensor) -> torch.Tensor:
        """Inverse of the tanh placement in :meth:`positions`: (*, 2) crop pixels -> (*, 2) raw."""
        cam = self.camera
        ndc = torch.stack(((uv[..., 0] + 0.5) * 2 / cam.width - 1, (uv[..., 1] + 0.5) * 2 / cam.height - 1), -1)
        return torch.atanh(ndc.clamp(-0.999, 0.999))

    def start_at_streak(self, streak: Streak) -> None:
        """Put the start and end of the motion at the streak's ends, sized to its width."""
        cam, (lo, hi) = self.camera, self.size_range
        with torch.no_grad():
            self.ends[:, :2] = self._raw_position(torch.stack((streak.start, streak.end)).to(self.ends))
            frac = min(max((streak.diameter / cam.height - lo) / (hi - lo), 1e-3), 1 - 1e-3)
            self.ends[0, 2] = math.log(frac / (1 - frac))
            self.ends[1, 2] = 0.0

    def motion(self) -> Motion:
        with torch.no_grad():
            ends = self.positions()
            return Motion(ends[0], ends[1] - ends[0], quaternion_to_matrix(self.quat0), self.omega())

    def load_motion(self, motion: Motion) -> None:
        """Set the parameters to reproduce ``motion`` (clamped into the crop's bounds)."""

        cam, (lo, hi) = self.camera, self.size_range
        with torch.no_grad():
            ends = torch.stack((motion.x0, motion.x0 + motion.dx)).to(self.ends)
            uv, depth = cam.project(ends)
            frac = ((cam.fy / depth[0] / cam.height - lo) / (hi - lo)).clamp(1e-3, 1 - 1e-3)
            ratio = (torch.log(depth[0] / depth[1]) / self.log_ratio).clamp(-0.999, 0.999)
            size = torch.stack((torch.logit(frac), torch.atanh(ratio)))
            self.ends.copy_(torch.cat((self._raw_position(uv), size[:, None]), -1))
            self.quat0.copy_(axis_angle_to_quaternion(matrix_to_axis_angle(motion.rot0.to(self.quat0))))
            if self.max_angle == 0:
                return
            omega = motion.omega.to(self.omega_raw)
            norm = omega.norm().clamp(max=self.max_angle * 0.999)
            scale = torch.atanh(norm / self.max_angle) * self.max_angle / norm.clamp_min(1e-12)
            self.omega_raw.copy_(omega * scale if float(norm) > 1e-9 else omega)
