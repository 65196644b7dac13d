"""What the rasteriser finds per pixel, handed to the shader.

The lists are sparse: only pixels that show a face are listed, because a fast moving object
covers a small part of its crop and shading cost should follow the object, not the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class PixelLists:
    """Which pixels a render shows and what they show, found without gradient.

    Attributes:
        size: (T, H, W) of the renders.
        pix_in: (P,) flat index into T * H * W of the pixels inside the silhouette.
        candidates: (K, 2) (render, face) of every face that was rasterised.
        cand_in: (P,) the covering (nearest) face of each inside pixel, into ``candidates``.
        pix_out: (Q,) flat index of the band pixels just outside the silhouette.
        t_out: (Q,) their render; edge_out: (Q,) their nearest contour edge; side_out: (Q,)
            which of the edge's two faces (0 or 1) faces the camera.
        zbuf: (T, H, W) depth of the covering surface, +inf where nothing covers.
    """

    size: tuple[int, int, int]
    pix_in: torch.Tensor
    candidates: torch.Tensor
    cand_in: torch.Tensor
    pix_out: torch.Tensor
    t_out: torch.Tensor
    edge_out: torch.Tensor
    side_out: torch.Tensor
    zbuf: torch.Tensor

    @property
    def face_in(self) -> torch.Tensor:
        """(P,) the covering face of each inside pixel."""
        return self.candidates[self.cand_in, 1]

    @property
    def face_idx(self) -> torch.Tensor:
        """(T, H, W) covering face per pixel, -1 where the pixel centre is not covered."""
        out = torch.full((self.size[0] * self.size[1] * self.size[2],), -1, dtype=torch.long, device=self.zbuf.device)
        return out.index_copy(0, self.pix_in, self.face_in).reshape(self.size)


@dataclass(frozen=True)
class Fragments:
    """Per-pixel rasterisation result for T renders of one mesh.

    A pixel is *listed* when it is inside the silhouette (its covering face is the nearest one
    under the z-test) or in the band just outside it (within the distance where the soft
    silhouette is non-negligible; its face is the one on the near side of the closest contour
    edge, and its barycentrics those of the closest point on that edge).

    Attributes:
        size: (T, H, W) of the renders.
        pix: (P,) flat index into T * H * W of each listed pixel.
        face: (P,) face shown at each listed pixel.
        bary: (P, 3) perspective-correct barycentric weights of the point shown, in ``face``;
            differentiable w.r.t. the vertices.
        inside: (P,) True where the pixel centre is covered by the mesh.
        dist2: (P,) squared distance from the pixel centre to the silhouette in normalised image
            units (half the longer image side is 1), 0 inside; differentiable w.r.t. vertices.
        zbuf: (T, H, W) depth of the covering surface, +inf where nothing covers (no gradient).
    """

    size: tuple[int, int, int]
    pix: torch.Tensor
    face: torch.Tensor
    bary: torch.Tensor
    inside: torch.Tensor
    dist2: torch.Tensor
    zbuf: torch.Tensor

    def dense(self, values: torch.Tensor, fill: float = 0.0) -> torch.Tensor:
        """Scatter per-listed-pixel ``values`` (P, *C) into a (T, H, W, *C) tensor, differentiably."""
        out = values.new_full((self.size[0] * self.size[1] * self.size[2], *values.shape[1:]), fill)
        return out.index_copy(0, self.pix, values).reshape(*self.size, *values.shape[1:])

    @property
    def face_idx(self) -> torch.Tensor:
        """(T, H, W) covering face per pixel, -1 where the pixel centre is not covered."""
        face = torch.where(self.inside, self.face, torch.full_like(self.face, -1))
        return self.dense(face, fill=-1)
