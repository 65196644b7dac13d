"""A slow, obviously correct rasteriser: every pixel against every face.

It is the test oracle for :func:`sfb_video.render.rasterizer.rasterize`: same outputs, same
gradients, computed by brute force. It needs (H * W * F) memory per render: tiny images only.
"""

from __future__ import annotations

import math

import torch

from sfb_video.config import RenderConfig
from sfb_video.errors import check_in_front
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology, check_vertices
from sfb_video.render.barycentric import (
    MIN_AREA_PX2,
    cross2,
    perspective_correct,
    screen_barycentric,
    segment_closest,
)
from sfb_video.render.fragments import Fragments
from sfb_video.render.rasterizer import band_radius_px, pixel_unit


def rasterize_reference(
    vertices: torch.Tensor, topology: MeshTopology, camera: PinholeCamera, settings: RenderConfig
) -> Fragments:
    """Brute-force twin of ``rasterize``: (T, V, 3) camera-space vertices -> :class:`Fragments`.

    Outside the silhouette the distance is the minimum over *all* faces of the point-triangle
    distance (not over contour edges), which is an independent definition of the same quantity.
    """
    check_vertices(vertices, topology)
    uv, depth = camera.project(vertices)
    check_in_front(depth.detach(), settings.near)
    num_t, height, width = vertices.shape[0], camera.height, camera.width
    faces = topology.faces
    ys, xs = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    pixels = torch.stack((xs, ys), -1).reshape(-1, 1, 2).to(uv.dtype)  # (HW, 1, 2)
    radius2 = band_radius_px(camera, settings) ** 2
    parts: list[tuple[torch.Tensor, ...]] = []
    zbuf = torch.full((num_t, height * width), math.inf, dtype=uv.dtype)
    for t in range(num_t):
        tri = uv[t, faces]  # (F, 3, 2)
        z_corner = depth[t, faces]  # (F, 3)
        area = cross2(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        bary = screen_barycentric(pixels, tri[None])  # (HW, F, 3)
        inside = (bary.detach() >= 0).all(-1) & (area.detach().abs() > MIN_AREA_PX2)
        z = 1.0 / (bary.detach() / z_corner.detach()).sum(-1)
        z = torch.where(inside, z, torch.full_like(z, math.inf))
        zmin, face_in = z.min(1)
        covered = torch.isfinite(zmin)
        pix = torch.nonzero(covered).squeeze(1)
        f = face_in[pix]
        b_in = perspective_correct(bary[pix, f], z_corner[f])
        zbuf[t, pix] = zmin[pix]
        parts.append(
            (t * height * width + pix, f, b_in, torch.ones_like(pix, dtype=torch.bool), torch.zeros_like(b_in[:, 0]))
        )

        # Distance from each pixel to each triangle: to its nearest edge (pixels are outside).
        lam_k, d2_k = zip(
            *(segment_closest(pixels, tri[None, :, k], tri[None, :, (k + 1) % 3]) for k in range(3)), strict=True
        )
        d2_all = torch.stack(d2_k, -1)  # (HW, F, 3)
        d2_face, k_best = d2_all.min(-1)
        d2_min, face_out = d2_face.detach().min(1)
        pix_o = torch.nonzero(~covered & (d2_min <= radius2)).squeeze(1)
        f_o, k_o = face_out[pix_o], k_best[pix_o, face_out[pix_o]]
        lam = torch.stack(lam_k, -1)[pix_o, f_o, k_o]
        w = torch.zeros(pix_o.shape[0], 3, dtype=uv.dtype)
        w = w.scatter(1, k_o[:, None], (1 - lam)[:, None]).scatter(1, ((k_o + 1) % 3)[:, None], lam[:, None])
        b_out = perspective_correct(w, z_corner[f_o])
        d2 = d2_face[pix_o, f_o] / pixel_unit(camera) ** 2
        parts.append((t * height * width + pix_o, f_o, b_out, torch.zeros_like(pix_o, dtype=torch.bool), d2))
    pix_all, face_all, bary_all, inside_all, d2_all = (torch.cat(x) for x in zip(*parts, strict=True))
    return Fragments(
        size=(num_t, height, width),
        pix=pix_all,
        face=face_all,
        bary=bary_all,
        inside=inside_all,
        dist2=d2_all,
        zbuf=zbuf.reshape(num_t, height, width),
    )
