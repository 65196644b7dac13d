"""Where a frame's rendered object replaces the frame, and how well the fit explains it.

A TSR sub-frame is the input frame outside the object's region and the background with the
model's sharp object inside it. The region is the model's path during the exposure (a capsule
around its projected centres) together with every part of the frame's difference image
connected to that path: when a fit saw only part of a streak (a fragment, a partial
detection), the rest of the input's blurred streak is replaced by the background too and does
not stay behind as a ghost. The region is grown and feathered over a few pixels where the frame
already equals the background, so the join shows no seam, and outside it the frame's own
pixels are kept (other movers, and whatever the median background got wrong).
"""

from __future__ import annotations

import itertools
import math

import cv2
import numpy as np
import torch

from sfb_video.config import DetectConfig, RenderConfig
from sfb_video.crop import Box
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.stages.detect import difference_image, hysteresis, weak_level

FEATHER_PX = 3
"""The region's edge blends from the composite to the frame over about this many pixels."""

EDGE_PX = 2
"""The region is grown this much over the streak's antialiased edge, which lies below the
difference level."""

BLUR_POSES = 32
"""A blurred reconstruction that the quality signal is measured on averages at least this many
poses over the exposure (a few sharp copies are not the frame's blur)."""

REGION_REACH = 4.0
"""Parts of the difference connected to the model's path are taken up to this many object
radii from it (:func:`object_region`)."""

PATH_SAMPLES = 17
"""Points along the exposure where the model's path is drawn."""


def path_mask(motion: Motion, radius: float, camera: PinholeCamera) -> np.ndarray:
    """(H, W) bool: the capsule ``radius`` pixels around the projected centre of ``motion``
    during the exposure: where the model's object can be."""
    _, positions = motion.at(torch.linspace(0, 1, PATH_SAMPLES))
    uv, _ = camera.project(positions)
    mask = np.zeros((camera.height, camera.width), dtype=np.uint8)
    # Far off-frame points are clamped (cv2 clips the lines) so they stay within int32 after
    # the 4 fractional bits.
    limit = 4 * max(camera.width, camera.height)
    points = np.round(np.clip(uv.detach().cpu().double().numpy(), -limit, limit) * 16).astype(np.int64)
    thickness = max(1, round(2 * radius))
    for a, b in itertools.pairwise(points):
        cv2.line(mask, (int(a[0]), int(a[1])), (int(b[0]), int(b[1])), 1, thickness, cv2.LINE_8, 4)
    return mask.astype(bool)


def object_region(path: np.ndarray, difference: np.ndarray, level: float, reach: float) -> np.ndarray:
    """(H, W) float32 weights in [0, 1]: 1 over the object's region, falling to 0 over
    :data:`FEATHER_PX` outside it.

    Args:
        path: (H, W) bool, where the model's object is (:func:`path_mask`).
        difference: (H, W) the frame's ||I - B|| (:func:`sfb_video.stages.detect.difference_image`).
        level: differences above this are the streak's (:func:`sfb_video.stages.detect.weak_level`).
        reach: the parts of the difference connected to the path are taken up to this many
            pixels from it, so that a slow mover touching the streak is not erased whole.
    """
    connected = hysteresis(difference, path, level)
    grow = max(1, math.ceil(reach))
    # Everything happens within the path's box grown by the reach and the feather: work there,
    # not over a whole 4K frame with a kernel of hundreds of pixels.
    ys, xs = np.nonzero(path)
    out = np.zeros(path.shape, dtype=np.float32)
    if xs.size == 0:
        return out
    margin = grow + EDGE_PX + FEATHER_PX + 2
    y0, x0 = max(0, int(ys.min()) - margin), max(0, int(xs.min()) - margin)
    y1, x1 = int(ys.max()) + margin + 1, int(xs.max()) + margin + 1
    window = (slice(y0, y1), slice(x0, x1))
    # A distance transform, not a dilation: its cost does not grow with the reach.
    near = cv2.distanceTransform((~path[window]).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) <= grow
    region = (path[window] | (connected[window] & near)).astype(np.uint8)
    # The streak's antialiased edge lies below ``level``: grow over it before the feather starts.
    region = cv2.dilate(
        region, np.ones((2 * EDGE_PX + 1,) * 2, np.uint8), borderType=cv2.BORDER_CONSTANT, borderValue=0
    )
    out[window] = _feathered(region)
    return out


def _feathered(region: np.ndarray) -> np.ndarray:
    """(H, W) float32: 1 on ``region`` (uint8), falling linearly to 0 over :data:`FEATHER_PX`
    pixels outside it."""
    distance = cv2.distanceTransform((1 - region).astype(np.uint8), cv2.DIST_L2, 3)
    return np.clip(1 - distance / (FEATHER_PX + 1), 0, 1).astype(np.float32)


def region_box(weights: np.ndarray, within: Box) -> Box:
    """(x, y, w, h): the box ``within`` grown to hold every pixel of ``weights`` > 0."""
    ys, xs = np.nonzero(weights > 0)
    x, y, w, h = within
    if xs.size == 0:
        return within
    x0, y0 = min(x, int(xs.min())), min(y, int(ys.min()))
    x1, y1 = max(x + w, int(xs.max()) + 1), max(y + h, int(ys.max()) + 1)
    return x0, y0, x1 - x0, y1 - y0


def explained(
    image: torch.Tensor, background: torch.Tensor, reconstruction: torch.Tensor, weights: torch.Tensor
) -> float:
    """How much of the frame's difference from its background the fit explains, over the
    object's region: 1 - sum |I - I_hat| / sum |I - B|, weighted by ``weights``.

    1 is a perfect fit; 0 explains nothing (as the background alone); below 0 is worse than
    nothing. A fit of a fragment of a streak leaves the rest of the streak unexplained.

    Args:
        image, background, reconstruction: (3, h, w) float32 over the same box.
        weights: (h, w) the region (:func:`object_region`) over that box.
    """
    total = float(((image - background).abs().sum(0) * weights).sum())
    if total <= 0:
        return 1.0
    return 1 - float(((image - reconstruction).abs().sum(0) * weights).sum()) / total


def object_radius(state: ObjectState, camera: PinholeCamera) -> float:
    """The object's largest radius in pixels (its furthest vertex) along its exposure's path."""
    _, positions = state.motion.at(torch.linspace(0, 1, PATH_SAMPLES))
    _, depth = camera.project(positions)
    return float(camera.fy * state.vertices.norm(dim=-1).max() / depth.min())


def fitted_region(
    state: ObjectState,
    camera: PinholeCamera,
    difference: np.ndarray,
    detect: DetectConfig,
    known: torch.Tensor | None = None,
) -> np.ndarray:
    """(H, W) float32 :func:`object_region` weights of ``state``'s object in ``camera``'s image,
    whose ||I - B|| is ``difference`` (``known``: :func:`~sfb_video.stages.detect.weak_level`'s):
    its path and the streak connected to it."""
    radius = object_radius(state, camera)
    path = path_mask(state.motion, radius, camera)
    return object_region(path, difference, weak_level(difference, detect, known), REGION_REACH * radius)


def fit_quality(
    state: ObjectState,
    image: torch.Tensor,
    background: torch.Tensor,
    camera: PinholeCamera,
    detect: DetectConfig,
    render: RenderConfig,
) -> float:
    """:func:`explained` of ``state`` on one image: (3, h, w) ``image`` and ``background``
    float32 in [0, 1] that ``camera`` renders (a fit's crop), over the object's region there."""
    region = fitted_region(state, camera, difference_image(image, background), detect)
    blurred = state.render_blurred(camera, background, BLUR_POSES, render)
    return explained(image, background, blurred, torch.from_numpy(region).to(image.device))
