"""Real-photo backgrounds from the images shipped inside scikit-image (no download needed).

A background is an (H, W, 3) uint8 RGB image: a random crop of one photo with the frame's
aspect ratio, resized with area averaging. Greyscale photos are repeated into three channels.
"""

from __future__ import annotations

import cv2
import numpy as np
import skimage.data

from sfb_video.errors import SfbError

# Photos stored in the scikit-image wheel itself; the others in skimage.data are fetched from
# the network on first use, which must never happen in a test.
BACKGROUND_NAMES = (
    "astronaut",
    "coffee",
    "chelsea",
    "rocket",
    "immunohistochemistry",
    "hubble_deep_field",
    "camera",
    "brick",
    "grass",
    "gravel",
)


def load_photo(name: str) -> np.ndarray:
    """The scikit-image photo ``name`` as an (h, w, 3) uint8 RGB array."""
    if name not in BACKGROUND_NAMES:
        raise SfbError(f"unknown background {name!r}; choose one of {', '.join(BACKGROUND_NAMES)}")
    image = np.asarray(getattr(skimage.data, name)())
    if image.ndim == 2:
        image = np.repeat(image[..., None], 3, axis=-1)
    return np.ascontiguousarray(image[..., :3], dtype=np.uint8)


def make_background(
    rng: np.random.Generator, width: int, height: int, name: str, crop_range: tuple[float, float]
) -> tuple[np.ndarray, str]:
    """A (height, width, 3) uint8 background and the name of the photo it was cut from.

    Args:
        rng: the source of the photo choice (when ``name`` is "random") and of the crop.
        name: one of ``BACKGROUND_NAMES`` or "random".
        crop_range: the crop's size as a fraction of the largest crop of the frame's aspect
            ratio that fits the photo, drawn uniformly from this range (1 = whole photo).
    """
    if width < 1 or height < 1:
        raise SfbError(f"background size must be positive, got {width} x {height}")
    lo, hi = crop_range
    if not 0 < lo <= hi <= 1:
        raise SfbError(f"crop_range must satisfy 0 < lo <= hi <= 1, got {crop_range}")
    if name == "random":
        name = BACKGROUND_NAMES[int(rng.integers(len(BACKGROUND_NAMES)))]
    photo = load_photo(name)
    ph, pw = photo.shape[:2]
    aspect = width / height
    full_w = min(pw, ph * aspect)
    scale = rng.uniform(lo, hi)
    crop_w = max(1, round(full_w * scale))
    crop_h = max(1, min(ph, round(crop_w / aspect)))
    x0 = int(rng.integers(0, pw - crop_w + 1))
    y0 = int(rng.integers(0, ph - crop_h + 1))
    crop = photo[y0 : y0 + crop_h, x0 : x0 + crop_w]
    shrink = crop_w >= width
    resized = cv2.resize(crop, (width, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return np.ascontiguousarray(resized, dtype=np.uint8), name
