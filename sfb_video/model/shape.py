"""The textured, deformable mesh a fit recovers: a prototype plus per-vertex offsets.

Vertices are re-normalised to unit scale at every step (paper, "Normalization"): otherwise a
change in size could be explained by the mesh or by the depth alike. The texture lives behind
a sigmoid and starts uniform grey.
"""

from __future__ import annotations

import torch

from sfb_video.geometry import compiled
from sfb_video.geometry.mesh import MeshTopology, normalize_vertices
from sfb_video.render import kernels


class ShapeParams(torch.nn.Module):
    """Learnable vertex offsets and texture of one prototype.

    Args:
        prototype: (V, 3) prototype vertices at unit scale.
        topology: the prototype's faces, UVs and edges.
        texture_size: side of the square texture map.
        deform: whether the vertex offsets are optimised (the reference also fits without).
        learn_texture: whether the texture is optimised.
    """

    def __init__(
        self,
        prototype: torch.Tensor,
        topology: MeshTopology,
        texture_size: int,
        deform: bool,
        learn_texture: bool = True,
    ) -> None:
        super().__init__()
        self.topology = topology
        self.register_buffer("prototype", prototype.clone())
        self.offsets = torch.nn.Parameter(torch.zeros_like(prototype), requires_grad=deform)
        texture = torch.zeros(3, texture_size, texture_size)
        self.texture_logits = torch.nn.Parameter(texture, requires_grad=learn_texture)

    def vertices(self) -> torch.Tensor:
        """(V, 3) current vertices at unit scale."""
        raw = self.prototype + self.offsets
        return compiled.normalize_vertices(raw) if kernels.serves(raw) else normalize_vertices(raw)

    def texture(self) -> torch.Tensor:
        """(3, Ht, Wt) current texture in [0, 1]."""
        return torch.sigmoid(self.texture_logits)
