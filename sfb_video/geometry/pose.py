"""Placing a unit-scale mesh in the camera frame at the T poses of one exposure."""

from __future__ import annotations

import torch

from sfb_video.geometry import compiled
from sfb_video.render import kernels


def pose_vertices(vertices: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor) -> torch.Tensor:
    """Rotate vertices about their centre of mass (the origin at unit scale), then translate.

    Args:
        vertices: (V, 3) mesh vertices at unit scale.
        rotations: (T, 3, 3) rotation at each time step.
        translations: (T, 3) camera-space position of the centre of mass at each time step.

    Returns:
        (T, V, 3) camera-space vertices.
    """
    if vertices.dim() == 2 and kernels.serves(vertices, rotations, translations):
        return compiled.pose_vertices(vertices, rotations, translations)
    return torch.einsum("tij,vj->tvi", rotations, vertices) + translations[:, None, :]
