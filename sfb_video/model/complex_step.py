"""Small parameter chains as one autograd node, differentiated by the complex step.

A motion model maps a dozen or two parameters to the T rotations and positions of an
exposure through ~70 tensor operations; on tiny tensors each costs 5-15 us forward and twice
that backward, ~3.8 ms a fit step in all. Here the chain is one NumPy function evaluated
once on a batch: the parameters, and each parameter nudged by an imaginary step i h. For a
real-analytic f, Im f(x + i h e_k) / h = df/dx_k up to O(h^2) with no cancellation, so with
h = 1e-20 the Jacobian is exact to rounding (Squire and Trapp, 1998). The functions must
therefore be written with analytic operations only (no abs, no clamp, norms as sqrt of sums
of squares; branches decided on real parts).

The formulas below are the complex-safe twins of :mod:`sfb_video.geometry.rotation` and
:meth:`~sfb_video.geometry.camera.PinholeCamera.unproject`; the tests check the chains built
from them against the torch chains under autograd.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

STEP = 1e-20

Chain = Callable[[np.ndarray], tuple[np.ndarray, ...]]
"""(B, N) complex parameter vectors -> outputs, each (B, *shape)."""


class _ComplexStep(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, chain: Chain, *params: torch.Tensor) -> tuple[torch.Tensor, ...]:  # type: ignore[override]
        flat = np.concatenate([p.detach().numpy().ravel() for p in params]).astype(np.complex128)
        n = flat.shape[0]
        batch = np.repeat(flat[None], n + 1, 0)
        batch[np.arange(1, n + 1), np.arange(n)] += 1j * STEP
        outs = chain(batch)
        # One (N, outputs) Jacobian: the backward is one product.
        ctx.jacobian = np.concatenate([out[1:].imag.reshape(n, -1) for out in outs], 1) / STEP
        ctx.sizes = [p.numel() for p in params]
        ctx.shapes = [p.shape for p in params]
        dtype = params[0].dtype
        return tuple(torch.from_numpy(out[0].real.astype(np.float64)).to(dtype) for out in outs)

    @staticmethod
    def backward(ctx: Any, *grads: torch.Tensor) -> tuple[torch.Tensor | None, ...]:  # type: ignore[override]
        flat = torch.cat([g.reshape(-1) for g in grads]).double().numpy()
        total = torch.from_numpy(ctx.jacobian @ flat).to(grads[0].dtype)
        return (None, *(part.view(shape) for part, shape in zip(total.split(ctx.sizes), ctx.shapes, strict=True)))


def complex_step(chain: Chain, params: Sequence[torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """``chain`` applied to the CPU tensors ``params`` (flattened and concatenated in order),
    as one autograd node whose backward is the Jacobian found by the complex step.

    Returns the chain's outputs at the parameters, each without the batch dimension, in the
    parameters' dtype.
    """
    return _ComplexStep.apply(chain, *params)


def skew(v: np.ndarray) -> np.ndarray:
    """(*, 3) -> (*, 3, 3) cross-product matrices."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = np.zeros_like(x)
    return np.stack((zero, -z, y, z, zero, -x, -y, x, zero), -1).reshape(*v.shape, 3)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(*, 4) WXYZ quaternions (normalised here) -> (*, 3, 3), as the torch twin."""
    q = q / np.sqrt((q * q).sum(-1, keepdims=True))
    k = skew(q[..., 1:])
    return np.eye(3) + 2 * (q[..., :1, None] * k + k @ k)


def axis_angle_to_matrix(omega: np.ndarray) -> np.ndarray:
    """(*, 3) axis-angle vectors -> (*, 3, 3) by Rodrigues' formula (Taylor series near 0)."""
    angle2 = (omega * omega).sum(-1)[..., None, None]
    small = angle2.real < 1e-6
    safe = np.where(small, 1.0, angle2)
    angle = np.sqrt(safe)
    a = np.where(small, 1 - angle2 / 6, np.sin(angle) / angle)
    b = np.where(small, 0.5 - angle2 / 24, (1 - np.cos(angle)) / safe)
    k = skew(omega)
    return np.eye(3) + a * k + b * (k @ k)


def cap_rotation(raw: np.ndarray, max_angle: float) -> np.ndarray:
    """(*, 3) -> (*, 3) axis-angles of norm < ``max_angle``, as the torch twin in ``motion``."""
    if max_angle == 0:
        return np.zeros_like(raw)
    norm = np.sqrt((raw * raw).sum(-1, keepdims=True) + 1e-12)
    return raw * (max_angle * np.tanh(norm / max_angle) / norm)


def unproject(
    u: np.ndarray, v: np.ndarray, depth: np.ndarray, fx: float, fy: float, cx: float, cy: float
) -> np.ndarray:
    """Pixels (u, v) at ``depth``, each (*,), -> (*, 3) camera points."""
    return np.stack(((u - cx) / fx * depth, (v - cy) / fy * depth, depth), -1)
