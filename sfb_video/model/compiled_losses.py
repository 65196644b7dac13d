"""The loss terms as compiled CPU passes, with their derivatives written out.

Each term is a few lines of tensor operations in :mod:`sfb_video.model.losses` (the formulas,
and the path on other devices), but autograd's graph of their slices, gathers and reductions
cost ~2.5 ms of a ~20 ms fit step on two cores for microseconds of arithmetic. Here each is one
compiled pass forward and one backward; the tests check both against the tensor formulas and
finite differences.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from sfb_video.render import kernels


def _tv_forward(texture: np.ndarray) -> float:
    channels, height, width = texture.shape
    down, right = 0.0, 0.0
    for c in range(channels):
        for y in range(height):
            for x in range(width):
                if y + 1 < height:
                    down += abs(texture[c, y + 1, x] - texture[c, y, x])
                if x + 1 < width:
                    right += abs(texture[c, y, x + 1] - texture[c, y, x])
    return down / max(channels * (height - 1) * width, 1) + right / max(channels * height * (width - 1), 1)


def _tv_backward(texture: np.ndarray, grad: float, out: np.ndarray) -> None:
    channels, height, width = texture.shape
    down = grad / max(channels * (height - 1) * width, 1)
    right = grad / max(channels * height * (width - 1), 1)
    # Each texel gathers the signs of its four differences (sign(0) = 0, as autograd's
    # derivative of abs) into its own element: written as additions scattered into its
    # neighbours this pass took 3.5x the forward pass. The four are added in the order the
    # scattered version added them, rounded to ``out``'s type at each, so that a fit's result is
    # the same to the last bit (a fit is chaotic enough that a last-bit change moves its result).
    for c in range(channels):
        for y in range(height):
            for x in range(width):
                v = texture[c, y, x]
                out[c, y, x] = 0.0
                if y > 0:
                    d = v - texture[c, y - 1, x]
                    out[c, y, x] += ((d > 0) - (d < 0)) * down
                if x > 0:
                    d = v - texture[c, y, x - 1]
                    out[c, y, x] += ((d > 0) - (d < 0)) * right
                if y + 1 < height:
                    d = texture[c, y + 1, x] - v
                    out[c, y, x] -= ((d > 0) - (d < 0)) * down
                if x + 1 < width:
                    d = texture[c, y, x + 1] - v
                    out[c, y, x] -= ((d > 0) - (d < 0)) * right


def _laplacian_forward(vertices: np.ndarray, edges: np.ndarray, lap: np.ndarray, inverse: np.ndarray) -> float:
    count = vertices.shape[0]
    degree = np.zeros(count)
    lap[:] = 0
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        degree[i] += 1
        degree[j] += 1
        for c in range(3):
            lap[i, c] -= vertices[j, c]
            lap[j, c] -= vertices[i, c]
    total = 0.0
    for v in range(count):
        inverse[v] = 1.0 / max(degree[v], 1.0)
        for c in range(3):
            lap[v, c] = vertices[v, c] + lap[v, c] * inverse[v]
            total += lap[v, c] * lap[v, c]
    return total / count


def _laplacian_backward(lap: np.ndarray, inverse: np.ndarray, edges: np.ndarray, grad: float, out: np.ndarray) -> None:
    # L = I - D^-1 A with A symmetric: the gradient (2 / V) L^T L v is y - A D^-1 y, y = (2 / V) L v.
    scale = 2.0 * grad / lap.shape[0]
    for v in range(lap.shape[0]):
        for c in range(3):
            out[v, c] = scale * lap[v, c]
    for e in range(edges.shape[0]):
        i, j = edges[e, 0], edges[e, 1]
        for c in range(3):
            out[i, c] -= scale * lap[j, c] * inverse[j]
            out[j, c] -= scale * lap[i, c] * inverse[i]


def _iou_forward(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    inter, union = 0.0, 0.0
    for y in range(a.shape[0]):
        for x in range(a.shape[1]):
            ab = a[y, x] * b[y, x]
            inter += ab
            union += a[y, x] + b[y, x] - ab
    return inter, union


def _iou_backward(a: np.ndarray, inter: float, union: float, grad: float, out: np.ndarray) -> None:
    # d(I / U)/db = (a U - I (1 - a)) / U^2; below the floor U is a constant (clamp_min's derivative).
    floor = union < 1e-8
    for y in range(a.shape[0]):
        for x in range(a.shape[1]):
            if floor:
                out[y, x] = grad * a[y, x] / 1e-8
            else:
                out[y, x] = grad * (a[y, x] * union - inter * (1 - a[y, x])) / (union * union)


if kernels.njit is not None:
    _iou_forward = kernels.compile_kernel(_iou_forward)
    _iou_backward = kernels.compile_kernel(_iou_backward)
    _tv_forward = kernels.compile_kernel(_tv_forward)
    _tv_backward = kernels.compile_kernel(_tv_backward)
    _laplacian_forward = kernels.compile_kernel(_laplacian_forward)
    _laplacian_backward = kernels.compile_kernel(_laplacian_backward)


class _TextureTV(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, texture: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        texture = texture.detach().contiguous()
        ctx.save_for_backward(texture)
        return torch.tensor(_tv_forward(texture.numpy()), dtype=texture.dtype)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        (texture,) = ctx.saved_tensors
        out = torch.empty_like(texture)
        _tv_backward(texture.numpy(), float(grad), out.numpy())
        return out


class _Laplacian(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, vertices: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        vertices, edges = vertices.detach().contiguous(), edges.contiguous()
        lap, inverse = torch.empty_like(vertices), torch.empty(vertices.shape[0], dtype=vertices.dtype)
        loss = _laplacian_forward(vertices.numpy(), edges.numpy(), lap.numpy(), inverse.numpy())
        ctx.save_for_backward(lap, inverse, edges)
        return torch.tensor(loss, dtype=vertices.dtype)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor, None]:  # type: ignore[override]
        lap, inverse, edges = ctx.saved_tensors
        out = torch.empty_like(lap)
        _laplacian_backward(lap.numpy(), inverse.numpy(), edges.numpy(), float(grad), out.numpy())
        return out, None


class _SoftIoU(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        a, b = a.detach().contiguous(), b.detach().contiguous()
        inter, union = _iou_forward(a.numpy(), b.numpy())
        ctx.save_for_backward(a)
        ctx.sums = inter, union
        return torch.tensor(inter / max(union, 1e-8), dtype=b.dtype)

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[None, torch.Tensor]:  # type: ignore[override]
        (a,) = ctx.saved_tensors
        out = torch.empty_like(a)
        _iou_backward(a.numpy(), *ctx.sums, float(grad), out.numpy())
        return None, out


def texture_tv(texture: torch.Tensor) -> torch.Tensor:
    """:func:`sfb_video.model.losses.texture_tv` of a (3, Ht, Wt) texture."""
    return _TextureTV.apply(texture)


def laplacian(vertices: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """:func:`sfb_video.model.losses.laplacian` of (V, 3) vertices over (E, 2) edges."""
    return _Laplacian.apply(vertices, edges)


def soft_iou(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """:func:`sfb_video.model.losses.soft_iou` of two (H, W) masks, differentiable in ``b`` only."""
    return _SoftIoU.apply(a, b)
