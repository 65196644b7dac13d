"""The shape and texture regularisers L_L and L_T, compiled on the CPU.

Each is a few lines of tensor operations (:func:`laplacian_tensors`, :func:`texture_tv_tensors`,
the reference and the path on other devices), but autograd's graph of their gathers, scatters
and slices cost ~2.5 ms of a ~20 ms fit step on two cores for microseconds of arithmetic. Here
each is one compiled pass forward and one backward with the derivative written out; the tests
check both against the tensor versions and finite differences.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from sfb_video.render import kernels


def texture_tv_tensors(texture: torch.Tensor) -> torch.Tensor:
    """L_T of a (3, Ht, Wt) texture as tensor operations (see :func:`texture_tv`)."""
    return (texture[:, 1:] - texture[:, :-1]).abs().mean() + (texture[:, :, 1:] - texture[:, :, :-1]).abs().mean()


def laplacian_tensors(vertices: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """L_L of (V, 3) vertices over (E, 2) edges as tensor operations (see :func:`laplacian`)."""
    i, j = edges[:, 0], edges[:, 1]
    total = torch.zeros_like(vertices).index_add(0, i, vertices[j]).index_add(0, j, vertices[i])
    degree = torch.zeros(vertices.shape[0], device=vertices.device, dtype=vertices.dtype)
    degree = degree.index_add(0, i, torch.ones_like(i, dtype=vertices.dtype)).index_add(
        0, j, torch.ones_like(j, dtype=vertices.dtype)
    )
    return (vertices - total / degree[:, None].clamp_min(1)).square().sum(-1).mean()


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
    out[:] = 0
    for c in range(channels):
        for y in range(height):
            for x in range(width):
                # sign(0) = 0, as autograd's derivative of abs.
                if y + 1 < height:
                    s = np.sign(texture[c, y + 1, x] - texture[c, y, x]) * down
                    out[c, y + 1, x] += s
                    out[c, y, x] -= s
                if x + 1 < width:
                    s = np.sign(texture[c, y, x + 1] - texture[c, y, x]) * right
                    out[c, y, x + 1] += s
                    out[c, y, x] -= s


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


if kernels.njit is not None:
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


def _compiled(tensor: torch.Tensor) -> bool:
    return kernels.njit is not None and tensor.device.type == "cpu" and tensor.dtype in (torch.float32, torch.float64)


def texture_tv(texture: torch.Tensor) -> torch.Tensor:
    """L_T: mean absolute difference between neighbouring texels in both directions (appendix,
    eq. 1) of a (3, Ht, Wt) texture."""
    return _TextureTV.apply(texture) if _compiled(texture) else texture_tv_tensors(texture)


def laplacian(vertices: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
    """L_L: mean over vertices of ||v_i - mean of its neighbours||^2 (appendix, eq. 2).

    The appendix sums over vertices; the mean keeps the paper's weight of 1000 independent of
    the vertex count (about 1.2k for the default prototype).

    Args:
        vertices: (V, 3); edges: (E, 2) undirected vertex edges.
    """
    return _Laplacian.apply(vertices, edges) if _compiled(vertices) else laplacian_tensors(vertices, edges)
