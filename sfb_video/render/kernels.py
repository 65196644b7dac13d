"""Compiled CPU loops for the rasteriser's two searches that need no gradient.

Which face is nearest at a pixel, and which contour edge is closest to a pixel outside the
silhouette, are plain loops over a few thousand triangles and edges writing into a z-buffer.
In eager PyTorch they cost a dozen tensor operations over ~300k candidate (pixel, face) and
(pixel, edge) pairs each step (benchmarks/RESULTS.md, "Renderer speed"); compiled by numba
(a PyPI wheel, no compiler needed on the user's machine) they are single passes over the same
pairs. They follow the tensor versions in ``rasterizer`` rule for rule (pixel centres, span
rounding, ties to the later candidate), which stay in use on CUDA and where numba is missing;
they take float32 (the fitter's precision) and round as the tensor version does, so both
find the same pixels and faces; float64 renders (the gradient tests) take the tensor version.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

log = logging.getLogger(__name__)

try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is a dependency; a broken install falls back
    njit = None
    log.info("numba is not importable: the rasteriser's searches run as tensor operations (slower)")


def available(points: torch.Tensor) -> bool:
    """Whether the compiled searches serve ``points``: float32 on the CPU, with numba."""
    return njit is not None and points.device.type == "cpu" and points.dtype == torch.float32


def _nearest_faces(
    tri: np.ndarray, inv_z: np.ndarray, t_idx: np.ndarray, height: int, width: int, num_t: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel, the candidate face with the largest 1/z among those covering its centre.

    Args:
        tri: (K, 3, 2) float32 screen corners; inv_z: (K, 3) their 1/z; t_idx: (K,) render.

    Returns:
        pix: (P,) int64 flat index into T * H * W of covered pixels, ascending.
        cand: (P,) int64 the winning candidate; inv_z: (P,) float32 its 1/z there.
    """
    best = np.full(num_t * height * width, -np.inf, dtype=np.float32)
    owner = np.full(num_t * height * width, -1, dtype=np.int64)
    for k in range(tri.shape[0]):
        x0, y0 = tri[k, 0, 0], tri[k, 0, 1]
        d1x, d1y = tri[k, 1, 0] - x0, tri[k, 1, 1] - y0
        d2x, d2y = tri[k, 2, 0] - x0, tri[k, 2, 1] - y0
        w1, w2 = inv_z[k, 1] - inv_z[k, 0], inv_z[k, 2] - inv_z[k, 0]
        area = d1x * d2y - d1y * d2x
        a = (w1 * d2y - w2 * d1y) / area
        b = (w2 * d1x - w1 * d2x) / area
        c = inv_z[k, 0] - a * x0 - b * y0
        y_min = min(tri[k, 0, 1], tri[k, 1, 1], tri[k, 2, 1])
        y_max = max(tri[k, 0, 1], tri[k, 1, 1], tri[k, 2, 1])
        y_lo = max(math.ceil(y_min), 0)
        y_hi = min(math.floor(y_max), height - 1)
        base = t_idx[k] * height * width
        for y in range(y_lo, y_hi + 1):
            fy = np.float32(y)
            left, right = np.float32(np.inf), np.float32(-np.inf)
            for e in range(3):
                px, py = tri[k, e, 0], tri[k, e, 1]
                qx, qy = tri[k, (e + 1) % 3, 0], tri[k, (e + 1) % 3, 1]
                dy = qy - py
                if dy == 0:
                    continue
                s = (fy - py) / dy
                if s < 0 or s > 1:
                    continue
                x = px + s * (qx - px)
                left, right = min(left, x), max(right, x)
            if left > right:
                continue
            x_lo = max(math.ceil(left), 0)
            x_hi = min(math.floor(right), width - 1)
            row = base + y * width
            for x in range(x_lo, x_hi + 1):
                value = a * np.float32(x) + b * fy + c
                if value >= best[row + x]:
                    best[row + x] = value
                    owner[row + x] = k
    pix = np.nonzero(owner >= 0)[0]
    return pix, owner[pix], best[pix]


def _nearest_edges(
    a: np.ndarray,
    b: np.ndarray,
    t_idx: np.ndarray,
    covered: np.ndarray,
    radius: float,
    height: int,
    width: int,
    num_t: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Per uncovered pixel within ``radius`` of a contour edge, the closest edge.

    Args:
        a, b: (E, 2) float32 edge ends in pixels; t_idx: (E,) render; covered: (T * H * W,).

    Returns:
        pix: (Q,) int64 flat pixel index, ascending; edge: (Q,) int64 the closest edge.
    """
    best = np.full(num_t * height * width, np.inf, dtype=np.float32)
    owner = np.full(num_t * height * width, -1, dtype=np.int64)
    r2 = np.float32(radius * radius)
    for k in range(a.shape[0]):
        ax, ay, bx, by = a[k, 0], a[k, 1], b[k, 0], b[k, 1]
        abx, aby = bx - ax, by - ay
        length2 = max(abx * abx + aby * aby, np.float32(1e-20))
        x_lo = max(math.ceil(min(ax, bx) - radius), 0)
        x_hi = min(math.floor(max(ax, bx) + radius), width - 1)
        y_lo = max(math.ceil(min(ay, by) - radius), 0)
        y_hi = min(math.floor(max(ay, by) + radius), height - 1)
        base = t_idx[k] * height * width
        for y in range(y_lo, y_hi + 1):
            py = np.float32(y)
            for x in range(x_lo, x_hi + 1):
                key = base + y * width + x
                if covered[key]:
                    continue
                px = np.float32(x)
                lam = min(max(((px - ax) * abx + (py - ay) * aby) / length2, np.float32(0)), np.float32(1))
                dx, dy = px - (ax + lam * abx), py - (ay + lam * aby)
                d2 = dx * dx + dy * dy
                if d2 <= r2 and d2 <= best[key]:
                    best[key] = d2
                    owner[key] = k
    pix = np.nonzero(owner >= 0)[0]
    return pix, owner[pix]


def _compile(function: Callable[..., Any]) -> Callable[..., Any]:
    # The on-disk cache saves the ~1 s compile per process; where no cache folder is writable
    # (a read-only install and home), numba refuses cache=True and it compiles every time.
    try:
        return njit(cache=True, nogil=True, error_model="numpy")(function)
    except RuntimeError:
        return njit(nogil=True, error_model="numpy")(function)


if njit is not None:
    _nearest_faces = _compile(_nearest_faces)
    _nearest_edges = _compile(_nearest_edges)


def nearest_faces(
    tri: torch.Tensor, inv_z: torch.Tensor, t_idx: torch.Tensor, size: tuple[int, int, int]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`_nearest_faces` on (K, 3, 2) corners, (K, 3) 1/z and (K,) renders of (T, H, W)."""
    num_t, height, width = size
    pix, cand, best = _nearest_faces(
        tri.contiguous().numpy(), inv_z.contiguous().numpy(), t_idx.numpy(), height, width, num_t
    )
    return torch.from_numpy(pix), torch.from_numpy(cand), torch.from_numpy(best)


def nearest_edges(
    a: torch.Tensor,
    b: torch.Tensor,
    t_idx: torch.Tensor,
    covered: torch.Tensor,
    radius: float,
    size: tuple[int, int, int],
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`_nearest_edges` on (E, 2) edge ends and (E,) renders of (T, H, W)."""
    num_t, height, width = size
    pix, edge = _nearest_edges(
        a.contiguous().numpy(),
        b.contiguous().numpy(),
        t_idx.numpy(),
        covered.numpy(),
        float(radius),
        height,
        width,
        num_t,
    )
    return torch.from_numpy(pix), torch.from_numpy(edge)
