"""Small scenes shared by the renderer tests."""

from __future__ import annotations

import torch

from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.geometry.prototypes import uv_sphere


def seamless_sphere(rings: int = 4, segments: int = 6) -> tuple[torch.Tensor, MeshTopology]:
    """A coarse sphere with one UV per vertex, so colour is continuous across every edge."""
    verts, topo = uv_sphere(rings, segments)
    uvs = (verts[:, :2] + 0.5).clamp(0, 1)
    return verts, MeshTopology.build(topo.faces, uvs, topo.faces)


def quad_filling_image(camera: PinholeCamera, depth: float) -> tuple[torch.Tensor, MeshTopology]:
    """A fronto-parallel square whose corners sit on the image's outer pixel edges."""
    w, h = camera.width, camera.height
    corners_px = torch.tensor([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    verts = camera.unproject(corners_px, torch.full((4,), depth))
    faces = torch.tensor([[0, 1, 2], [0, 2, 3]])
    uvs = torch.tensor([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    return verts, MeshTopology.build(faces, uvs, faces)
