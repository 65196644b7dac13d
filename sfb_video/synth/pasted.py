"""Clips made from one real blurred frame: its streak pasted along a path over its background.

A pair of a real blurred frame and its clean background (as ../shared/data/pairs holds) gives a
real object's streak, with its real blur and texture, but one frame. Moving that streak (its
difference from the background, under a feathered matte) to other places over the same
background makes a clip whose every frame shows a real streak, at known boxes: what the
detection of real footage of a large object (a frisbee, a disc) needs to be tested on. The
difference is added, not the pixels copied, so no patch of the old background comes along; over
a background much unlike the original the streak's colours are off (keep the path over similar
ground).
"""

from __future__ import annotations

import cv2
import numpy as np

from sfb_video.crop import Box

STREAK_LEVEL = 0.02
"""Pixels whose colour differs from the background by more than this (RGB distance in [0, 1])
belong to the streak."""


def streak_matte(image: np.ndarray, background: np.ndarray) -> tuple[np.ndarray, Box]:
    """The streak of a blurred frame over its background: (H, W) float32 matte in [0, 1] (its
    largest blob of differing pixels, grown and feathered by a few pixels) and the box of
    pixels above :data:`STREAK_LEVEL` in it.

    Args:
        image, background: (H, W, 3) uint8.
    """
    difference = np.linalg.norm(image.astype(np.float32) - background.astype(np.float32), axis=2) / 255
    mask = (difference > STREAK_LEVEL).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if count < 2:
        raise ValueError("the image does not differ from its background")
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    blob = (labels == largest).astype(np.uint8)
    x, y, w, h = (int(v) for v in stats[largest, :4])
    matte = cv2.GaussianBlur(cv2.dilate(blob, np.ones((5, 5), np.uint8)).astype(np.float32), (5, 5), 0)
    return np.clip(matte, 0, 1), (x, y, w, h)


def paste_streak(
    image: np.ndarray,
    background: np.ndarray,
    offsets: list[tuple[int, int]],
    noise_sigma: float = 2.0,
    seed: int = 0,
) -> tuple[np.ndarray, list[Box]]:
    """A clip of the streak of ``image`` moved by each of ``offsets`` over ``background``.

    Args:
        image, background: (H, W, 3) uint8, a blurred frame and its clean background.
        offsets: per frame, the (dx, dy) pixels the streak moves by; the streak must stay in
            the frame.
        noise_sigma: Gaussian noise added to every frame, in grey levels (0-255).
        seed: the noise's seed.

    Returns:
        (F, H, W, 3) uint8 frames and each frame's streak box (x, y, w, h).
    """
    matte, (x, y, w, h) = streak_matte(image, background)
    layer = (image.astype(np.float32) - background.astype(np.float32)) * matte[..., None]
    height, width = background.shape[:2]
    rng = np.random.default_rng(seed)
    frames, boxes = [], []
    for dx, dy in offsets:
        if not (0 <= x + dx <= width - w and 0 <= y + dy <= height - h):
            raise ValueError(f"offset {(dx, dy)} moves the streak out of the frame")
        shift = np.float32([[1, 0, dx], [0, 1, dy]])
        moved = cv2.warpAffine(layer, shift, (width, height), flags=cv2.INTER_NEAREST)
        frame = background.astype(np.float32) + moved + rng.normal(0, noise_sigma, background.shape)
        frames.append(np.clip(np.round(frame), 0, 255).astype(np.uint8))
        boxes.append((x + dx, y + dy, w, h))
    return np.stack(frames), boxes
