"""A recovered object (textured mesh + motion) and rendering it through any camera."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from sfb_video.config import RenderConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.geometry.pose import pose_vertices
from sfb_video.model.formation import composite, exposure_times, subframes
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

    def render(self, camera: PinholeCamera, taus: torch.Tensor, settings: RenderConfig) -> RenderOutput:
        """Render the object at exposure times ``taus`` (T,) through ``camera``."""
        rotations, positions = self.motion.at(taus)
        renderer = MeshRenderer(camera, settings)
        return renderer(pose_vertices(self.vertices, rotations, positions), self.topology, self.texture)

    def render_subframes(
        self, camera: PinholeCamera, background: torch.Tensor, n: int, steps_per_subframe: int, settings: RenderConfig
    ) -> torch.Tensor:
        """(n, 3, H, W) sharp sub-frames (TSR): the formation model over [k / n, (k + 1) / n].

        Args:
            background: (3, H, W) matching ``camera``'s image size.
        """
        taus = exposure_times(n * steps_per_subframe, background.device)
        with torch.no_grad():
            out = self.render(camera, taus, settings)
            return subframes(out.rgb, out.alpha, background, n)

    def render_blurred(
        self, camera: PinholeCamera, background: torch.Tensor, steps: int, settings: RenderConfig
    ) -> torch.Tensor:
        """(3, H, W) the whole exposure composited over ``background``."""
        taus = exposure_times(steps, background.device)
        with torch.no_grad():
            out = self.render(camera, taus, settings)
            return composite(out.rgb, out.alpha, background)
