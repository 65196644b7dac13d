"""Differentiable 2D triangle and segment geometry shared by both rasterisers."""

from __future__ import annotations

import torch

MIN_AREA_PX2 = 1e-4
"""Faces whose projected (doubled) area is below this many square pixels are not rasterised.

Below it, float32 cancellation in the barycentric planes of pixels ~100 px from the origin can
make their sum vanish (infinite weights); such slivers cover no pixel centre in practice."""


def cross2(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """z component of the cross product of (*, 2) vectors."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def screen_barycentric(p: torch.Tensor, tri: torch.Tensor) -> torch.Tensor:
    """Screen-space barycentric coordinates of points ``p`` (*, 2) in triangles ``tri`` (*, 3, 2).

    Returns (*, 3) weights summing to one; all >= 0 exactly when ``p`` is inside, whatever the
    triangle's winding. Degenerate triangles give non-finite weights: callers drop them.
    """
    a, b, c = tri.unbind(-2)
    area = cross2(b - a, c - a)
    w0 = cross2(b - p, c - p) / area
    w1 = cross2(c - p, a - p) / area
    return torch.stack((w0, w1, 1 - w0 - w1), dim=-1)


def perspective_correct(bary: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
    """Turn screen-space weights (*, 3) into weights of the 3D point, given corner depths (*, 3).

    A point at screen weights l_i lies at 3D weights (l_i / z_i) / sum_j (l_j / z_j).
    """
    w = bary / depth
    return w / w.sum(-1, keepdim=True)


def segment_closest(p: torch.Tensor, a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Closest point of segments [a, b] to points ``p``, all (*, 2).

    Returns:
        lam: (*,) position of the closest point along the segment, in [0, 1].
        dist2: (*,) squared distance from ``p`` to it.
    """
    ab = b - a
    lam = ((p - a) * ab).sum(-1) / ab.square().sum(-1).clamp_min(1e-20)
    lam = lam.clamp(0.0, 1.0)
    closest = a + lam[..., None] * ab
    return lam, (p - closest).square().sum(-1)
