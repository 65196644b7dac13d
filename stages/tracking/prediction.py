"""Where a track expects its object: a motion's streak in the image, two frames joined end to
start, a streak glided on at its image pace, and a 3D guess that lags that pace."""

from __future__ import annotations

import math

import numpy as np
import torch

from sfb_video.config import DetectConfig, TrackConfig
from sfb_video.crop import Box
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.motion import Motion, continue_motion
from sfb_video.results import FrameResult
from sfb_video.stages.side_by_side import parallel
from sfb_video.stages.types import Prediction


def predict(motion: Motion, camera: PinholeCamera) -> Prediction:
    """Where ``motion``'s streak appears in ``camera``: the centre of its middle, its diameter
    and its ends."""
    uv, depth = camera.project(torch.stack((motion.x0 + 0.5 * motion.dx, motion.x0, motion.x0 + motion.dx)))
    ends = ((float(uv[1, 0]), float(uv[1, 1])), (float(uv[2, 0]), float(uv[2, 1])))
    return Prediction((float(uv[0, 0]), float(uv[0, 1])), float(camera.fy / depth[0]), ends=ends)


def join_gap(previous: FrameResult, current: FrameResult, camera: PinholeCamera, exposure_fraction: float) -> float:
    """Pixels between where ``current``'s exposure starts and where ``previous``'s motion,
    continued at constant velocity across the gap, puts that start."""
    predicted = continue_motion(previous.state.motion, current.index - previous.index, exposure_fraction)
    uv = camera.project(torch.stack((predicted.x0, current.state.motion.x0)))[0]
    return float((uv[0] - uv[1]).norm())


def ray_gap(
    previous: FrameResult, current: FrameResult, camera: PinholeCamera, min_exposure_fraction: float = 0.2
) -> float:
    """Pixels between where ``current``'s exposure starts and the segment on which
    ``previous``'s streak goes on past its end for any exposure fraction down to
    ``min_exposure_fraction``: the join gap where the shutter is not known (a short one leaves a
    long gap between streaks; e leaves 1 / e - 1 streak lengths)."""
    motion = previous.state.motion
    uv = camera.project(torch.stack((motion.x0, motion.x0 + motion.dx, current.state.motion.x0)))[0]
    direction = uv[1] - uv[0]
    along = float(((uv[2] - uv[1]) @ direction) / direction.square().sum().clamp_min(1e-12))
    gaps = (current.index - previous.index) / min_exposure_fraction - 1
    return float((uv[2] - uv[1] - min(max(along, 0.0), gaps) * direction).norm())


def join(
    previous: FrameResult,
    current: FrameResult,
    camera: PinholeCamera,
    exposure_fraction: float,
    may_flip_previous: bool,
) -> tuple[FrameResult, FrameResult]:
    """Choose the time directions of two frames of one track so that they join end to start.

    The current frame's start should be where the previous frame's motion, continued across the
    gap, puts it (in image pixels, where the fit is surest). The previous frame may be reversed
    too when nothing before it fixed its direction (the first frame of a track).

    Returns:
        previous and current, each possibly reversed.
    """
    options = [(p, c) for p in (previous, previous.reversed()) for c in (current, current.reversed())]
    if not may_flip_previous:
        options = options[:2]
    return min(options, key=lambda pc: join_gap(pc[0], pc[1], camera, exposure_fraction))


def glide(at: FrameResult, other: FrameResult, index: int, camera: PinholeCamera) -> Prediction:
    """Frame ``index``'s prediction from frame ``at``'s streak, moved in the image at the pace
    between ``other`` and ``at`` (frames of one track): on past a track's last clean frame, or
    back before its first."""
    moved, seen = predict(at.state.motion, camera), predict(other.state.motion, camera)
    pace = [(a - b) / (at.index - other.index) for a, b in zip(moved.centre, seen.centre, strict=True)]
    steps = index - at.index

    def on(point: tuple[float, float]) -> tuple[float, float]:
        return point[0] + steps * pace[0], point[1] + steps * pace[1]

    ends = None if moved.ends is None else (on(moved.ends[0]), on(moved.ends[1]))
    return Prediction(on(moved.centre), moved.diameter, None, ends)


def lags(
    three_d: Prediction, paced: Prediction, last: tuple[float, float], detect: DetectConfig, track: TrackConfig
) -> bool:
    """Whether the 3D guess falls short of the image-pace guess along the pace's line: more than
    ``track.lag_diameters`` of the object's diameters from it, and either hardly on from the
    ``last`` streak's centre (under one diameter), or on from it the pace's way, less far, and
    parallel to its line (``detect.parallel_deg``: a ball swung on a circle, where the 3D guess
    turns as the object turned, and the pace does not)."""
    gap = math.hypot(three_d.centre[0] - paced.centre[0], three_d.centre[1] - paced.centre[1])
    if gap <= track.lag_diameters * max(paced.diameter, 1.0):
        return False
    step = np.subtract(three_d.centre, last)
    pace = np.subtract(paced.centre, last)
    if np.linalg.norm(step) < max(paced.diameter, 1.0):
        return True  # hardly on from the last streak: its direction says nothing
    on = float(step @ pace) > 0 and np.linalg.norm(step) < np.linalg.norm(pace)
    return on and parallel(step / np.linalg.norm(step), pace / np.linalg.norm(pace), detect.parallel_deg)


def at_edge(box: Box, camera: PinholeCamera) -> bool:
    """Whether ``box`` (x, y, w, h) touches the edge of ``camera``'s image."""
    x, y, w, h = box
    return x <= 0 or y <= 0 or x + w >= camera.width or y + h >= camera.height
