"""From a frame, its background and an object box to the crop a fit works in.

The crop is the box grown by about one object radius, widened to 4:3, kept inside the frame
where it fits, and rendered at native resolution up to a cap (rendering cost grows with pixels,
and upsampling a small crop adds none of them information). The crop's camera is the frame's
camera with shifted and scaled intrinsics, so 3D results from every crop share one frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch
import torch.nn.functional as F

from sfb_video.config import CropConfig
from sfb_video.errors import SfbError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.imageio import as_float

Box = tuple[int, int, int, int]
"""(x0, y0, width, height) in full-frame pixels; (x0, y0) is the top-left pixel."""


@dataclass(frozen=True)
class Crop:
    """One frame's working crop.

    Attributes:
        box: the crop's box in the full frame.
        camera: the camera that renders exactly this crop at its working resolution.
        image: (3, h, w) the blurred frame, cropped and resized.
        background: (3, h, w) the background, likewise.
        object_mask: (h, w) the largest blob of sum_rgb |I - B| > ``region_threshold``: the
            object region, and the difference mask D of L_D.
        streak: (h, w) bool, the largest blob of that region grown into the streak's faint
            parts (:func:`object_region`): the object's footprint is read off it. Not the fit's
            mask: measured, the grown mask cost the window fit its spin (3.8 -> 50 degrees off
            on tests/fitting/test_window.py's clip).
    """

    box: Box
    camera: PinholeCamera
    image: torch.Tensor
    background: torch.Tensor
    object_mask: torch.Tensor
    streak: torch.Tensor


def box_union(a: Box | np.ndarray, b: Box | np.ndarray) -> Box:
    """The smallest box that holds boxes ``a`` and ``b`` (each (x, y, w, h), or an array that
    starts so)."""
    x0, y0 = min(a[0], b[0]), min(a[1], b[1])
    return int(x0), int(y0), int(max(a[0] + a[2], b[0] + b[2]) - x0), int(max(a[1] + a[3], b[1] + b[3]) - y0)


def mask_box(mask: np.ndarray) -> Box | None:
    """(x, y, w, h) of the True pixels of an (H, W) bool mask, None if there are none."""
    rows, cols = np.nonzero(mask.any(1))[0], np.nonzero(mask.any(0))[0]
    if rows.size == 0:
        return None
    return int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1)


def box_mask(box: Box, size: tuple[int, int]) -> torch.Tensor:
    """(H, W) bool, True inside ``box`` (x, y, w, h), for an image of ``size`` (H, W)."""
    x, y, w, h = box
    mask = torch.zeros(size, dtype=torch.bool)
    mask[y : y + h, x : x + w] = True
    return mask


def largest_blob(mask: torch.Tensor) -> tuple[torch.Tensor, Box | None]:
    """The largest 8-connected blob of a boolean (H, W) mask, and its box (None if empty)."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask.cpu().numpy().astype(np.uint8), connectivity=8)
    if count <= 1:
        return torch.zeros_like(mask, dtype=torch.float32), None
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h, _ = (int(v) for v in stats[best])
    return torch.from_numpy(labels == best).float().to(mask.device), (x, y, w, h)


def object_region(image: torch.Tensor, background: torch.Tensor, threshold: float, noise: float) -> torch.Tensor:
    """Boolean (H, W) mask of the pixels where (3, H, W) ``image`` shows the object over ``background``.

    The pixels of sum_rgb |I - B| > ``threshold``, grown by hysteresis into the streak's faint
    parts: a thin or grey object covers each pixel of its streak so briefly that most of it
    lies under the threshold (a striped grey pen keeps its bright end alone), and so does the
    ramp at each end of every streak. Joined are the pixels whose difference, smoothed, stands
    ``noise`` spreads (1.4826 MAD) above the image's median, a background's noise level where
    most of the image is background, and above half the threshold, when they touch the
    thresholded ones. ``noise`` 0 keeps the threshold alone.
    """
    difference = (image - background).abs().sum(0)
    strict = difference > threshold
    if noise <= 0:
        return strict
    d = difference.cpu().numpy().astype(np.float32)
    smooth = cv2.GaussianBlur(d, (0, 0), 1.0)
    level = float(np.median(smooth))
    spread = 1.4826 * float(np.median(np.abs(smooth - level)))
    weak = (smooth > level + noise * spread) & (d > threshold / 2)
    seeds = strict.cpu().numpy()
    _, labels = cv2.connectedComponents((weak | seeds).astype(np.uint8), connectivity=8)
    touched = np.unique(labels[seeds])
    grown = np.isin(labels, touched[touched > 0])
    return torch.from_numpy(grown).to(strict.device)


def find_object_box(image: torch.Tensor, background: torch.Tensor, threshold: float) -> Box | None:
    """The box of the largest blob of sum_rgb |I - B| > threshold, or None if there is none.

    Args:
        image, background: (3, H, W) in [0, 1].
    """
    return largest_blob(object_region(image, background, threshold, 0.0))[1]


def streak_width(blob: np.ndarray) -> float:
    """The width in pixels of the streak in (h, w) bool ``blob``: twice its largest inscribed
    radius, so a thin streak's width whatever its direction (a diagonal streak's box is as tall
    as it is long). The distance is to pixel centres: a band k pixels wide measures about k + 1."""
    if not blob.any():
        return 0.0
    inside = cv2.distanceTransform(np.pad(blob, 1).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return 2.0 * float(inside.max())


def crop_box(box: Box, frame_size: tuple[int, int], config: CropConfig) -> Box:
    """Grow ``box`` by the margin, widen it to the aspect ratio and fit it in the frame (W, H)."""
    x, y, w, h = box
    width, height = frame_size
    pad = config.margin * min(w, h)
    cx, cy = x + w / 2, y + h / 2
    w, h = w + 2 * pad, h + 2 * pad
    if w / h < config.aspect:
        w = h * config.aspect
    else:
        h = w / config.aspect
    w, h = min(math.ceil(w), width), min(math.ceil(h), height)
    x0 = round(min(max(cx - w / 2, 0), width - w))
    y0 = round(min(max(cy - h / 2, 0), height - h))
    return x0, y0, w, h


def masks_onto(masks: torch.Tensor, box: Box, crop: Crop) -> torch.Tensor:
    """(N, h, w) masks made on the crop of ``box`` (at that crop's working size) drawn on
    ``crop`` at its working size instead; 0 where ``box`` does not reach."""
    bx, by, bw, bh = box
    native = F.interpolate(masks[None], size=(bh, bw), mode="bilinear", align_corners=False)[0]
    cx, cy, cw, ch = crop.box
    on_crop = masks.new_zeros((masks.shape[0], ch, cw))
    x0, x1, y0, y1 = max(bx, cx), min(bx + bw, cx + cw), max(by, cy), min(by + bh, cy + ch)
    if x1 > x0 and y1 > y0:
        on_crop[:, y0 - cy : y1 - cy, x0 - cx : x1 - cx] = native[:, y0 - by : y1 - by, x0 - bx : x1 - bx]
    return _resize(on_crop, (crop.image.shape[2], crop.image.shape[1])).clamp(0, 1)


def _resize(image: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    if image.shape[-2:] == (size[1], size[0]):
        return image
    return F.interpolate(image[None], size=(size[1], size[0]), mode="bilinear", antialias=True, align_corners=False)[0]


def _native_width(
    image: torch.Tensor, background: torch.Tensor, box: Box, config: CropConfig, blob: torch.Tensor | None
) -> float:
    """:func:`streak_width` of the object in ``box`` at the frame's own resolution: of the largest
    blob of its object region (within ``blob`` when given; a window's blob may be its whole box)."""
    x, y, w, h = box
    w, h, x, y = w + min(x, 0), h + min(y, 0), max(x, 0), max(y, 0)  # a box reaching past the top or left
    region = object_region(
        as_float(image[:, y : y + h, x : x + w]),
        as_float(background[:, y : y + h, x : x + w]),
        config.region_threshold,
        0.0,
    )
    if blob is not None:
        region &= blob[y : y + h, x : x + w].to(region.device) > 0
    return streak_width(largest_blob(region)[0].cpu().numpy() > 0)


def make_crop(
    image: torch.Tensor,
    background: torch.Tensor,
    box: Box,
    camera: PinholeCamera,
    config: CropConfig,
    blob: torch.Tensor | None = None,
) -> Crop:
    """Crop ``image`` and ``background`` (3, H, W; uint8 or float32 in [0, 1]) around the object box ``box``.

    Args:
        blob: (H, W) bool, the detected object; when given, the object region is restricted to
            the differing pixels near it, so that another mover inside the crop is not taken
            for the object.

    Raises:
        SfbError: when the images differ in size or the box is empty or outside the frame.
    """
    if image.shape != background.shape:
        raise SfbError(f"image {tuple(image.shape[1:])} and background {tuple(background.shape[1:])} differ in size")
    height, width = image.shape[1:]
    x, y, w, h = box
    if w <= 0 or h <= 0 or x >= width or y >= height or x + w <= 0 or y + h <= 0:
        raise SfbError(f"object box {box} is empty or outside the {width}x{height} frame")
    cb = crop_box(box, (width, height), config)
    x0, y0, cw, ch = cb
    scale = min(1.0, config.max_width / cw)
    if config.max_object_px > 0:
        scale = min(scale, config.max_object_px / max(1.0, _native_width(image, background, box, config, blob)))
    out = (max(1, round(cw * scale)), max(1, round(ch * scale)))
    img = _resize(as_float(image[:, y0 : y0 + ch, x0 : x0 + cw]), out).clamp(0, 1)
    bgr = _resize(as_float(background[:, y0 : y0 + ch, x0 : x0 + cw]), out).clamp(0, 1)
    region = object_region(img, bgr, config.region_threshold, 0.0)
    grown = object_region(img, bgr, config.region_threshold, config.region_noise)
    if blob is not None:
        near = _resize(blob[None, y0 : y0 + ch, x0 : x0 + cw].to(img), out)[0] > 0
        # Grown a little: the blob came from a stricter threshold and misses the streak's faint rim.
        grow = 2 * max(1, round(0.1 * min(out))) + 1
        near = F.max_pool2d(near[None, None].float(), grow, stride=1, padding=grow // 2)[0, 0] > 0
        region &= near
        grown &= near
    return Crop(
        box=cb,
        camera=camera.crop(x0, y0, cw, ch, out[0], out[1]),
        image=img,
        background=bgr,
        object_mask=largest_blob(region)[0],
        streak=largest_blob(grown)[0] > 0,
    )
