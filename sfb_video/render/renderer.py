"""The mesh renderer: rasterise, then shade (the split of PyTorch3D's MeshRenderer)."""

from __future__ import annotations

from collections.abc import Callable

import torch

from sfb_video.config import RenderConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.render.fragments import Fragments
from sfb_video.render.rasterizer import rasterize
from sfb_video.render.shader import RenderOutput, shade

Rasterizer = Callable[[torch.Tensor, MeshTopology, PinholeCamera, RenderConfig], Fragments]


class MeshRenderer:
    """Renders T poses of one textured mesh through one camera.

    Example:
        >>> from sfb_video.geometry.prototypes import load_prototype
        >>> verts, topo = load_prototype("sphere")
        >>> cam = PinholeCamera.from_fov(64, 48, 45.0)
        >>> out = MeshRenderer(cam)(verts[None] + torch.tensor([0.0, 0.0, 3.0]), topo, torch.rand(3, 8, 8))
        >>> out.rgb.shape, out.alpha.shape
        (torch.Size([1, 3, 48, 64]), torch.Size([1, 1, 48, 64]))
    """

    def __init__(
        self, camera: PinholeCamera, settings: RenderConfig | None = None, rasterizer: Rasterizer = rasterize
    ) -> None:
        self.camera = camera
        self.settings = settings or RenderConfig()
        self.rasterizer = rasterizer

    def __call__(self, vertices: torch.Tensor, topology: MeshTopology, texture: torch.Tensor) -> RenderOutput:
        """(T, V, 3) camera-space vertices and a (3, Ht, Wt) texture -> :class:`RenderOutput`."""
        fragments = self.rasterizer(vertices, topology, self.camera, self.settings)
        return shade(fragments, topology, texture, self.settings.sigma_inv)
