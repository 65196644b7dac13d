"""Stage 4, fit: one detected frame -> its :class:`~sfb_video.results.FrameResult`.

A track's first frame starts cold (every prototype, full iterations). Each next frame starts
warm from the previous frame's mesh, texture and motion, its start pose predicted by continuing
that motion across the gap between the two exposures (:mod:`sfb_video.stages.track` decides which frames
form a track and in which time direction they run).
"""

from __future__ import annotations

import dataclasses
import time

import torch

from sfb_video.config import Config
from sfb_video.crop import make_crop
from sfb_video.fitting.frame import WarmStart, fit_frame
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.motion import Motion, continue_motion, continue_turning
from sfb_video.results import FrameResult
from sfb_video.stages.masks import MaskSource, orient_masks
from sfb_video.stages.types import Detection, FrameWithBackground
from sfb_video.timing import timed


def continued(previous: FrameResult, earlier: FrameResult | None, index: int, exposure_fraction: float) -> Motion:
    """Frame ``index``'s motion as ``previous``'s continues: turning as the path turned from
    ``earlier`` (the frame before ``previous``, where there is one), else straight."""
    frames_ahead = index - previous.index
    if earlier is None or previous.index - earlier.index != 1:
        return continue_motion(previous.state.motion, frames_ahead, exposure_fraction)
    return continue_turning(earlier.state.motion, previous.state.motion, frames_ahead, exposure_fraction)


@timed("fit")
def fit_detection(
    frame: FrameWithBackground,
    detection: Detection,
    camera: PinholeCamera,
    config: Config,
    previous: FrameResult | None,
    device: torch.device,
    masks: MaskSource | None = None,
    earlier: FrameResult | None = None,
) -> FrameResult:
    """Fit the object of one frame, warm from ``previous`` when given (a frame of the same track;
    with ``earlier``, the frame before it, its motion continues turning as the path turned).

    With DeFMO ``masks``, the fit uses L_S on them, in the time direction the warm start
    predicts when there is one (DeFMO's own order otherwise); without, L_D.

    Args:
        frame: the frame and its background, (3, H, W) each.
        detection: the object's blob in the frame.
        camera: the clip's full-frame camera.
        config: crop, fit, render and video settings.
        previous: the result of an earlier frame of the same track, or None for a cold start.
        device: where to fit.
        masks: where the sub-frame masks come from (None: the difference mask).

    Raises:
        NoObjectError: when the crop around the detection shows no difference after all.
    """
    image, background = frame.pixels.to(device), frame.background_pixels.to(device)
    crop = make_crop(image, background, detection.box, camera, config.crop, detection.mask.to(device))
    warm = None
    if previous is not None:
        motion = continued(previous, earlier, frame.index, config.video.exposure_fraction)
        warm = WarmStart(previous.prototype, previous.state.vertices, previous.state.texture, motion.to(device))
    started = time.perf_counter()
    subframe_masks = None if masks is None else masks.masks(frame, detection.box, crop, config.render.time_steps)
    mask_seconds = time.perf_counter() - started
    flipped = False
    if subframe_masks is not None and warm is not None:
        subframe_masks, flipped = orient_masks(subframe_masks, crop.camera.project(warm.motion.x0)[0])
    # A track's first frame decides the shape the whole track refines: it tries every prototype.
    first = dataclasses.replace(config.fit, prototypes=config.video.track_prototypes)
    fit = fit_frame(crop, config.fit if warm is not None else first, config.render, warm=warm, masks=subframe_masks)
    seconds = mask_seconds + fit.seconds
    if warm is not None and fit.losses["image"] > config.video.retry_ratio * previous.losses["image"]:
        # The track's shape or prediction no longer explains this frame (a bounce, a turn, a
        # bad previous fit): start cold as well and keep whichever explains the frame better.
        cold = fit_frame(crop, config.fit, config.render, masks=subframe_masks)
        seconds += cold.seconds
        if cold.losses["image"] < fit.losses["image"]:
            fit, warm = cold, None
    state = fit.state
    return FrameResult(
        index=frame.index,
        detection_box=detection.box,
        crop_box=crop.box,
        crop_camera=crop.camera,
        state=type(state)(state.vertices.cpu(), state.topology.to("cpu"), state.texture.cpu(), state.motion.to("cpu")),
        start="cold" if warm is None else "warm",
        prototype=fit.prototype,
        losses=fit.losses,
        curve=fit.curves[fit.prototype],
        seconds=seconds,
        mask_source="diff" if subframe_masks is None else masks.name,
        masks=None if subframe_masks is None else subframe_masks.cpu(),
        masks_reversed=flipped,
    )
