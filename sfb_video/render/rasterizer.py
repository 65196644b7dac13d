"""The fast rasteriser: hard visibility by candidate pairs, a soft band around the silhouette.

Visibility is found without gradient: each front face lists the pixel centres it covers in
its scanline spans, and a scatter-min over depth keeps the nearest face per pixel. Only then
are barycentrics recomputed, with gradient, for the winning (pixel, face) pairs. The soft
silhouette outside the mesh needs the distance to the silhouette; it is the distance to the
nearest *contour* edge (an edge between a front- and a back-facing face, or on the boundary of
an open mesh), so only contour edges propose pixels, within the band where
exp(-sigma_inv * d^2) exceeds ``band_eps``. Cost follows the object's screen area
and outline, not (pixels x faces).

Convention: a face is front-facing when its projected corners run clockwise in pixel
coordinates (y down), i.e. counter-clockwise as seen by the viewer, as outward faces do.
"""

from __future__ import annotations

import math

import torch

from sfb_video.config import RenderConfig
from sfb_video.errors import check_in_front
from sfb_video.geometry import compiled
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology, check_vertices
from sfb_video.render import kernels
from sfb_video.render.barycentric import MIN_AREA_PX2, cross2, segment_closest
from sfb_video.render.fragments import Fragments, PixelLists


def band_radius_px(camera: PinholeCamera, settings: RenderConfig) -> float:
    """Distance in pixels beyond which the soft silhouette is below ``band_eps``."""
    d_norm = math.sqrt(math.log(1.0 / settings.band_eps) / settings.sigma_inv)
    return d_norm * pixel_unit(camera)


def pixel_unit(camera: PinholeCamera) -> float:
    """Pixels per normalised image unit (half the longer image side)."""
    return max(camera.width, camera.height) / 2


def _enumerate_boxes(lo: torch.Tensor, hi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """All integer points of boxes [lo, hi] (K, 2), inclusive; empty boxes give none.

    Returns:
        owner: (N,) index of the box each point comes from.
        xy: (N, 2) the points.
    """
    size = (hi - lo + 1).clamp_min(0)
    count = size[:, 0] * size[:, 1]
    owner = torch.repeat_interleave(torch.arange(lo.shape[0], device=lo.device), count)
    start = torch.cumsum(count, 0) - count
    local = torch.arange(owner.shape[0], device=lo.device) - start[owner]
    width = size[owner, 0]
    xy = torch.stack((lo[owner, 0] + local % width, lo[owner, 1] + local // width), -1)
    return owner, xy


def _argmin_per_key(key: torch.Tensor, value: torch.Tensor, size: int) -> torch.Tensor:
    """Index of the entry with the smallest ``value`` for each distinct ``key`` (ties: last)."""
    best = torch.full((size,), math.inf, device=value.device, dtype=value.dtype)
    best = best.scatter_reduce(0, key, value, reduce="amin")
    cand = torch.nonzero(value <= best[key]).squeeze(1)
    pick = torch.full((size,), -1, device=key.device, dtype=torch.long)
    pick = pick.scatter_reduce(0, key[cand], cand, reduce="amax")
    return pick[pick >= 0]


def _scanline_spans(tri: torch.Tensor, width: int, height: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel centres covered by triangles ``tri`` (K, 3, 2), row by row.

    Each row a triangle crosses is cut by its edges into one span [x_left, x_right]; only pixel
    centres in that span are listed, so slivers cost what they cover, not their bounding box.

    Returns:
        owner: (N,) triangle of each listed pixel.
        xy: (N, 2) integer pixel coordinates.
    """
    y_lo = tri[..., 1].amin(1).ceil().clamp_min(0).long()
    y_hi = tri[..., 1].amax(1).floor().clamp_max(height - 1).long()
    rows = (y_hi - y_lo + 1).clamp_min(0)
    row_owner = torch.repeat_interleave(torch.arange(tri.shape[0], device=tri.device), rows)
    row_start = torch.cumsum(rows, 0) - rows
    y = (y_lo[row_owner] + torch.arange(row_owner.shape[0], device=tri.device) - row_start[row_owner]).to(tri.dtype)
    corners = tri[row_owner]  # (R, 3, 2)
    p, q = corners, corners.roll(-1, dims=1)
    dy = q[..., 1] - p[..., 1]
    s = (y[:, None] - p[..., 1]) / dy
    crosses = (s >= 0) & (s <= 1) & (dy != 0)
    x = p[..., 0] + s * (q[..., 0] - p[..., 0])
    # Finite bounds before casting: a row that no edge crosses (rounding) gets an empty span.
    x_left = torch.where(crosses, x, torch.full_like(x, math.inf)).amin(1).ceil().clamp(0, width)
    x_right = torch.where(crosses, x, torch.full_like(x, -math.inf)).amax(1).floor().clamp(-1, width - 1)
    lo = torch.stack((x_left, y), -1).long()
    hi = torch.stack((x_right.clamp_min(x_left - 1), y), -1).long()
    owner, xy = _enumerate_boxes(lo, hi)
    return row_owner[owner], xy


def _inverse_depth_planes(tri: torch.Tensor, inv_z: torch.Tensor) -> torch.Tensor:
    """Coefficients (K, 3) of 1/z = a * u + b * v + c over each screen triangle (K, 3, 2).

    Perspective projection keeps 1/z affine in screen space, so the z-test needs no barycentrics.
    """
    d1, d2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    w1, w2 = inv_z[:, 1] - inv_z[:, 0], inv_z[:, 2] - inv_z[:, 0]
    area = cross2(d1, d2)
    a = (w1 * d2[:, 1] - w2 * d1[:, 1]) / area
    b = (w2 * d1[:, 0] - w1 * d2[:, 0]) / area
    c = inv_z[:, 0] - a * tri[:, 0, 0] - b * tri[:, 0, 1]
    return torch.stack((a, b, c), -1)


def _visible_faces(
    uv: torch.Tensor, depth: torch.Tensor, topology: MeshTopology, camera: PinholeCamera
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Hard z-buffered visibility, without gradient.

    Returns:
        pix: (P,) flat pixel index into T * H * W of covered pixels.
        cand: (P,) index of their nearest covering face into the candidate list.
        candidates: (K, 2) (render, face) of every face that was rasterised.
        zbuf: (T, H, W) depth at covered pixels, +inf elsewhere.
        front: (T, F) which faces face the camera.
    """
    num_t, height, width = uv.shape[0], camera.height, camera.width
    faces = topology.faces
    if kernels.available(uv):
        size = (height, width)
        pix, cand, inv_z, candidates, front = kernels.nearest_faces(
            uv, depth, faces, topology.is_closed(), MIN_AREA_PX2, size
        )
    else:
        tri = uv[:, faces]  # (T, F, 3, 2)
        area = cross2(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
        front = area < 0
        # A ray enters a closed surface through a front face first, so back faces never win there.
        keep = (area.abs() > MIN_AREA_PX2) & (front | (not topology.is_closed()))
        t_idx, f_idx = torch.nonzero(keep, as_tuple=True)
        tri = tri[t_idx, f_idx]
        corner_inv_z = 1.0 / depth[t_idx[:, None], faces[f_idx]]
        planes = _inverse_depth_planes(tri, corner_inv_z)
        owner, xy = _scanline_spans(tri, width, height)
        pl = planes[owner]
        inv_z = pl[:, 0] * xy[:, 0] + pl[:, 1] * xy[:, 1] + pl[:, 2]
        key = (t_idx[owner] * height + xy[:, 1]) * width + xy[:, 0]
        # The nearest surface has the largest 1/z.
        win = _argmin_per_key(key, -inv_z, num_t * height * width)
        pix, cand, inv_z = key[win], owner[win], inv_z[win]
        candidates = torch.stack((t_idx, f_idx), -1)
    zbuf = torch.full((num_t * height * width,), math.inf, device=uv.device, dtype=uv.dtype)
    zbuf[pix] = 1.0 / inv_z
    return pix, cand, candidates, zbuf.reshape(num_t, height, width), front


def _weight_planes(
    uv: torch.Tensor, depth: torch.Tensor, faces: torch.Tensor, cand: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Planes whose ratios give perspective-correct barycentrics, with gradient.

    Screen barycentric l_i is affine in the pixel (u, v), and the 3D weight of corner i is
    (l_i / z_i) / sum_j (l_j / z_j). Up to the triangle's area, which cancels in that ratio,
    l_i = (q_v - r_v) du + (r_u - q_u) dv + (q_u r_v - q_v r_u) with (q, r) the next two corners,
    all taken relative to the face's first corner: in absolute pixel coordinates the constant
    term cancels catastrophically in float32 (about 170 * 126 - 126 * 171 for a small face).

    Returns:
        planes: (K, 3, 3), row i holding those three coefficients divided by z_i.
        origin: (K, 2) the first corner, which (du, dv) are measured from.
    """
    corners = faces[cand[:, 1]]
    tri = uv[cand[:, :1], corners]  # (K, 3, 2)
    origin = tri[:, 0]
    local = tri - origin[:, None]
    q, r = local.roll(-1, dims=1), local.roll(-2, dims=1)
    coef = torch.stack(
        (q[..., 1] - r[..., 1], r[..., 0] - q[..., 0], q[..., 0] * r[..., 1] - q[..., 1] * r[..., 0]), -1
    )
    return coef / depth[cand[:, :1], corners][..., None], origin


def _contour_band(
    uv: torch.Tensor,
    front: torch.Tensor,
    topology: MeshTopology,
    covered: torch.Tensor,
    camera: PinholeCamera,
    radius: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Band pixels outside the silhouette and their nearest contour edge, without gradient.

    Args:
        front: (T, F) bool, front-facing faces.
        covered: (T * H * W,) bool, pixels inside the silhouette.

    Returns:
        pix: (Q,) flat pixel index; t_idx: (Q,) render index; edge: (Q,) nearest contour edge;
        side: (Q,) which of the edge's faces (0 or 1) is front-facing.
    """
    num_t, height, width = uv.shape[0], camera.height, camera.width
    edges, edge_faces = topology.edges, topology.edge_faces
    if kernels.available(uv):
        return kernels.nearest_edges(uv, front, edges, edge_faces, covered, radius, (height, width))
    has_two = edge_faces[:, 1] >= 0
    front0 = front[:, edge_faces[:, 0]]
    front1 = front[:, edge_faces[:, 1].clamp_min(0)]
    contour = ~has_two | (front0 != front1)  # (T, E)
    t_idx, e_idx = torch.nonzero(contour, as_tuple=True)
    a, b = uv[t_idx, edges[e_idx, 0]], uv[t_idx, edges[e_idx, 1]]
    lo = (torch.minimum(a, b) - radius).ceil().long()
    hi = (torch.maximum(a, b) + radius).floor().long()
    lo = torch.maximum(lo, torch.zeros_like(lo))
    hi = torch.minimum(hi, torch.tensor([width - 1, height - 1], device=uv.device))
    owner, xy = _enumerate_boxes(lo, hi)
    key = (t_idx[owner] * height + xy[:, 1]) * width + xy[:, 0]
    keep = ~covered[key]
    owner, xy, key = owner[keep], xy[keep], key[keep]
    _, d2 = segment_closest(xy.to(uv.dtype), a[owner], b[owner])
    keep = d2 <= radius * radius
    owner, key, d2 = owner[keep], key[keep], d2[keep]
    win = _argmin_per_key(key, d2, num_t * height * width)
    owner = owner[win]
    side = (~(front0[t_idx[owner], e_idx[owner]]) & has_two[e_idx[owner]]).long()
    return key[win], t_idx[owner], e_idx[owner], side


def project_checked(
    vertices: torch.Tensor, topology: MeshTopology, camera: PinholeCamera, settings: RenderConfig
) -> tuple[torch.Tensor, torch.Tensor, MeshTopology]:
    """Check (T, V, 3) camera-space vertices and project them.

    Returns:
        uv: (T, V, 2) pixels; depth: (T, V); the topology on the vertices' device.

    Raises:
        MeshError, PoseError: non-finite vertices, faces out of range, vertices behind the camera.
    """
    check_vertices(vertices, topology)
    if vertices.dim() != 3:
        raise ValueError(f"vertices must have shape (T, V, 3), got {tuple(vertices.shape)}")
    uv, depth = compiled.project(vertices, camera) if kernels.serves(vertices) else camera.project(vertices)
    check_in_front(depth.detach(), settings.near)
    return uv, depth, topology.to(vertices.device)


@torch.no_grad()
def find_pixels(
    uv: torch.Tensor, depth: torch.Tensor, topology: MeshTopology, camera: PinholeCamera, settings: RenderConfig
) -> PixelLists:
    """The pixels inside the silhouette with their nearest face, and the band pixels around it
    with their nearest contour edge, from (T, V, 2) pixels and (T, V) depths (no gradient)."""
    num_t, height, width = uv.shape[0], camera.height, camera.width
    pix_in, cand_in, candidates, zbuf, front = _visible_faces(uv, depth, topology, camera)
    covered = torch.zeros(num_t * height * width, dtype=torch.bool, device=uv.device)
    covered[pix_in] = True
    radius = band_radius_px(camera, settings)
    pix_out, t_out, edge_out, side_out = _contour_band(uv, front, topology, covered, camera, radius)
    return PixelLists((num_t, height, width), pix_in, candidates, cand_in, pix_out, t_out, edge_out, side_out, zbuf)


def interpolate(
    uv: torch.Tensor, depth: torch.Tensor, lists: PixelLists, topology: MeshTopology, camera: PinholeCamera
) -> Fragments:
    """Barycentrics of the listed pixels and the band's distances, with gradient w.r.t. the
    (T, V, 2) pixels and (T, V) depths of the vertices."""
    height, width = camera.height, camera.width
    faces = topology.faces
    # Inside: barycentrics of the pixel centre in its covering face.
    pix_in = lists.pix_in
    planes, origin = _weight_planes(uv, depth, faces, lists.candidates)
    plane, origin = planes[lists.cand_in], origin[lists.cand_in]  # (P, 3, 3), (P, 2)
    du = (pix_in % width).to(uv.dtype)[:, None] - origin[:, :1]
    dv = ((pix_in // width) % height).to(uv.dtype)[:, None] - origin[:, 1:]
    bary_in = plane[..., 0] * du + plane[..., 1] * dv + plane[..., 2]
    bary_in = bary_in / bary_in.sum(-1, keepdim=True)

    # Band: the closest point on the contour edge, expressed in the edge's front face.
    pix_out, t_out, edge_out, side_out = lists.pix_out, lists.t_out, lists.edge_out, lists.side_out
    ends = topology.edges[edge_out]  # (Q, 2)
    a, b = uv[t_out, ends[:, 0]], uv[t_out, ends[:, 1]]
    p_out = torch.stack((pix_out % width, (pix_out // width) % height), -1).to(uv.dtype)
    lam, d2_px = segment_closest(p_out, a, b)
    face_out = topology.edge_faces[edge_out, side_out]
    slots = topology.edge_slots[edge_out, side_out]  # (Q, 2)
    w_edge = torch.stack((1 - lam, lam), -1) / depth[t_out[:, None], ends]
    w_edge = w_edge / w_edge.sum(-1, keepdim=True)
    bary_out = torch.zeros(lam.shape[0], 3, dtype=uv.dtype, device=uv.device).scatter(1, slots, w_edge)

    unit2 = pixel_unit(camera) ** 2
    return Fragments(
        size=lists.size,
        pix=torch.cat((pix_in, pix_out)),
        face=torch.cat((lists.face_in, face_out)),
        bary=torch.cat((bary_in, bary_out)),
        inside=torch.cat((torch.ones_like(pix_in, dtype=torch.bool), torch.zeros_like(pix_out, dtype=torch.bool))),
        dist2=torch.cat((torch.zeros_like(bary_in[:, 0]), d2_px / unit2)),
        zbuf=lists.zbuf,
    )


def rasterize(
    vertices: torch.Tensor,
    topology: MeshTopology,
    camera: PinholeCamera,
    settings: RenderConfig,
) -> Fragments:
    """Rasterise T poses of one mesh.

    Args:
        vertices: (T, V, 3) vertices in camera coordinates (OpenCV axes, z > near).
        topology: the mesh's faces, UVs and edges.
        camera: intrinsics and image size (H, W) of the render.
        settings: sharpness of the soft silhouette, band cut-off and near plane.

    Returns:
        :class:`Fragments` with gradient w.r.t. ``vertices`` in ``bary`` and ``dist2``.
    """
    uv, depth, topo = project_checked(vertices, topology, camera, settings)
    lists = find_pixels(uv.detach(), depth.detach(), topo, camera, settings)
    return interpolate(uv, depth, lists, topo, camera)
