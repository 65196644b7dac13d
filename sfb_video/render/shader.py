"""Shading: turn fragments into colour from a texture map and a soft silhouette."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from sfb_video.errors import SfbError, check_finite
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.render.fragments import Fragments


@dataclass(frozen=True)
class RenderOutput:
    """What a render returns.

    Attributes:
        rgb: (T, 3, H, W) texture colour of the surface shown at each pixel; inside the
            silhouette the covering surface, in the band just outside the colour of the nearest
            contour point (so that rgb * alpha never darkens the outline), 0 elsewhere.
        alpha: (T, 1, H, W) soft silhouette in [0, 1]: 1 inside, exp(-sigma_inv * d^2) outside.
        depth: (T, H, W) depth of the covering surface, +inf where uncovered (no gradient).
        face_idx: (T, H, W) covering face, -1 where uncovered (no gradient).
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    face_idx: torch.Tensor


def check_texture(texture: torch.Tensor) -> None:
    """A texture is (3, Ht, Wt) and finite."""
    if texture.dim() != 3 or texture.shape[0] != 3:
        raise SfbError(f"texture must have shape (3, Ht, Wt), got {tuple(texture.shape)}")
    check_finite(texture, "texture")


def texture_coords(fragments: Fragments, face_uv_coords: torch.Tensor) -> torch.Tensor:
    """(P, 2) texture coordinates of the point shown at each listed pixel, from the (F, 3, 2)
    coordinates of each face corner."""
    return torch.bmm(fragments.bary[:, None, :], face_uv_coords[fragments.face]).squeeze(1)


def silhouette_values(fragments: Fragments, sigma_inv: float) -> torch.Tensor:
    """(P,) coverage of each listed pixel: 1 inside, exp(-sigma_inv * d^2) in the band."""
    return torch.where(fragments.inside, torch.ones_like(fragments.dist2), torch.exp(-sigma_inv * fragments.dist2))


def sample_texture(fragments: Fragments, face_uv_coords: torch.Tensor, texture: torch.Tensor) -> torch.Tensor:
    """Bilinear texture colour at every listed pixel.

    Args:
        fragments: rasteriser output for T renders of size (H, W).
        face_uv_coords: (F, 3, 2) texture coordinates of each face corner, in [0, 1].
        texture: (3, Ht, Wt) texture map.

    Returns:
        (T, 3, H, W) colours, 0 at pixels that show no face.
    """
    uv = texture_coords(fragments, face_uv_coords)
    # UV (0, 0) is the texture's top-left corner, which grid_sample calls (-1, -1). The grid is
    # made finite and clamped: grid_sample's CPU backward writes out of bounds on NaN coordinates.
    grid = torch.nan_to_num(2 * uv - 1).clamp(-1.0, 1.0).reshape(1, 1, -1, 2)
    colour = F.grid_sample(texture[None], grid, mode="bilinear", padding_mode="border", align_corners=False)
    return fragments.dense(colour[0, :, 0].T).permute(0, 3, 1, 2)


def soft_silhouette(fragments: Fragments, sigma_inv: float) -> torch.Tensor:
    """(T, 1, H, W) coverage: 1 inside, exp(-sigma_inv * d^2) in the band, 0 beyond."""
    return fragments.dense(silhouette_values(fragments, sigma_inv))[:, None]


def shade(fragments: Fragments, topology: MeshTopology, texture: torch.Tensor, sigma_inv: float) -> RenderOutput:
    """Colour, soft silhouette, depth and face index from ``fragments``."""
    check_texture(texture)
    face_uv = topology.face_uv_coords().to(texture.device, texture.dtype)
    return RenderOutput(
        rgb=sample_texture(fragments, face_uv, texture),
        alpha=soft_silhouette(fragments, sigma_inv),
        depth=fragments.zbuf,
        face_idx=fragments.face_idx,
    )
