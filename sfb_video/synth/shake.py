"""A camera that moves: a still clip's frames shaken as a hand holds a phone, or panned.

Each frame k is the still frame seen through a camera moved by a similarity S_k (a shift and a
turn about the frame's centre): shaken[k](S_k p) = still[k](p). The transforms are seeded, so a
shaken clip is as reproducible as the clip. What the moved camera sees beyond the still frame's
border is the border mirrored, as a real camera would see more of the scene; keep pans short
(a pan beyond the frame is better cut from a wider image, :func:`pan_crops`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np


def similarity(shift: tuple[float, float], turn_deg: float, size: tuple[int, int]) -> np.ndarray:
    """(3, 3) turn by ``turn_deg`` about the centre of a ``size`` = (width, height) frame, then
    shift by ``shift`` (pixels)."""
    width, height = size
    cx, cy = (width - 1) / 2, (height - 1) / 2
    c, s = math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg))
    return np.array(
        [
            [c, -s, cx - c * cx + s * cy + shift[0]],
            [s, c, cy - s * cx - c * cy + shift[1]],
            [0.0, 0.0, 1.0],
        ]
    )


def shake_transforms(
    frames: int,
    size: tuple[int, int],
    seed: int,
    max_shift_px: float = 6.0,
    max_turn_deg: float = 0.7,
    pan_px: float = 0.0,
) -> np.ndarray:
    """(F, 3, 3) seeded camera moves, S_k: still pixels -> shaken pixels.

    Each frame shakes independently by up to ``max_shift_px`` and ``max_turn_deg``; ``pan_px``
    adds a steady drift of that many pixels a frame in a seeded direction.
    """
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0, 2 * math.pi)
    drift = pan_px * np.array([math.cos(angle), math.sin(angle)])
    out = []
    for k in range(frames):
        shift = rng.uniform(-max_shift_px, max_shift_px, 2) + k * drift
        out.append(similarity((float(shift[0]), float(shift[1])), float(rng.uniform(-1, 1) * max_turn_deg), size))
    return np.stack(out)


def from_first(transforms: np.ndarray) -> np.ndarray:
    """(F, 3, 3) the same moves with the first frame's taken off (S_0^-1 S_k): the first frame is
    the still one, so a fit in its coordinates compares with the still clip's truth."""
    return np.stack([np.linalg.inv(transforms[0]) @ t for t in transforms])


def shake_frames(frames: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """(F, H, W, C) frames (any dtype cv2 warps) as the moved cameras ``transforms`` see them."""
    height, width = frames.shape[1:3]
    return np.stack(
        [
            cv2.warpAffine(f, t[:2], (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
            for f, t in zip(frames, transforms, strict=True)
        ]
    )


def true_to_reference(transforms: np.ndarray, reference: int = 0) -> np.ndarray:
    """(F, 3, 3) what registration should find: each shaken frame's pixels to the reference
    frame's, S_ref S_k^-1."""
    return np.stack([transforms[reference] @ np.linalg.inv(t) for t in transforms])


def pan_crops(image: np.ndarray, size: tuple[int, int], step_px: tuple[float, float], frames: int) -> np.ndarray:
    """(F, h, w, C) windows of ``size`` = (w, h) cut from a wider ``image``, the k-th shifted by
    k * ``step_px`` from the top left: a camera panning across a scene larger than its frame."""
    width, height = size
    out = []
    for k in range(frames):
        move = np.array([[1.0, 0.0, -k * step_px[0]], [0.0, 1.0, -k * step_px[1]]])
        out.append(cv2.warpAffine(image, move, (width, height), flags=cv2.INTER_LINEAR))
    return np.stack(out)
