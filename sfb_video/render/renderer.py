"""The mesh renderer: rasterise, then shade (the split of PyTorch3D's MeshRenderer)."""

from __future__ import annotations

from collections.abc import Callable

import torch

from sfb_video.config import RenderConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.model.formation import blend
from sfb_video.render import fused
from sfb_video.render.fragments import Fragments, PixelLists
from sfb_video.render.rasterizer import find_pixels, pixel_unit, project_checked, rasterize
from sfb_video.render.shader import RenderOutput, check_texture, shade

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
        if self._compiled(vertices, texture):
            rgb, alpha, lists = self._fused(vertices, topology, texture, None)
            return RenderOutput(rgb=rgb, alpha=alpha, depth=lists.zbuf, face_idx=lists.face_idx)
        fragments = self.rasterizer(vertices, topology, self.camera, self.settings)
        return shade(fragments, topology, texture, self.settings.sigma_inv)

    def blurred(
        self, vertices: torch.Tensor, topology: MeshTopology, texture: torch.Tensor, background: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The T renders composited over a (3, H, W) background (no gradient): the blurred image
        (3, H, W) of :func:`~sfb_video.model.formation.blend` and the silhouettes
        (T, 1, H, W), without the T colour images in between where the compiled passes serve."""
        if self._compiled(vertices, texture):
            image, alpha, _ = self._fused(vertices, topology, texture, background)
            return image, alpha
        out = self(vertices, topology, texture)
        return blend(out.rgb, out.alpha, background), out.alpha

    def _compiled(self, vertices: torch.Tensor, texture: torch.Tensor) -> bool:
        return self.rasterizer is rasterize and fused.available(vertices, texture)

    def _fused(
        self, vertices: torch.Tensor, topology: MeshTopology, texture: torch.Tensor, background: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor, PixelLists]:
        # The same renderer with its differentiable half compiled (sfb_video.render.fused).
        check_texture(texture)
        uv, depth, topo = project_checked(vertices, topology, self.camera, self.settings)
        lists = find_pixels(uv.detach(), depth.detach(), topo, self.camera, self.settings)
        unit = pixel_unit(self.camera)
        colour, alpha = fused.shade_lists(uv, depth, lists, topo, texture, self.settings.sigma_inv, unit, background)
        return colour, alpha, lists
