"""A fit step's geometry (normalise, pose, project) as compiled CPU passes.

Each step normalises the mesh, places it at the T poses of the exposure and projects the T x V
vertices. As tensor operations (:func:`~sfb_video.geometry.mesh.normalize_vertices`,
:func:`~sfb_video.geometry.pose.pose_vertices`, :meth:`~sfb_video.geometry.camera.PinholeCamera.project`,
the formulas and the path on other devices) that is ~25 small operations and their autograd
graph, ~1.5 ms of a ~14 ms step on two cores; here each is one loop forward and one backward
with the derivative written out. The tests hold them to the formulas and to finite differences.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from sfb_video.geometry.camera import PinholeCamera
from sfb_video.render import kernels


def _normalize_forward(vertices: np.ndarray, out: np.ndarray) -> float:
    count = vertices.shape[0]
    mean = np.zeros(3)
    for v in range(count):
        for c in range(3):
            mean[c] += vertices[v, c]
    mean /= count
    square = 0.0
    for v in range(count):
        for c in range(3):
            out[v, c] = vertices[v, c] - mean[c]
            square += out[v, c] * out[v, c]
    rms = max(np.sqrt(square / count), 1e-12)
    for v in range(count):
        for c in range(3):
            out[v, c] *= 0.5 / rms
    return rms


def _normalize_backward(normalized: np.ndarray, rms: float, grad: np.ndarray, out: np.ndarray) -> None:
    # n = c / (2 r), r = sqrt(mean |c|^2): dn/dc = (I - n n^T * 4 / V) / (2 r); then centring.
    count = normalized.shape[0]
    dot = 0.0
    for v in range(count):
        for c in range(3):
            dot += grad[v, c] * normalized[v, c]
    mean = np.zeros(3)
    for v in range(count):
        for c in range(3):
            out[v, c] = (grad[v, c] - 4.0 * dot * normalized[v, c] / count) * (0.5 / rms)
            mean[c] += out[v, c]
    mean /= count
    for v in range(count):
        for c in range(3):
            out[v, c] -= mean[c]


def _pose_forward(vertices: np.ndarray, rotations: np.ndarray, translations: np.ndarray, out: np.ndarray) -> None:
    for t in range(rotations.shape[0]):
        for v in range(vertices.shape[0]):
            for i in range(3):
                out[t, v, i] = (
                    rotations[t, i, 0] * vertices[v, 0]
                    + rotations[t, i, 1] * vertices[v, 1]
                    + rotations[t, i, 2] * vertices[v, 2]
                    + translations[t, i]
                )


def _pose_backward(
    vertices: np.ndarray,
    rotations: np.ndarray,
    grad: np.ndarray,
    grad_vertices: np.ndarray,
    grad_rotations: np.ndarray,
    grad_translations: np.ndarray,
) -> None:
    grad_vertices[:] = 0
    for t in range(rotations.shape[0]):
        rot = np.zeros((3, 3))
        move = np.zeros(3)
        for v in range(vertices.shape[0]):
            for i in range(3):
                g = grad[t, v, i]
                move[i] += g
                for j in range(3):
                    rot[i, j] += g * vertices[v, j]
                    grad_vertices[v, j] += g * rotations[t, i, j]
        for i in range(3):
            grad_translations[t, i] = move[i]
            for j in range(3):
                grad_rotations[t, i, j] = rot[i, j]


def _project_forward(
    points: np.ndarray, fx: float, fy: float, cx: float, cy: float, uv: np.ndarray, depth: np.ndarray
) -> None:
    for t in range(points.shape[0]):
        for v in range(points.shape[1]):
            z = points[t, v, 2]
            uv[t, v, 0] = fx * points[t, v, 0] / z + cx
            uv[t, v, 1] = fy * points[t, v, 1] / z + cy
            depth[t, v] = z


def _project_backward(
    points: np.ndarray, fx: float, fy: float, grad_uv: np.ndarray, grad_depth: np.ndarray, out: np.ndarray
) -> None:
    # u = fx x / z + cx: du/dx = fx / z, du/dz = -(fx / z)(x / z); likewise v.
    for t in range(points.shape[0]):
        for v in range(points.shape[1]):
            inverse = 1.0 / points[t, v, 2]
            gx = grad_uv[t, v, 0] * fx * inverse
            gy = grad_uv[t, v, 1] * fy * inverse
            out[t, v, 0] = gx
            out[t, v, 1] = gy
            out[t, v, 2] = grad_depth[t, v] - (gx * points[t, v, 0] + gy * points[t, v, 1]) * inverse


if kernels.njit is not None:
    _normalize_forward = kernels.compile_kernel(_normalize_forward)
    _normalize_backward = kernels.compile_kernel(_normalize_backward)
    _pose_forward = kernels.compile_kernel(_pose_forward)
    _pose_backward = kernels.compile_kernel(_pose_backward)
    _project_forward = kernels.compile_kernel(_project_forward)
    _project_backward = kernels.compile_kernel(_project_backward)


class _Normalize(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, vertices: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        out = torch.empty_like(vertices)
        ctx.rms = _normalize_forward(vertices.detach().contiguous().numpy(), out.numpy())
        ctx.save_for_backward(out)
        return out

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        (normalized,) = ctx.saved_tensors
        out = torch.empty_like(normalized)
        _normalize_backward(normalized.numpy(), ctx.rms, grad.contiguous().numpy(), out.numpy())
        return out


class _Pose(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, vertices: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        vertices, rotations = vertices.detach().contiguous(), rotations.detach().contiguous()
        out = vertices.new_empty(rotations.shape[0], *vertices.shape)
        _pose_forward(vertices.numpy(), rotations.numpy(), translations.detach().contiguous().numpy(), out.numpy())
        ctx.save_for_backward(vertices, rotations)
        return out

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:  # type: ignore[override]
        vertices, rotations = ctx.saved_tensors
        outs = torch.empty_like(vertices), torch.empty_like(rotations), vertices.new_empty(rotations.shape[0], 3)
        _pose_backward(vertices.numpy(), rotations.numpy(), grad.contiguous().numpy(), *(o.numpy() for o in outs))
        return outs


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx: Any, points: torch.Tensor, camera: PinholeCamera) -> tuple[torch.Tensor, torch.Tensor]:  # type: ignore[override]
        points = points.detach().contiguous()
        uv, depth = points.new_empty(*points.shape[:2], 2), points.new_empty(points.shape[:2])
        _project_forward(points.numpy(), camera.fx, camera.fy, camera.cx, camera.cy, uv.numpy(), depth.numpy())
        ctx.save_for_backward(points)
        ctx.focal = camera.fx, camera.fy
        return uv, depth

    @staticmethod
    def backward(ctx: Any, grad_uv: torch.Tensor, grad_depth: torch.Tensor) -> tuple[torch.Tensor, None]:  # type: ignore[override]
        (points,) = ctx.saved_tensors
        out = torch.empty_like(points)
        args = (grad_uv.contiguous().numpy(), grad_depth.contiguous().numpy(), out.numpy())
        _project_backward(points.numpy(), *ctx.focal, *args)
        return out, None


def normalize_vertices(vertices: torch.Tensor) -> torch.Tensor:
    """:func:`~sfb_video.geometry.mesh.normalize_vertices` of (V, 3) vertices."""
    return _Normalize.apply(vertices)


def pose_vertices(vertices: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor) -> torch.Tensor:
    """:func:`~sfb_video.geometry.pose.pose_vertices`: (V, 3), (T, 3, 3), (T, 3) -> (T, V, 3)."""
    return _Pose.apply(vertices, rotations, translations)


def project(points: torch.Tensor, camera: PinholeCamera) -> tuple[torch.Tensor, torch.Tensor]:
    """:meth:`~sfb_video.geometry.camera.PinholeCamera.project` of (T, V, 3) points."""
    return _Project.apply(points, camera)
