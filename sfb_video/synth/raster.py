"""A hard, supersampled, z-buffered, textured triangle rasteriser for the synthetic data.

It is deliberately independent of ``sfb_video.render`` (the fitter's soft renderer): ground
truth made by the fitter's own forward model would hide that model's errors.

Convention:
    Camera coordinates and pixels as in ``geometry/camera.py``: x right, y down, z forward,
    pixel centres at integer coordinates. With supersampling factor s, output pixel (i, j) is
    sampled at the s x s points j - 1/2 + (a + 1/2)/s, i - 1/2 + (b + 1/2)/s, which are the
    pixel centres of the camera ``camera.crop(0, 0, W, H, s W, s H)``.
    Texture lookup is bilinear at perspective-correct texture coordinates; (u, v) = (0, 0) is
    the texture's top-left corner, texel centres at ((k + 1/2) / size).
    No lighting: the texture is the object's radiance, as in the SfB image formation model.

Views (poses) can be rendered in groups whose images are averaged on the fly, which is how a
blurred exposure or a temporal sub-frame is integrated without storing every sub-exposure.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from sfb_video.errors import PoseError, SfbError, check_shape
from sfb_video.geometry.camera import PinholeCamera

# Samples whose barycentric coordinate is this far below 0 still count as inside, so a sample
# that lies exactly on an edge shared by two triangles is never lost to rounding in both; the
# z-test then keeps one of the two.
_INSIDE_EPS = 1e-9
# Triangles with a smaller doubled screen area (in supersampled pixels^2) cover no sample.
_MIN_AREA = 1e-12
# Upper bound on candidate samples enumerated at once; bounds peak memory (~100 MB per 2^20).
_CHUNK = 1 << 20


@dataclass(frozen=True)
class RasterImages:
    """Rendered images, averaged over the views of each group.

    Attributes:
        premultiplied: (G, H, W, 3) float64, the mean over a pixel's samples and the group's
            views of colour * covered (F * A in the formation model).
        coverage: (G, H, W) float64 in [0, 1], the fraction of samples covered (A).
    """

    premultiplied: np.ndarray
    coverage: np.ndarray

    def composite(self, background: np.ndarray) -> np.ndarray:
        """(G, H, W, 3) images F * A + (1 - A) * B over a float (H, W, 3) ``background``."""
        return self.premultiplied + (1.0 - self.coverage[..., None]) * background[None]


def pose_points(vertices: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor) -> torch.Tensor:
    """Camera-space points R @ v + x: (V, 3), (B, 3, 3), (B, 3) -> (B, V, 3) float64.

    Written as explicit products and sums rather than a matrix product, whose BLAS summation
    order may depend on the thread count: the data must be bit-identical on every machine.
    """
    rot = rotations.double()[:, None, :, :]  # (B, 1, 3, 3)
    v = vertices.double()[None, :, None, :]  # (1, V, 1, 3)
    return _sum3(rot * v) + translations.double()[:, None, :]


def _sample_texture(texture: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Bilinear lookup of (Ht, Wt, 3) ``texture`` at (n, 2) ``uv``, clamped at the border.

    Returns (n, 3) colours in the texture's dtype.
    """
    th, tw = texture.shape[:2]
    x = uv[:, 0] * tw - 0.5
    y = uv[:, 1] * th - 0.5
    x0f, y0f = torch.floor(x), torch.floor(y)
    fx = (x - x0f)[:, None].to(texture.dtype)
    fy = (y - y0f)[:, None].to(texture.dtype)
    xi, yi = x0f.long(), y0f.long()
    x0, x1 = xi.clamp(0, tw - 1), (xi + 1).clamp(0, tw - 1)
    y0, y1 = yi.clamp(0, th - 1) * tw, (yi + 1).clamp(0, th - 1) * tw
    flat = texture.reshape(-1, 3)
    top = torch.lerp(flat.index_select(0, y0 + x0), flat.index_select(0, y0 + x1), fx)
    bottom = torch.lerp(flat.index_select(0, y1 + x0), flat.index_select(0, y1 + x1), fx)
    return torch.lerp(top, bottom, fy)


def _sum3(x: torch.Tensor) -> torch.Tensor:
    """Sum over a last axis of size 3; much faster on CPU than a reduction kernel over it."""
    return x[..., 0] + x[..., 1] + x[..., 2]


def _edge_coefficients(xs: torch.Tensor, ys: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Affine screen barycentrics l_k(p) = A_k . (px, py) + C_k of (T, 3) triangles.

    Returns:
        AB: (T, 3, 2) gradients and C: (T, 3) offsets, already divided by the signed area, so
        that all three are >= 0 exactly inside the triangle whatever its winding.
    """
    xa, ya = xs[:, [1, 2, 0]], ys[:, [1, 2, 0]]  # edge k runs from vertex k+1 to vertex k+2
    xb, yb = xs[:, [2, 0, 1]], ys[:, [2, 0, 1]]
    a = -(yb - ya)
    b = xb - xa
    c = (yb - ya) * xa - (xb - xa) * ya
    area = (xs[:, 1] - xs[:, 0]) * (ys[:, 2] - ys[:, 0]) - (ys[:, 1] - ys[:, 0]) * (xs[:, 2] - xs[:, 0])
    inv = 1.0 / area[:, None]
    return torch.stack((a * inv, b * inv), -1), c * inv


def rasterize(
    points: torch.Tensor,
    faces: torch.Tensor,
    face_uv_coords: torch.Tensor,
    texture: np.ndarray,
    camera: PinholeCamera,
    supersample: int = 2,
    groups: np.ndarray | None = None,
    cull_backfaces: bool = True,
    near: float = 1e-3,
    view_batch: int = 16,
) -> RasterImages:
    """Render textured triangles hard, at ``supersample`` x the resolution, box-downsampled.

    Args:
        points: (B, V, 3) camera-space vertices of B views (poses) of one mesh.
        faces: (F, 3) vertex indices, counter-clockwise seen from outside.
        face_uv_coords: (F, 3, 2) texture coordinates of each face corner.
        texture: (Ht, Wt, 3) uint8 or float image in [0, 1] (uint8 is divided by 255).
        camera: the camera of the output image (H x W = camera.height x camera.width).
        supersample: samples per pixel along each axis (s); coverage steps are 1 / s^2.
        groups: (B,) group index of each view, 0..G-1, every group non-empty; the G output
            images average their views. ``None`` renders each view on its own (G = B).
        cull_backfaces: drop faces turned away from the camera; exact for closed meshes and
            halves the work. Turn it off for open or two-sided geometry.
        near: the smallest depth a vertex may have.
        view_batch: views rasterised at once; bounds the working set (it does not change the
            images beyond floating-point summation order).

    Returns:
        RasterImages with (G, H, W, 3) premultiplied colour and (G, H, W) coverage.
    """
    if points.dim() != 3 or points.shape[-1] != 3:
        raise SfbError(f"points must have shape (B, V, 3), got {tuple(points.shape)}")
    check_shape(face_uv_coords, (faces.shape[0], 3, 2), "face_uv_coords")
    if supersample < 1 or view_batch < 1:
        raise SfbError(f"supersample and view_batch must be >= 1, got {supersample} and {view_batch}")
    num_views = points.shape[0]
    if groups is None:
        groups = np.arange(num_views)
    groups = np.asarray(groups, dtype=np.int64)
    if groups.shape != (num_views,) or (num_views and groups.min() < 0):
        raise SfbError(f"groups must be (B,) = ({num_views},) non-negative indices")
    num_groups = int(groups.max()) + 1 if num_views else 0
    views_per_group = np.bincount(groups, minlength=num_groups)
    if (views_per_group == 0).any():
        raise SfbError("every group index 0..G-1 must hold at least one view")
    height, width = camera.height, camera.width
    ss_camera = camera.crop(0, 0, width, height, supersample * width, supersample * height)
    tex = _texture_tensor(texture)
    size = num_groups * height * width
    count = np.zeros(size)
    premult = np.zeros((3, size))
    all_points = points.double()
    for first in range(0, num_views, view_batch):
        view, py, px, colour = _visible_samples(
            all_points[first : first + view_batch],
            faces.long(),
            face_uv_coords.double(),
            tex,
            ss_camera,
            cull_backfaces,
            near,
        )
        # Box-downsample and average the group's views in one scatter: sample (py, px) of view
        # b lands in output pixel (py // s, px // s) of image groups[b].
        pix = (groups[first + view] * height + py // supersample) * width + px // supersample
        count += np.bincount(pix, minlength=size)
        for c in range(3):
            premult[c] += np.bincount(pix, weights=colour[:, c], minlength=size)
    norm = (supersample**2 * views_per_group).astype(np.float64)[:, None, None]
    count = count.reshape(num_groups, height, width) / norm
    premult = np.moveaxis(premult, 0, -1).reshape(num_groups, height, width, 3) / norm[..., None]
    return RasterImages(premult, count)


def _texture_tensor(texture: np.ndarray) -> torch.Tensor:
    """(Ht, Wt, 3) float32 texture in [0, 1]: colours end up 8-bit, so float32 loses nothing and
    halves the memory traffic of the lookups, the renderer's largest cost."""
    if texture.ndim != 3 or texture.shape[2] != 3:
        raise SfbError(f"texture must have shape (Ht, Wt, 3), got {texture.shape}")
    scale = 255.0 if texture.dtype == np.uint8 else 1.0
    return torch.from_numpy((np.asarray(texture, dtype=np.float64) / scale).astype(np.float32))


def _visible_samples(
    points: torch.Tensor,
    faces: torch.Tensor,
    face_uv: torch.Tensor,
    texture: torch.Tensor,
    cam: PinholeCamera,
    cull_backfaces: bool,
    near: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The front-most sample of every covered (view, supersampled pixel), with its colour.

    Returns:
        view, row, column: (n,) int64 arrays; colour: (n, 3) float32 in [0, 1].
    """
    num_views, num_faces = points.shape[0], faces.shape[0]
    empty = (np.zeros(0, np.int64),) * 3 + (np.zeros((0, 3)),)
    if num_views == 0 or num_faces == 0:
        return empty
    z = points[..., 2]
    if float(z.min()) <= near:
        raise PoseError(f"a vertex is at depth {float(z.min()):.3g} <= near {near:g}: behind the camera")
    u = cam.fx * points[..., 0] / z + cam.cx
    v = cam.fy * points[..., 1] / z + cam.cy
    tri_u, tri_v, tri_z = u[:, faces], v[:, faces], z[:, faces]  # (B, F, 3)
    keep = torch.ones(num_views, num_faces, dtype=torch.bool)
    if cull_backfaces:
        p = points[:, faces]  # (B, F, 3, 3)
        normal = torch.linalg.cross(p[:, :, 1] - p[:, :, 0], p[:, :, 2] - p[:, :, 0], dim=-1)
        keep &= _sum3(normal * p[:, :, 0]) < 0  # outward normal towards the camera at 0
    area = (tri_u[..., 1] - tri_u[..., 0]) * (tri_v[..., 2] - tri_v[..., 0]) - (tri_v[..., 1] - tri_v[..., 0]) * (
        tri_u[..., 2] - tri_u[..., 0]
    )
    keep &= area.abs() > _MIN_AREA
    x_lo = torch.ceil(tri_u.amin(-1)).clamp_min(0)
    x_hi = torch.floor(tri_u.amax(-1)).clamp_max(cam.width - 1)
    y_lo = torch.ceil(tri_v.amin(-1)).clamp_min(0)
    y_hi = torch.floor(tri_v.amax(-1)).clamp_max(cam.height - 1)
    keep &= (x_lo <= x_hi) & (y_lo <= y_hi)
    view_id, face_id = torch.nonzero(keep, as_tuple=True)
    if view_id.numel() == 0:
        return empty
    tu, tv, tz = tri_u[view_id, face_id], tri_v[view_id, face_id], tri_z[view_id, face_id]
    grad, offset = _edge_coefficients(tu, tv)
    x0, y0 = x_lo[view_id, face_id].long(), y_lo[view_id, face_id].long()
    bw = x_hi[view_id, face_id].long() - x0 + 1
    bh = y_hi[view_id, face_id].long() - y0 + 1

    # Each view's depth buffer spans only the box of its own triangles, packed one after the
    # other: far smaller than B full supersampled frames.
    vx0 = torch.full((num_views,), cam.width, dtype=torch.long).scatter_reduce(0, view_id, x0, "amin")
    vy0 = torch.full((num_views,), cam.height, dtype=torch.long).scatter_reduce(0, view_id, y0, "amin")
    vx1 = torch.zeros(num_views, dtype=torch.long).scatter_reduce(0, view_id, x0 + bw, "amax")
    vy1 = torch.zeros(num_views, dtype=torch.long).scatter_reduce(0, view_id, y0 + bh, "amax")
    vw = (vx1 - vx0).clamp_min(0)
    base = torch.cumsum(vw * (vy1 - vy0).clamp_min(0), 0) - vw * (vy1 - vy0).clamp_min(0)
    buffer_size = int((vw * (vy1 - vy0).clamp_min(0)).sum())

    # Scanline spans: on each row of its box a triangle covers one interval of columns, where
    # all three barycentrics are >= -eps; enumerating only those avoids testing box samples.
    row_tri = torch.arange(len(bh)).repeat_interleave(bh)
    row_y = y0[row_tri] + torch.arange(len(row_tri)) - (torch.cumsum(bh, 0) - bh)[row_tri]
    row_val = grad[row_tri, :, 1] * row_y[:, None].double() + offset[row_tri]  # (R, 3)
    gx = grad[row_tri, :, 0]
    bound = (-_INSIDE_EPS - row_val) / torch.where(gx == 0, 1.0, gx)
    lower = torch.where(gx > 0, bound, -torch.inf).amax(-1)
    upper = torch.where(gx < 0, bound, torch.inf).amin(-1)
    # A row parallel to an edge lies wholly on one side of it.
    outside = ((gx == 0) & (row_val < -_INSIDE_EPS)).any(-1)
    col_lo = torch.maximum(torch.ceil(lower), x0[row_tri].double()).long()
    col_hi = torch.minimum(torch.floor(upper), (x0 + bw - 1)[row_tri].double()).long()
    counts = torch.where(outside, 0, (col_hi - col_lo + 1).clamp_min(0))

    # Per row, the affine pieces every sample needs: its buffer key is row_key + column, and
    # 1/z (affine in screen space, so exact) is row_iz + column * row_iz_dx.
    vid_row = view_id[row_tri]
    row_key = base[vid_row] + (row_y - vy0[vid_row]) * vw[vid_row] - vx0[vid_row]
    inv_z = 1.0 / tz[row_tri]
    row_iz = _sum3(row_val * inv_z)
    row_iz_dx = _sum3(gx * inv_z)

    keys, depths, rows, cols = [], [], [], []
    ends = torch.cumsum(counts, 0)
    start = 0
    while start < len(counts):
        # Take whole rows up to the chunk budget (at least one).
        done = int(ends[start - 1]) if start else 0
        stop = max(start + 1, int(torch.searchsorted(ends, done + _CHUNK, right=True)))
        n_row = counts[start:stop]
        r = torch.arange(start, stop).repeat_interleave(n_row)
        sx = col_lo[r] + torch.arange(len(r)) - (torch.cumsum(n_row, 0) - n_row)[r - start]
        keys.append(row_key[r] + sx)
        depths.append(1.0 / torch.addcmul(row_iz[r], row_iz_dx[r], sx.double()))
        rows.append(r)
        cols.append(sx)
        start = stop
    key, depth, r, sx = torch.cat(keys), torch.cat(depths), torch.cat(rows), torch.cat(cols)
    zbuf = torch.full((buffer_size,), float("inf"), dtype=torch.float64)
    zbuf.scatter_reduce_(0, key, depth, "amin")
    front = depth <= zbuf[key]
    # Ties (a sample on an edge shared by two front triangles) keep the lowest candidate.
    cand = torch.arange(len(key))[front]
    winner = torch.full((buffer_size,), len(key), dtype=torch.long)
    winner.scatter_reduce_(0, key[front], cand, "amin")
    sel = winner[winner < len(key)]
    r, sx = r[sel], sx[sel]
    # Perspective-correct texture coordinates: weights l_k / z_k, renormalised.
    w = torch.addcmul(row_val.index_select(0, r), gx.index_select(0, r), sx[:, None].double())
    w *= inv_z.index_select(0, r)
    w /= _sum3(w)[:, None]
    tri = row_tri[r]
    corner_uv = face_uv.index_select(0, face_id[tri])  # (n, 3, 2)
    uv = _sum3(w[:, None, :] * corner_uv.transpose(1, 2))
    colour = _sample_texture(texture, uv)
    vid, row, col = view_id[tri], row_y[r], sx
    return vid.numpy(), row.numpy(), col.numpy(), colour.numpy()
