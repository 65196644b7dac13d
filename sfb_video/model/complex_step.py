"""Small parameter chains as one autograd node, differentiated by the complex step.

A motion model maps a dozen or two parameters to the T rotations and positions of an
exposure through ~70 tensor operations; on tiny tensors each costs 5-15 us forward and twice
that backward, ~3.8 ms a fit step in all. Here the chain is one compiled function evaluated
once on a batch: the parameters, and each parameter nudged by an imaginary step i h. For a
real-analytic f, Im f(x + i h e_k) / h = df/dx_k up to O(h^2) with no cancellation, so with
h = 1e-20 the Jacobian is exact to rounding (Squire and Trapp, 1998). The functions must
therefore be written with analytic operations only (no abs, no clamp, norms as sqrt of sums
of squares; branches decided on real parts).

The helpers below are the complex-safe scalar twins of :mod:`sfb_video.geometry.rotation`, to
be inlined into compiled chains; the tests check the chains built from them against the tensor
chains under autograd.
"""

from __future__ import annotations

import cmath
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch

from sfb_video.render import kernels

STEP = 1e-20

Chain = Callable[[np.ndarray], tuple[np.ndarray, ...]]
"""(B, N) complex parameter vectors -> outputs, each (B, *shape)."""


class _ComplexStep(torch.autograd.Function):
    # NumPy between the tensors: on arrays of a few dozen numbers its calls cost ~1 us, torch's ~10.
    @staticmethod
    def forward(ctx: Any, chain: Chain, *params: torch.Tensor) -> tuple[torch.Tensor, ...]:  # type: ignore[override]
        flat = np.concatenate([p.detach().numpy().ravel() for p in params])
        n = flat.shape[0]
        batch = np.empty((n + 1, n), dtype=np.complex128)
        batch[:] = flat
        batch[np.arange(1, n + 1), np.arange(n)] += 1j * STEP
        outs = chain(batch)
        # One (N, outputs) Jacobian: the backward is one product.
        ctx.jacobian = np.concatenate([out[1:].imag.reshape(n, -1) for out in outs], 1) / STEP
        ctx.shapes = [tuple(p.shape) for p in params]
        ctx.dtype = params[0].detach().numpy().dtype
        return tuple(torch.from_numpy(out[0].real.astype(ctx.dtype)) for out in outs)

    @staticmethod
    def backward(ctx: Any, *grads: torch.Tensor) -> tuple[torch.Tensor | None, ...]:  # type: ignore[override]
        total = ctx.jacobian @ np.concatenate([g.numpy().ravel() for g in grads])
        parts, start = [], 0
        for shape in ctx.shapes:
            size = math.prod(shape)
            parts.append(torch.from_numpy(total[start : start + size].reshape(shape).astype(ctx.dtype)))
            start += size
        return (None, *parts)


def complex_step(chain: Chain, params: Sequence[torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """``chain`` applied to the CPU tensors ``params`` (flattened and concatenated in order),
    as one autograd node whose backward is the Jacobian found by the complex step.

    Returns the chain's outputs at the parameters, each without the batch dimension, in the
    parameters' dtype.
    """
    return _ComplexStep.apply(chain, *params)


def rotation_from_quaternion(w: complex, x: complex, y: complex, z: complex, out: np.ndarray) -> None:
    """The (3, 3) rotation of the WXYZ quaternion (normalised here) into ``out``, as
    :func:`~sfb_video.geometry.rotation.quaternion_to_matrix`: I + 2 w [v]_x + 2 [v]_x^2 with
    [v]_x^2 = v v^T - (v.v) I."""
    norm = cmath.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    _rotation(1.0, 2.0 * w, 2.0, x, y, z, out)


def rotation_from_axis_angle(x: complex, y: complex, z: complex, out: np.ndarray) -> None:
    """The (3, 3) rotation of an axis-angle by Rodrigues' formula into ``out``, as
    :func:`~sfb_video.geometry.rotation.axis_angle_to_matrix` (its Taylor series near 0)."""
    angle2 = x * x + y * y + z * z
    if angle2.real < 1e-6:
        a, b = 1 - angle2 / 6, 0.5 - angle2 / 24
    else:
        angle = cmath.sqrt(angle2)
        a, b = cmath.sin(angle) / angle, (1 - cmath.cos(angle)) / angle2
    _rotation(1.0, a, b, x, y, z, out)


def _rotation(eye: float, a: complex, b: complex, x: complex, y: complex, z: complex, out: np.ndarray) -> None:
    # eye I + a [v]_x + b [v]_x^2, written out.
    dot = x * x + y * y + z * z
    out[0, 0] = eye + b * (x * x - dot)
    out[1, 1] = eye + b * (y * y - dot)
    out[2, 2] = eye + b * (z * z - dot)
    out[0, 1], out[1, 0] = -a * z + b * x * y, a * z + b * x * y
    out[0, 2], out[2, 0] = a * y + b * x * z, -a * y + b * x * z
    out[1, 2], out[2, 1] = -a * x + b * y * z, a * x + b * y * z


def cap_rotation(x: complex, y: complex, z: complex, max_angle: float) -> tuple[complex, complex, complex]:
    """An axis-angle of norm < ``max_angle``, as :func:`~sfb_video.model.motion.cap_rotation`."""
    if max_angle == 0:
        return 0j, 0j, 0j
    norm = cmath.sqrt(x * x + y * y + z * z + 1e-12)
    scale = max_angle * cmath.tanh(norm / max_angle) / norm
    return x * scale, y * scale, z * scale


if kernels.njit is not None:
    _rotation = kernels.compile_kernel(_rotation, inline=True)
    rotation_from_quaternion = kernels.compile_kernel(rotation_from_quaternion, inline=True)
    rotation_from_axis_angle = kernels.compile_kernel(rotation_from_axis_angle, inline=True)
    cap_rotation = kernels.compile_kernel(cap_rotation, inline=True)
