"""The loss terms of Shape from Blur (paper, Sec. 3.1 and the appendix).

All images are (3, H, W) or (T, 1, H, W) in [0, 1]. Each term is a small function so that the
fitter's joint loss is a weighted sum a reader can check against the paper. On the CPU, the
terms whose autograd graphs cost more than their arithmetic run as compiled passes with the
same values and derivatives (:mod:`sfb_video.model.compiled_losses`); the tensor formulas here
are their reference.
"""

from __future__ import annotations

import torch

from sfb_video.model import compiled_losses as compiled
from sfb_video.render import kernels
from sfb_video.render.fused import swept


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
    region = swept(alpha[:, 0])
    if kernels.serves(mask, region):
        return 1 - compiled.soft_iou(mask.to(region.dtype), region)
    return 1 - soft_iou(mask, region)


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


def texture_tv(texture: torch.Tensor) -> torch.Tensor:
    """L_T: mean absolute difference between neighbouring texels in both directions (appendix,
    eq. 1) of a (3, Ht, Wt) texture."""
    if kernels.serves(texture):
        return compiled.texture_tv(texture)
    return (texture[:, 1:] - texture[:, :-1]).abs().mean() + (texture[:, :, 1:] - texture[:, :, :-1]).abs().mean()


def laplacian(vertices: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """L_L: mean over vertices of ||v_i - mean of its neighbours||^2 (appendix, eq. 2).

    The appendix sums over vertices; the mean keeps the paper's weight of 1000 independent of
    the vertex count (about 1.2k for the default prototype).

    Args:
        vertices: (V, 3); edges: (E, 2) undirected vertex edges.
    """
    if kernels.serves(vertices):
        return compiled.laplacian(vertices, edges)
    i, j = edges[:, 0], edges[:, 1]
    total = torch.zeros_like(vertices).index_add(0, i, vertices[j]).index_add(0, j, vertices[i])
    degree = torch.zeros(vertices.shape[0], device=vertices.device, dtype=vertices.dtype)
    degree = degree.index_add(0, i, torch.ones_like(i, dtype=vertices.dtype)).index_add(
        0, j, torch.ones_like(j, dtype=vertices.dtype)
    )
    return (vertices - total / degree[:, None].clamp_min(1)).square().sum(-1).mean()
