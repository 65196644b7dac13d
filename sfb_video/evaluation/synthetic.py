"""Fitting synthetic frames and scoring the fits against their ground truth.

Used by the fitter's tests and benchmark and by the demo, scored by
:mod:`sfb_video.evaluation.scoring` as the benchmark runner scores (3D measures compare the
rotation made during the exposure: the mesh's own orientation is arbitrary for a prototype).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from sfb_video.config import Config
from sfb_video.crop import Crop, make_crop
from sfb_video.evaluation.scoring import render_estimate, score_estimate
from sfb_video.fitting.frame import FitResult, fit_frame
from sfb_video.model.scene import ObjectState
from sfb_video.synth import SyntheticClip


@dataclass(frozen=True)
class FrameScore:
    """Accuracy of one fitted frame (see the module docstring).

    Attributes:
        tiou, psnr, ssim: benchmark measures on the tight box.
        translation_err: mean position error at the sub-frame mid-times, in object sizes.
        rotation_err_deg: angle between the estimated and true rotation during the exposure.
        mesh_err: mean bidirectional mesh distance, in unit-cube object sizes (paper, Sec. 5).
        image_loss: the fit's L_I.
        seconds: wall time of the fit.
        flipped: whether the estimate was reversed in time to match the truth.
    """

    tiou: float
    psnr: float
    ssim: float
    translation_err: float
    rotation_err_deg: float
    mesh_err: float
    image_loss: float
    seconds: float
    flipped: bool


def _image(array: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(array)).permute(2, 0, 1).float() / 255


def synthetic_crop(clip: SyntheticClip, index: int, config: Config) -> Crop:
    """The working crop of frame ``index`` around its true tight box (as the benchmark hands it)."""
    truth = clip.truth[index]
    if truth.bbox is None:
        raise ValueError(f"frame {index} has no object")
    return make_crop(_image(clip.frames[index]), _image(clip.scene.background), truth.bbox, clip.camera, config.crop)


def crop_masks(clip: SyntheticClip, index: int, crop: Crop) -> torch.Tensor:
    """The true sub-frame masks (N, h, w) of frame ``index``, cut and resized to ``crop``."""
    x, y, w, h = crop.box
    masks = torch.from_numpy(clip.truth[index].masks[:, y : y + h, x : x + w]).float()
    size = crop.image.shape[1:]
    return F.interpolate(masks[:, None], size=size, mode="bilinear", antialias=True, align_corners=False)[:, 0]


def score_state(
    state: ObjectState, clip: SyntheticClip, index: int, config: Config, may_flip: bool = True
) -> FrameScore:
    """Compare a recovered object of frame ``index`` with its ground truth.

    Args:
        may_flip: reverse the estimate in time where the benchmark would, for one frame; a
            video, whose direction the pipeline resolves, is scored without.
    """
    truth = clip.truth[index]
    x, y, w, h = truth.bbox
    background = clip.scene.background.astype(np.float64) / 255
    estimate = render_estimate(state, clip.camera, truth.bbox, background, clip.spec.num_subframes, config.render)
    expected = truth.subframes[:, y : y + h, x : x + w].astype(np.float64) / 255
    scores, flipped = score_estimate(
        state,
        estimate,
        expected,
        clip.camera,
        truth.centres,
        truth.radius_px,
        (truth.motion, clip.scene.mesh),
        may_flip,
    )
    return FrameScore(**scores, image_loss=float("nan"), seconds=float("nan"), flipped=flipped)


def score_fit(fit: FitResult, clip: SyntheticClip, index: int, config: Config) -> FrameScore:
    """Compare a single-frame fit of frame ``index`` with its ground truth."""
    score = score_state(fit.state, clip, index, config)
    return dataclasses.replace(score, image_loss=fit.losses["image"], seconds=fit.seconds)


def fit_synthetic_frame(
    clip: SyntheticClip, index: int, config: Config, use_true_masks: bool = False
) -> tuple[FitResult, FrameScore]:
    """Fit frame ``index`` of a synthetic clip from a cold start and score it.

    Args:
        use_true_masks: fit with L_S on the true sub-frame masks (standing in for DeFMO's)
            instead of L_D on the difference mask.
    """
    crop = synthetic_crop(clip, index, config)
    masks = crop_masks(clip, index, crop) if use_true_masks else None
    fit = fit_frame(crop, config.fit, config.render, masks=masks)
    return fit, score_fit(fit, clip, index, config)
