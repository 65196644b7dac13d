"""Accuracy measures: the FMO deblurring benchmark's TIoU, PSNR and SSIM, and 3D errors.

Benchmark conventions (DESIGN.md): every image measure is taken on the tight box crop of the
sub-frames; PSNR comes from one MSE over all pixels, channels and sub-frames (peak 1, and 100
for identical images); SSIM is per sub-frame, averaged; TIoU is the mean over sub-frames of the
IoU of two discs of the ground-truth radius, at the estimated and the true centres. A single
frame does not tell which way time runs, so an estimate is flipped in time when that fits the
ground truth better.
"""

from __future__ import annotations

import math

import numpy as np
from skimage.metrics import structural_similarity


def psnr(estimate: np.ndarray, truth: np.ndarray) -> float:
    """PSNR in dB of (N, H, W, 3) sub-frames in [0, 1], from one MSE over all of them."""
    mse = float(np.mean((estimate.astype(np.float64) - truth.astype(np.float64)) ** 2))
    return 100.0 if mse == 0 else 10 * math.log10(1.0 / mse)


def ssim(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Mean over sub-frames of the SSIM of (N, H, W, 3) images in [0, 1] (scikit-image's)."""
    scores = [
        structural_similarity(e, t, channel_axis=-1, data_range=1.0)
        for e, t in zip(estimate.astype(np.float64), truth.astype(np.float64), strict=True)
    ]
    return float(np.mean(scores))


def disc_iou(distance: np.ndarray, radius: float) -> np.ndarray:
    """IoU of two discs of equal ``radius`` whose centres lie ``distance`` apart (any shape)."""
    d = np.clip(np.asarray(distance, dtype=np.float64) / (2 * radius), 0.0, 1.0)
    # Lens area of two unit-radius-r circles at distance 2 r d, over the disc area pi r^2.
    lens = (2 * np.arccos(d) - 2 * d * np.sqrt(1 - d**2)) / math.pi
    return lens / (2 - lens)


def tiou(centres: np.ndarray, truth: np.ndarray, radius: float) -> float:
    """Mean disc IoU of estimated (N, 2) and true (N, 2) sub-frame centres, in pixels."""
    return float(disc_iou(np.linalg.norm(centres - truth, axis=-1), radius).mean())


def best_direction(estimate: np.ndarray, truth: np.ndarray) -> bool:
    """True when the sub-frames (N, ...) fit ``truth`` better in reversed order."""
    forward = np.mean((estimate.astype(np.float64) - truth) ** 2)
    backward = np.mean((estimate[::-1].astype(np.float64) - truth) ** 2)
    return bool(backward < forward)


def translation_error(positions: np.ndarray, truth: np.ndarray) -> float:
    """Mean distance between estimated and true (N, 3) positions, in object sizes."""
    return float(np.linalg.norm(positions - truth, axis=-1).mean())


def rotation_error_deg(rotation: np.ndarray, truth: np.ndarray) -> float:
    """Angle in degrees between two (3, 3) rotations."""
    cos = (np.trace(rotation.T @ truth) - 1) / 2
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))
