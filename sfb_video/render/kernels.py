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

import functools
import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from sfb_video.interrupts import kernel_call

log = logging.getLogger(__name__)

try:
    from numba import njit, prange
except ImportError:  # pragma: no cover - numba is a dependency; a broken install falls back
    njit, prange = None, range
    log.info("numba is not importable: the rasteriser's searches run as tensor operations (slower)")


def available(points: torch.Tensor) -> bool:
    """Whether the compiled searches serve ``points``: float32 on the CPU, with numba."""
    return njit is not None and points.device.type == "cpu" and points.dtype == torch.float32


def serves(*tensors: torch.Tensor) -> bool:
    """Whether compiled passes that take float32 and float64 serve ``tensors``: all on the
    CPU, in one of those two types, with numba."""
    return njit is not None and all(
        t.device.type == "cpu" and t.dtype in (torch.float32, torch.float64) for t in tensors
    )


def _nearest_faces(
    uv: np.ndarray, depth: np.ndarray, faces: np.ndarray, closed: bool, min_area: float, height: int, width: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel, the face with the largest 1/z among those covering its centre.

    Args:
        uv: (T, V, 2) float32 pixels; depth: (T, V) float32; faces: (F, 3).
        closed: whether back faces can be skipped (they never win on a closed surface).
        min_area: faces whose projected doubled area is not above this are skipped.

    Returns:
        pix: (P,) int64 flat index into T * H * W of covered pixels, ascending.
        cand: (P,) int64 the winning candidate; inv_z: (P,) float32 its 1/z there.
        candidates: (K, 2) int64 (render, face) of every rasterised face, in (render, face)
            order; front: (T, F) bool, which faces face the camera.
    """
    num_t, num_f = uv.shape[0], faces.shape[0]
    best = np.empty(num_t * height * width, dtype=np.float32)
    owner = np.empty(num_t * height * width, dtype=np.int64)
    fill(best, -np.inf)
    fill(owner, -1)
    front = np.empty((num_t, num_f), dtype=np.bool_)
    keep = np.empty((num_t, num_f), dtype=np.bool_)
    min_area32 = np.float32(min_area)
    # The renders write disjoint parts of ``best`` and ``owner``: one per thread. Candidates are
    # numbered in (render, face) order, so each render's first number is counted beforehand.
    for t in prange(num_t):
        for f in range(num_f):
            a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
            d1x, d1y = uv[t, b, 0] - uv[t, a, 0], uv[t, b, 1] - uv[t, a, 1]
            d2x, d2y = uv[t, c, 0] - uv[t, a, 0], uv[t, c, 1] - uv[t, a, 1]
            area = d1x * d2y - d1y * d2x
            front[t, f] = area < 0
            keep[t, f] = abs(area) > min_area32 and (area < 0 or not closed)
    first = np.zeros(num_t + 1, dtype=np.int64)
    for t in range(num_t):
        first[t + 1] = first[t]
        for f in range(num_f):
            first[t + 1] += keep[t, f]
    candidates = np.empty((first[num_t], 2), dtype=np.int64)
    for t in prange(num_t):
        tri = np.empty((3, 2), dtype=np.float32)
        inv_z = np.empty(3, dtype=np.float32)
        k = first[t]
        for f in range(num_f):
            if not keep[t, f]:
                continue
            candidates[k, 0], candidates[k, 1] = t, f
            k += 1
            for i in range(3):
                tri[i, 0], tri[i, 1] = uv[t, faces[f, i], 0], uv[t, faces[f, i], 1]
            # Many faces of a fitted mesh are smaller than a pixel (14% of those kept hold no
            # pixel centre at the fitter's crops): skip them before their depth plane.
            if not _holds_centre(tri, height, width):
                continue
            for i in range(3):
                inv_z[i] = np.float32(1.0) / depth[t, faces[f, i]]
            _scan_face(tri, inv_z, t * height * width, k - 1, height, width, best, owner)
    pix = _claimed(owner)
    cand = np.empty(pix.shape[0], dtype=np.int64)
    inv_z_at = np.empty(pix.shape[0], dtype=np.float32)
    for n in range(pix.shape[0]):
        cand[n], inv_z_at[n] = owner[pix[n]], best[pix[n]]
    return pix, cand, inv_z_at, candidates, front


def fill(array: np.ndarray, value: float) -> None:
    """Set every element of the contiguous ``array`` to ``value``.

    Written as a loop on purpose: in a ``parallel`` kernel numba turns array expressions and
    ``np.full`` into parallel loops of their own, each a fork and join, and at the fitter's
    sizes those cost several times the work (the shading backward with empty pixel lists: 215
    us with them, 64 with loops). Inlined into :mod:`sfb_video.render.fused`'s passes: numba's
    cache watches only a kernel's own file, so after editing this or :func:`add_parts`, clear
    ``sfb_video/render/__pycache__/*.nbi`` (or touch fused.py).
    """
    flat = array.reshape(-1)
    for i in range(flat.shape[0]):
        flat[i] = value


def add_parts(target: np.ndarray, parts: np.ndarray) -> None:
    """target += parts[0] + parts[1] + ..., in that order (contiguous arrays; see :func:`fill`)."""
    flat = target.reshape(-1)
    rows = parts.reshape(parts.shape[0], -1)
    for c in range(rows.shape[0]):
        for i in range(flat.shape[0]):
            flat[i] += rows[c, i]


def _claimed(owner: np.ndarray) -> np.ndarray:
    """(N,) int64 the ascending indices where the flat ``owner`` is not -1 (see :func:`fill`)."""
    count = 0
    for i in range(owner.shape[0]):
        count += owner[i] >= 0
    indices = np.empty(count, dtype=np.int64)
    n = 0
    for i in range(owner.shape[0]):
        if owner[i] >= 0:
            indices[n] = i
            n += 1
    return indices


def _holds_centre(tri: np.ndarray, height: int, width: int) -> bool:
    """Whether the (3, 2) screen triangle's bounding box holds a pixel centre in the image (the
    scan of :func:`_scan_face` writes none otherwise).

    The rows are the scan's own. A span's ends are computed in float32 and can round past the
    box (-0.5 + (-1e-9 + 0.5) is 0.0), so the columns are widened by more than that rounding
    (about 3 * 2^-24 of the largest coordinate)."""
    x_min, x_max = min(tri[0, 0], tri[1, 0], tri[2, 0]), max(tri[0, 0], tri[1, 0], tri[2, 0])
    pad = 2.0**-20 * max(abs(x_min), abs(x_max), 1.0)
    x_lo = max(math.ceil(x_min - pad), 0)
    x_hi = min(math.floor(x_max + pad), width - 1)
    y_lo = max(math.ceil(min(tri[0, 1], tri[1, 1], tri[2, 1])), 0)
    y_hi = min(math.floor(max(tri[0, 1], tri[1, 1], tri[2, 1])), height - 1)
    return x_lo <= x_hi and y_lo <= y_hi


def _scan_face(
    tri: np.ndarray,
    inv_z: np.ndarray,
    base: int,
    k: int,
    height: int,
    width: int,
    best: np.ndarray,
    owner: np.ndarray,
) -> None:
    """Z-test candidate ``k``, the (3, 2) screen triangle ``tri`` with corner 1/z ``inv_z``, at
    the pixel centres in its scanline spans (render offset ``base``), keeping the nearest."""
    x0, y0 = tri[0, 0], tri[0, 1]
    d1x, d1y = tri[1, 0] - x0, tri[1, 1] - y0
    d2x, d2y = tri[2, 0] - x0, tri[2, 1] - y0
    w1, w2 = inv_z[1] - inv_z[0], inv_z[2] - inv_z[0]
    area = d1x * d2y - d1y * d2x
    a = (w1 * d2y - w2 * d1y) / area
    b = (w2 * d1x - w1 * d2x) / area
    c = inv_z[0] - a * x0 - b * y0
    y_min = min(tri[0, 1], tri[1, 1], tri[2, 1])
    y_max = max(tri[0, 1], tri[1, 1], tri[2, 1])
    y_lo = max(math.ceil(y_min), 0)
    y_hi = min(math.floor(y_max), height - 1)
    for y in range(y_lo, y_hi + 1):
        fy = np.float32(y)
        left, right = np.float32(np.inf), np.float32(-np.inf)
        for e in range(3):
            px, py = tri[e, 0], tri[e, 1]
            qx, qy = tri[(e + 1) % 3, 0], tri[(e + 1) % 3, 1]
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


def _nearest_edges(
    uv: np.ndarray,
    front: np.ndarray,
    edges: np.ndarray,
    edge_faces: np.ndarray,
    covered: np.ndarray,
    radius: float,
    height: int,
    width: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per uncovered pixel within ``radius`` of a contour edge, the closest edge.

    A contour edge lies between a front- and a back-facing face, or on an open mesh's boundary.

    Args:
        uv: (T, V, 2) float32 pixels; front: (T, F) bool; edges, edge_faces: (E, 2);
        covered: (T * H * W,) bool, pixels inside the silhouette.

    Returns:
        pix: (Q,) int64 flat pixel index, ascending; t_idx, edge: (Q,) int64 its render and
        closest contour edge; side: (Q,) int64 which face of the edge (0 or 1) faces the camera.
    """
    num_t = uv.shape[0]
    best = np.empty(num_t * height * width, dtype=np.float32)
    owner = np.empty(num_t * height * width, dtype=np.int64)
    fill(best, np.inf)
    fill(owner, -1)
    r2 = np.float32(radius * radius)
    for t in prange(num_t):  # disjoint parts of ``best`` and ``owner``: one render per thread
        for e in range(edges.shape[0]):
            has_two = edge_faces[e, 1] >= 0
            front0 = front[t, edge_faces[e, 0]]
            if has_two and front0 == front[t, edge_faces[e, 1]]:
                continue
            ax, ay = uv[t, edges[e, 0], 0], uv[t, edges[e, 0], 1]
            bx, by = uv[t, edges[e, 1], 0], uv[t, edges[e, 1], 1]
            abx, aby = bx - ax, by - ay
            length2 = max(abx * abx + aby * aby, np.float32(1e-20))
            x_lo = max(math.ceil(min(ax, bx) - radius), 0)
            x_hi = min(math.floor(max(ax, bx) + radius), width - 1)
            y_lo = max(math.ceil(min(ay, by) - radius), 0)
            y_hi = min(math.floor(max(ay, by) + radius), height - 1)
            base = t * height * width
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
                        owner[key] = t * edges.shape[0] + e
    pix = _claimed(owner)
    t_idx = np.empty(pix.shape[0], dtype=np.int64)
    edge = np.empty(pix.shape[0], dtype=np.int64)
    side = np.empty(pix.shape[0], dtype=np.int64)
    for n in range(pix.shape[0]):
        t_idx[n], edge[n] = owner[pix[n]] // edges.shape[0], owner[pix[n]] % edges.shape[0]
        side[n] = edge_faces[edge[n], 1] >= 0 and not front[t_idx[n], edge_faces[edge[n], 0]]
    return pix, t_idx, edge, side


def compile_kernel(function: Callable[..., Any], inline: bool = False, parallel: bool = False) -> Callable[..., Any]:
    """``function`` compiled by numba (cached on disk where a cache folder is writable), called
    as a :func:`~sfb_video.interrupts.kernel_call`; ``inline``: compiled into each compiled caller
    instead (small helpers); ``parallel``: its ``prange`` loops run on numba's threads."""
    options = {"nogil": True, "error_model": "numpy", "inline": "always" if inline else "never", "parallel": parallel}
    # The on-disk cache saves the ~1 s compile per process; where no cache folder is writable
    # (a read-only install and home), numba refuses cache=True and it compiles every time.
    try:
        compiled = njit(cache=True, **options)(function)
    except RuntimeError:
        compiled = njit(**options)(function)
    if inline:
        return compiled

    @functools.wraps(function)
    def call(*args: Any) -> Any:
        with kernel_call():
            return compiled(*args)

    return call


if njit is not None:
    _scan_face = compile_kernel(_scan_face, inline=True)
    fill = compile_kernel(fill, inline=True)
    add_parts = compile_kernel(add_parts, inline=True)
    _claimed = compile_kernel(_claimed, inline=True)
    _holds_centre = compile_kernel(_holds_centre, inline=True)
    _nearest_faces = compile_kernel(_nearest_faces, parallel=True)
    _nearest_edges = compile_kernel(_nearest_edges, parallel=True)


def nearest_faces(
    uv: torch.Tensor, depth: torch.Tensor, faces: torch.Tensor, closed: bool, min_area: float, size: tuple[int, int]
) -> tuple[torch.Tensor, ...]:
    """:func:`_nearest_faces` on (T, V, 2) pixels, (T, V) depths and (F, 3) faces; ``size`` (H, W)."""
    arrays = (a.contiguous().numpy() for a in (uv, depth, faces))
    return tuple(torch.from_numpy(a) for a in _nearest_faces(*arrays, closed, float(min_area), *size))


def nearest_edges(
    uv: torch.Tensor,
    front: torch.Tensor,
    edges: torch.Tensor,
    edge_faces: torch.Tensor,
    covered: torch.Tensor,
    radius: float,
    size: tuple[int, int],
) -> tuple[torch.Tensor, ...]:
    """:func:`_nearest_edges` on (T, V, 2) pixels, (T, F) front faces and the mesh's edges."""
    arrays = (a.contiguous().numpy() for a in (uv, front, edges, edge_faces, covered))
    return tuple(torch.from_numpy(a) for a in _nearest_edges(*arrays, float(radius), *size))
