"""A recovered object (textured mesh + motion) and rendering it through any camera."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from sfb_video.config import RenderConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.geometry.pose import pose_vertices
from sfb_video.model.formation import exposure_times
from sfb_video.model.motion import Motion
from sfb_video.render import MeshRenderer, RenderOutput


@dataclass(frozen=True)
class ObjectState:
    """What a fit recovers for one frame.

    Attributes:
        vertices: (V, 3) mesh at unit scale.
        topology: faces, UVs and edges.
        texture: (3, Ht, Wt) texture map in [0, 1].
        motion: the pose at the start of the exposure and the motion during it.
    """

    vertices: torch.Tensor
    topology: MeshTopology
    texture: torch.Tensor
    motion: Motion

    def to(self, device: torch.device | str) -> ObjectState:
        """This state with every tensor on ``device``."""
        return ObjectState(
            self.vertices.to(device), self.topology.to(device), self.texture.to(device), self.motion.to(device)
        )

    def render(self, camera: PinholeCamera, taus: torch.Tensor, settings: RenderConfig) -> RenderOutput:
        """Render the object at exposure times ``taus`` (T,) through ``camera``."""
        rotations, positions = self.motion.at(taus)
        renderer = MeshRenderer(camera, settings)
        return renderer(pose_vertices(self.vertices, rotations, positions), self.topology, self.texture)

    def render_subframes(
        self, camera: PinholeCamera, background: torch.Tensor, n: int, settings: RenderConfig
    ) -> torch.Tensor:
        """(n, 3, H, W) sharp sub-frames (TSR): the formation model over [k / n, (k + 1) / n],
        each averaging ``settings.steps_per_subframe`` poses.

        Args:
            background: (3, H, W) matching ``camera``'s image size, or (n, 3, H, W): one per
                sub-frame (a farther object's sub-frames behind this one).
        """
        steps = settings.steps_per_subframe
        taus = exposure_times(n * steps, background.device).reshape(n, steps)
        backgrounds = background if background.dim() == 4 else background.expand(n, *background.shape)
        pairs = zip(backgrounds, taus, strict=True)
        return torch.stack([self.render_blurred(camera, b, t, settings) for b, t in pairs])

    def render_blurred(
        self, camera: PinholeCamera, background: torch.Tensor, taus: torch.Tensor | int, settings: RenderConfig
    ) -> torch.Tensor:
        """(3, H, W) the object blurred over exposure times ``taus`` (T,) (or that many evenly
        spaced over the whole exposure), composited over ``background``.

        Poses are rendered in batches of at most ``settings.max_batch_pixels`` pixels in all, so
        that memory stays bounded however large the image (an export at native resolution).
        """
        if isinstance(taus, int):
            taus = exposure_times(taus, background.device)
        batch = max(1, settings.max_batch_pixels // (camera.width * camera.height))
        premultiplied = torch.zeros_like(background)  # sum_t F_t * A_t
        coverage = torch.zeros_like(background[:1])  # sum_t A_t
        with torch.no_grad():
            for chunk in taus.split(batch):
                out = self.render(camera, chunk, settings)
                premultiplied += (out.rgb * out.alpha).sum(0)
                coverage += out.alpha.sum(0)
        # blend() of all T renders, from their sums.
        return premultiplied / len(taus) + (1 - coverage / len(taus)) * background

    def image_box(self, camera: PinholeCamera, samples: int = 17) -> tuple[int, int, int, int] | None:
        """(x, y, w, h) box of the pixels the object covers during the exposure, within
        ``camera``'s image (None: it is never in the image).

        A mesh's silhouette reaches no farther than its vertices, so the box is that of its
        posed vertices projected at ``samples`` instants of the exposure (pixel centres at
        integers): no render needed.
        """
        with torch.no_grad():
            rotations, positions = self.motion.at(torch.linspace(0, 1, samples, device=self.vertices.device))
            uv, depth = camera.project(pose_vertices(self.vertices, rotations, positions))
        uv = uv[depth > 0]
        if uv.numel() == 0:
            return None
        (u0, v0), (u1, v1) = torch.floor(uv.amin(0) + 0.5).tolist(), torch.floor(uv.amax(0) + 0.5).tolist()
        x0, y0 = max(0, int(u0)), max(0, int(v0))
        x1, y1 = min(camera.width - 1, int(u1)), min(camera.height - 1, int(v1))
        if x1 < x0 or y1 < y0:
            return None
        return x0, y0, x1 - x0 + 1, y1 - y0 + 1
