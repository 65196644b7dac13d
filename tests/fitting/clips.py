"""What the window-fit tests hand a window: a generated clip's frames cropped on their true boxes."""

from __future__ import annotations

import numpy as np
import torch

from sfb_video.config import CropConfig
from sfb_video.crop import make_crop
from sfb_video.fitting.window import WindowFrame
from sfb_video.synth import SyntheticClip


def image_tensor(image: np.ndarray) -> torch.Tensor:
    """(3, H, W) float32 in [0, 1] of an (H, W, 3) uint8 image."""
    return torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float() / 255


def window_frames(clip: SyntheticClip, crop: CropConfig) -> list[WindowFrame]:
    """Every frame of ``clip`` as a window frame, cropped on its true box (the box its blob)."""
    background, frames = image_tensor(clip.scene.background), []
    for truth in clip.truth:
        x, y, w, h = truth.bbox
        blob = torch.zeros(clip.spec.height, clip.spec.width, dtype=torch.bool)
        blob[y : y + h, x : x + w] = True
        image = image_tensor(clip.frames[truth.index])
        frames.append(WindowFrame(truth.index, make_crop(image, background, truth.bbox, clip.camera, crop, blob)))
    return frames
