"""The path of a window: its trajectory fitted to the seeds' streak ends in the image (no
rendering), the exposure fraction the seeds show, and the choice of motion model (one smooth
path, or a bounce)."""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import torch

from sfb_video.config import JointConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.model.trajectory import MOTION_MODELS, TrajectoryParams, interpolate


@dataclass(frozen=True)
class Seed:
    """A single-frame fit of one frame of the window, where the joint fit starts.

    Attributes:
        index: the frame's index; state: its mesh, texture and motion (camera coordinates, in
        the track's time direction); prototype: the prototype it deformed; image_loss: its L_I.
    """

    index: int
    state: ObjectState
    prototype: str
    image_loss: float


def apparent_px(motion: Motion, camera: PinholeCamera) -> float:
    """The object's apparent size in pixels at its start (a unit size seen at its depth)."""
    return float(camera.fy / motion.x0[2].clamp_min(1e-6))


def _streak_ends(seeds: list[Seed], first: int, exposure: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Window times (2S,) and camera-space points (2S, 3) of the seeds' streak ends, in time order."""
    times, points = [], []
    for seed in seeds:
        m = seed.state.motion
        times += [seed.index - first, seed.index - first + exposure]
        points += [m.x0, m.x0 + m.dx]
    t = torch.tensor(times, dtype=torch.float32)
    order = torch.argsort(t)
    return t[order], torch.stack(points).float()[order]


PATH_CHECK = 25
"""The path's fit reads its loss every this many steps, and stops where it changed by less than
:data:`PATH_TOLERANCE` (relative) since the last read."""
PATH_TOLERANCE = 1e-3


def fit_path(params: TrajectoryParams, seeds: list[Seed], first: int, exposure: float, steps: int) -> torch.Tensor:
    """Fit the anchors to the seeds' streak ends in the image (no rendering): in pixels (in
    units of the reference diameter), and loosely in apparent size, which sets depth but which
    one frame measures poorly (a thin object's size barely shows).

    Returns:
        (2S,) each streak end's distance from the fitted path in the image, in reference diameters.
    """
    t, target = _streak_ends(seeds, first, exposure)
    uv, depth = params.camera.project(target)
    log_size = torch.log(params.camera.fy / depth)
    # Start from the seeds themselves, interpolated at the anchors' times in the image and in
    # log depth: extrapolated in camera space, a depth can end behind the camera (circle_fast).
    start_uv = torch.stack([_interp(params.times, t, uv[:, k]) for k in range(2)], -1)
    start_depth = torch.exp(_interp(params.times, t, torch.log(depth)))
    params.load_anchors(params.camera.unproject(start_uv, start_depth))
    optimiser = torch.optim.Adam([params.anchors_raw], lr=0.05)
    last = math.inf
    for step in range(steps):
        optimiser.zero_grad(set_to_none=True)
        path = interpolate(params.anchors(), params.breaks, params.degree, t)
        p_uv, p_depth = params.camera.project(path)
        loss = ((p_uv - uv) / params.ref_px).square().sum(-1).mean()
        loss = loss + 0.25 * (torch.log(params.camera.fy / p_depth) - log_size).square().mean()
        if step % PATH_CHECK == 0:
            # Read every few steps (a read waits for the device); stop once the loss has settled.
            # Settled, not merely risen: from a start near the truth Adam's first steps overshoot
            # and the loss climbs before it falls below where it began.
            now = float(loss.detach())
            if abs(last - now) < PATH_TOLERANCE * now:
                break
            last = now
        loss.backward()
        optimiser.step()
    with torch.no_grad():
        path = interpolate(params.anchors(), params.breaks, params.degree, t)
        return ((params.camera.project(path)[0] - uv) / params.ref_px).norm(dim=-1)


def _interp(x: torch.Tensor, xp: torch.Tensor, fp: torch.Tensor) -> torch.Tensor:
    """Linear interpolation of (xp, fp) at x, extended linearly beyond the ends."""
    if xp.shape[0] == 1:
        return fp.expand_as(x).clone()
    i = torch.searchsorted(xp, x).clamp(1, xp.shape[0] - 1)
    x0, x1, f0, f1 = xp[i - 1], xp[i], fp[i - 1], fp[i]
    w = (x - x0) / (x1 - x0).clamp_min(1e-9)
    return f0 + w * (f1 - f0)


def measured_exposure(seeds: list[Seed], camera: PinholeCamera) -> float | None:
    """The exposure fraction the seeds show: the median over consecutive frames of a streak's
    length in the image over the distance from its start to the next frame's start (a shutter
    open for the fraction e of the interval draws e of the way). None without two consecutive
    seeds that move."""
    ratios = []
    by_index = {s.index: s.state.motion for s in seeds}
    for index, motion in by_index.items():
        following = by_index.get(index + 1)
        if following is None:
            continue
        uv = camera.project(torch.stack((motion.x0, motion.x0 + motion.dx, following.x0)))[0]
        step = float((uv[2] - uv[0]).norm())
        if step > 1.0:
            ratios.append(float((uv[1] - uv[0]).norm()) / step)
    return min(max(statistics.median(ratios), 0.05), 1.0) if ratios else None


def path_params(
    model: str,
    bounce: float | None,
    end: float,
    camera: PinholeCamera,
    ref_px: float,
    exposure_fraction: float,
    config: JointConfig,
    max_rotation_deg: float,
) -> TrajectoryParams:
    degree, pieces = MOTION_MODELS[model]
    breaks = torch.tensor([0.0, end] if pieces == 1 else [0.0, float(bounce), end])
    return TrajectoryParams(camera, breaks, degree, ref_px, exposure_fraction, config.learn_exposure, max_rotation_deg)


def choose_motion(
    seeds: list[Seed],
    first: int,
    end: float,
    camera: PinholeCamera,
    exposure_fraction: float,
    config: JointConfig,
) -> tuple[str, float | None]:
    """The motion model of a window and, for a bounce, the time of its break.

    A configured model is used as is (a bounce's break then goes where it fits the seeds best).
    ``auto`` takes constant acceleration unless one smooth path leaves some seed's streak end
    more than ``config.bounce_residual`` reference diameters away, and a path that breaks in
    one of the gaps between exposures brings every end within that distance and halves the
    worst miss (seeds that are simply wrong, a fit of the wrong blob, are not taken for a
    bounce: breaking the path does not bring them near).

    Returns:
        the model's name and the bounce's window time (None without a bounce).
    """
    ref_px = statistics.median(apparent_px(s.state.motion, camera) for s in seeds)

    def residual(model: str, bounce: float | None) -> float:
        params = path_params(model, bounce, end, camera, ref_px, exposure_fraction, config, 0.0)
        return float(fit_path(params, seeds, first, exposure_fraction, config.path_steps).max())

    if config.motion not in ("auto", "bounce"):
        return config.motion, None
    smooth = residual("constant_acceleration", None) if config.motion == "auto" else float("inf")
    if len(seeds) < 3 or smooth <= config.bounce_residual:
        return "constant_acceleration", None
    # The break in the middle of a gap: the bounce happened while the shutter was closed, or
    # near enough (a break during an exposure is seen as a bend of one streak).
    gaps = [k + (1 + exposure_fraction) / 2 for k in range(round(end) - 1)]
    broken = {
        g: residual("bounce", g)
        for g in gaps
        if min(s.index for s in seeds) - first < g < max(s.index for s in seeds) - first
    }
    best = min(broken, key=broken.__getitem__)
    if config.motion == "bounce" or broken[best] <= min(0.5 * smooth, config.bounce_residual):
        return "bounce", best
    return "constant_acceleration", None
