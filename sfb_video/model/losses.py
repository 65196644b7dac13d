"""The loss terms of Shape from Blur (paper, Sec. 3.1 and the appendix).

All images are (3, H, W) or (T, 1, H, W) in [0, 1]. Each term is a small function so that the
fitter's joint loss is a weighted sum a reader can check against the paper.
"""

from __future__ import annotations

import torch

from sfb_video.model.regularisers import laplacian, texture_tv
from sfb_video.render.fused import swept

__all__ = ["difference_loss", "image_loss", "laplacian", "silhouette_loss", "soft_iou", "texture_tv"]


def image_loss(image: torch.Tensor, rendered: torch.Tensor, roi: torch.Tensor | None = None) -> torch.Tensor:
    """L_I: absolute error between the input (3, H, W) and the reconstruction (3, H, W).

    Summed and divided by the pixel count of the region of interest ``roi`` (H, W) (as the
    reference does) rather than of the whole crop, so that its weight against the other terms
    does not depend on how much background the crop holds; the whole crop without ``roi``.
    """
    area = image.shape[-1] * image.shape[-2] if roi is None else float(roi.sum().clamp_min(1.0))
    return (image - rendered).abs().sum() / (image.shape[0] * area)


def soft_iou(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """IoU of real-valued masks (*, H, W) (appendix, eq. 3): |a b| / |a + b - a b|, per leading index."""
    inter = (a * b).flatten(-2).sum(-1)
    union = (a + b - a * b).flatten(-2).sum(-1)
    return inter / union.clamp_min(1e-8)


def difference_loss(mask: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """L_D: 1 - IoU between D (H, W) and the region the object sweeps, from alpha (T, 1, H, W).

    The appendix binarises the mean silhouette, [mean_t A_t > 0], i.e. the union of the
    silhouettes over the exposure; its differentiable form is 1 - prod_t (1 - A_t). (The soft
    mean itself would reward a static opaque blob over a streak, whose mean coverage is low.)
    """
    return 1 - soft_iou(mask, swept(alpha[:, 0]))


def silhouette_loss(masks: torch.Tensor, alpha: torch.Tensor) -> torch.Tensor:
    """L_S: 1 - mean over sub-frames of IoU(M_k, A_k).

    Args:
        masks: (N, H, W) sub-frame masks in time order (e.g. from DeFMO).
        alpha: (T, 1, H, W) soft silhouettes, T a multiple of N; each group of T / N time steps
            is averaged into the silhouette of its sub-frame.
    """
    n = masks.shape[0]
    grouped = alpha[:, 0].reshape(n, alpha.shape[0] // n, *alpha.shape[2:]).mean(1)
    return 1 - soft_iou(masks, grouped).mean()
