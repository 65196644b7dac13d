"""The differentiable half of the renderer in two compiled passes: forward and backward.

After the searches (:func:`sfb_video.render.rasterizer.find_pixels`) the renderer interpolates
barycentrics, samples the texture and computes the soft silhouette at every listed pixel. As
tensor operations (:func:`~sfb_video.render.rasterizer.interpolate` and the shader) that is
about sixty small operations forward and as many backward, and at the fitter's crops (~10k
listed pixels) their fixed cost, not the arithmetic, is most of a fit step (benchmarks/RESULTS.md,
"Renderer speed"). Here the forward pass is one numba loop over the listed pixels and the
backward pass another, with the derivatives written out. Both split the list into a fixed
number of parts (``CHUNKS``) that run on numba's threads, each adding into its own image or
gradients, which are then summed in part order: the results are the same on any number of
threads. The tensor version stays the reference (and the
CUDA path): the tests hold both to the same values and gradients.

The forward pass per pixel, as in the tensor version:
- inside, in the covering face with corners i = 0, 1, 2 (relative to corner 0, for float32):
  b_i = m_i / z_i, m_i = (q_y - r_y) du + (r_x - q_x) dv + q_x r_y - q_y r_x for (q, r) the next
  two corners, barycentrics b / sum(b);
- in the band, on the contour edge (a, b): lam = clamp((p - a).(b - a) / |b - a|^2, 0, 1),
  d2 = |p - a - lam (b - a)|^2, weights ((1 - lam) / z_a, lam / z_b) normalised into the edge's
  two corners of its front face, alpha = exp(-sigma_inv d2 / unit^2);
- the texture sampled bilinearly as ``grid_sample`` does (align_corners False, border padding,
  coordinates clamped to the texture, border texels without gradient);
- for the fitter, optionally composited straight into the blurred image (paper, eq. 4), so
  that the T colour images are never made.

The region the object sweeps over the exposure, L_D's 1 - prod_t (1 - A_t), is compiled here
too (:func:`swept`): torch's product backward over the T silhouettes cost more than the rest
of the loss.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from sfb_video.geometry.mesh import MeshTopology
from sfb_video.render import kernels
from sfb_video.render.fragments import PixelLists
from sfb_video.render.kernels import add_parts, fill, prange

# Fixed, not the thread count: each part's gradients are summed in the same order on any machine.
CHUNKS = 4

# The flat arrays both passes take, in this order, after uv, depth and the texture.
_Lists = tuple[np.ndarray, ...]


def available(uv: torch.Tensor, texture: torch.Tensor) -> bool:
    """Whether the compiled passes serve these tensors: CPU, float32 or float64, with numba."""
    return kernels.serves(uv, texture) and texture.dtype == uv.dtype


def _sample(texture: np.ndarray, s: float, t: float) -> tuple[float, float, int, int, float, float, float, float]:
    """Where ``grid_sample`` reads texture coordinates (s, t) in [0, 1]: the corner texel
    (x0, y0), the fractions (wx, wy) and d(ix)/ds, d(iy)/dt (0 where clamped)."""
    height, width = texture.shape[1], texture.shape[2]
    gx, gy = 2.0 * s - 1.0, 2.0 * t - 1.0
    gx = 0.0 if gx != gx else gx  # nan_to_num, as the tensor version does
    gy = 0.0 if gy != gy else gy
    dgx = 1.0 if -1.0 <= gx <= 1.0 else 0.0
    dgy = 1.0 if -1.0 <= gy <= 1.0 else 0.0
    gx, gy = min(max(gx, -1.0), 1.0), min(max(gy, -1.0), 1.0)
    ix, iy = ((gx + 1.0) * width - 1.0) / 2.0, ((gy + 1.0) * height - 1.0) / 2.0
    # Border padding; the border itself counts as outside for the gradient, as in torch.
    if ix <= 0.0:
        ix, dgx = 0.0, 0.0
    elif ix >= width - 1:
        ix, dgx = float(width - 1), 0.0
    if iy <= 0.0:
        iy, dgy = 0.0, 0.0
    elif iy >= height - 1:
        iy, dgy = float(height - 1), 0.0
    x0, y0 = math.floor(ix), math.floor(iy)
    return ix, iy, x0, y0, ix - x0, iy - y0, dgx * width, dgy * height


def _texel(texture: np.ndarray, c: int, y: int, x: int) -> float:
    if 0 <= y < texture.shape[1] and 0 <= x < texture.shape[2]:
        return texture[c, y, x]
    return 0.0


def _add_texel(grad: np.ndarray, c: int, y: int, x: int, value: float) -> None:
    if 0 <= y < grad.shape[1] and 0 <= x < grad.shape[2]:
        grad[c, y, x] += value


def _inside_bary(
    uv: np.ndarray,
    depth: np.ndarray,
    corners: np.ndarray,
    t: int,
    px: float,
    py: float,
    raw: np.ndarray,
    bary: np.ndarray,
) -> float:
    """Barycentrics (3,) of pixel (px, py) in the face with vertex ``corners`` of render ``t``
    into ``bary``, the raw weights b_i into ``raw``; returns their sum, which normalised them."""
    ox, oy = uv[t, corners[0], 0], uv[t, corners[0], 1]
    du, dv = px - ox, py - oy
    for i in range(3):
        j, k = corners[(i + 1) % 3], corners[(i + 2) % 3]
        qx, qy = uv[t, j, 0] - ox, uv[t, j, 1] - oy
        rx, ry = uv[t, k, 0] - ox, uv[t, k, 1] - oy
        raw[i] = ((qy - ry) * du + (rx - qx) * dv + qx * ry - qy * rx) / depth[t, corners[i]]
    total = raw[0] + raw[1] + raw[2]
    for i in range(3):
        bary[i] = raw[i] / total
    return total


def _band_bary(
    uv: np.ndarray,
    depth: np.ndarray,
    a: int,
    b: int,
    slot_a: int,
    slot_b: int,
    t: int,
    px: float,
    py: float,
    bary: np.ndarray,
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """Barycentrics (3,) into ``bary`` of the point of edge (a, b) of render ``t`` closest to
    pixel (px, py), in the corners ``slot_a``, ``slot_b`` of its front face; returns what the
    derivatives need: a, b - a, lam, p - closest and the weights (v0, v1) before normalising."""
    ax, ay = uv[t, a, 0], uv[t, a, 1]
    abx, aby = uv[t, b, 0] - ax, uv[t, b, 1] - ay
    lam = min(max(((px - ax) * abx + (py - ay) * aby) / max(abx * abx + aby * aby, 1e-20), 0.0), 1.0)
    dx, dy = px - (ax + lam * abx), py - (ay + lam * aby)
    v0, v1 = (1.0 - lam) / depth[t, a], lam / depth[t, b]
    bary[0] = bary[1] = bary[2] = 0.0
    bary[slot_a] = v0 / (v0 + v1)
    bary[slot_b] = v1 / (v0 + v1)
    return ax, ay, abx, aby, lam, dx, dy, v0, v1


def _texcoords(bary: np.ndarray, face_uv: np.ndarray, f: int) -> tuple[float, float]:
    """Texture coordinates (s, t) of barycentrics ``bary`` in face ``f``."""
    s = bary[0] * face_uv[f, 0, 0] + bary[1] * face_uv[f, 1, 0] + bary[2] * face_uv[f, 2, 0]
    t = bary[0] * face_uv[f, 0, 1] + bary[1] * face_uv[f, 1, 1] + bary[2] * face_uv[f, 2, 1]
    return s, t


def _bilinear(v00: float, v01: float, v10: float, v11: float, wx: float, wy: float) -> float:
    return (1 - wy) * ((1 - wx) * v00 + wx * v01) + wy * ((1 - wx) * v10 + wx * v11)


def _chunk(n: int, count: int, chunk: int) -> tuple[int, int]:
    """The ``chunk``-th of ``count`` contiguous parts of range(n)."""
    return n * chunk // count, n * (chunk + 1) // count


def _forward(
    uv: np.ndarray,
    depth: np.ndarray,
    texture: np.ndarray,
    faces: np.ndarray,
    face_uv: np.ndarray,
    pix_in: np.ndarray,
    cand_in: np.ndarray,
    candidates: np.ndarray,
    pix_out: np.ndarray,
    t_out: np.ndarray,
    edge_out: np.ndarray,
    side_out: np.ndarray,
    edges: np.ndarray,
    edge_faces: np.ndarray,
    edge_slots: np.ndarray,
    sigma_unit: float,
    background: np.ndarray,
    blur: bool,
    rgb: np.ndarray,
    alpha: np.ndarray,
) -> None:
    """Fill ``alpha`` (T, H, W) at the listed pixels (inside, then in the band), and their
    colour into ``rgb``: as (T, 3, H, W) renders, or with ``blur`` composited over
    ``background`` (3, H, W) into the blurred image (1, 3, H, W), which must hold the background
    on entry. The list runs in ``CHUNKS`` parts on numba's threads; with ``blur`` each part adds
    into an image of its own, and these are added to ``rgb`` in part order."""
    height, width = alpha.shape[1], alpha.shape[2]
    num_t = alpha.shape[0]
    n_listed = pix_in.shape[0] + pix_out.shape[0]
    # The renders' pixels are written once each, so the parts may share ``rgb``.
    parts = np.empty((CHUNKS if blur else 1, 1, 3, height, width), dtype=rgb.dtype)
    for chunk in prange(CHUNKS):
        lo, hi = _chunk(n_listed, CHUNKS, chunk)
        if blur:
            fill(parts[chunk], 0.0)
        out = parts[chunk] if blur else rgb
        raw = np.empty(3, dtype=np.float64)
        bary = np.empty(3, dtype=np.float64)
        for n in range(lo, hi):
            # Spelled out in both passes: as an inlined helper returning this tuple it made the
            # passes 1.5x slower (measured at the paper's setting).
            inside = n < pix_in.shape[0]
            m = n if inside else n - pix_in.shape[0]
            pix = pix_in[m] if inside else pix_out[m]
            t = candidates[cand_in[m], 0] if inside else t_out[m]
            e, side = (0, 0) if inside else (edge_out[m], side_out[m])
            f = candidates[cand_in[m], 1] if inside else edge_faces[e, side]
            x, y = pix % width, (pix // width) % height
            px, py = float(x), float(y)
            if inside:
                _inside_bary(uv, depth, faces[f], t, px, py, raw, bary)
                alpha[t, y, x] = 1.0
            else:
                _, _, _, _, _, dx, dy, _, _ = _band_bary(
                    uv, depth, edges[e, 0], edges[e, 1], edge_slots[e, side, 0], edge_slots[e, side, 1], t, px, py, bary
                )
                alpha[t, y, x] = math.exp(-sigma_unit * (dx * dx + dy * dy))
            s, tt = _texcoords(bary, face_uv, f)
            _, _, x0, y0, wx, wy, _, _ = _sample(texture, s, tt)
            for c in range(3):
                v00, v01 = _texel(texture, c, y0, x0), _texel(texture, c, y0, x0 + 1)
                v10, v11 = _texel(texture, c, y0 + 1, x0), _texel(texture, c, y0 + 1, x0 + 1)
                colour = _bilinear(v00, v01, v10, v11, wx, wy)
                if blur:
                    # I = mean_t(F_t A_t) + (1 - mean_t A_t) B, one listed pixel at a time.
                    out[0, c, y, x] += alpha[t, y, x] * (colour - background[c, y, x]) / num_t
                else:
                    out[t, c, y, x] = colour
    if blur:
        add_parts(rgb, parts)


def _backward(
    uv: np.ndarray,
    depth: np.ndarray,
    texture: np.ndarray,
    faces: np.ndarray,
    face_uv: np.ndarray,
    pix_in: np.ndarray,
    cand_in: np.ndarray,
    candidates: np.ndarray,
    pix_out: np.ndarray,
    t_out: np.ndarray,
    edge_out: np.ndarray,
    side_out: np.ndarray,
    edges: np.ndarray,
    edge_faces: np.ndarray,
    edge_slots: np.ndarray,
    sigma_unit: float,
    background: np.ndarray,
    blur: bool,
    alpha: np.ndarray,
    grad_rgb: np.ndarray,
    grad_alpha: np.ndarray,
    grad_uv: np.ndarray,
    grad_depth: np.ndarray,
    grad_texture: np.ndarray,
) -> None:
    """Add the gradients of the listed pixels' colour and coverage to ``grad_uv`` (T, V, 2),
    ``grad_depth`` (T, V) and ``grad_texture`` (3, Ht, Wt); ``grad_rgb`` is that of the renders
    (T, 3, H, W), or with ``blur`` of the blurred image (1, 3, H, W). The list runs in
    ``CHUNKS`` parts on numba's threads, each pixel by pixel in list order into gradients of
    its own, which are added up in part order."""
    height, width = alpha.shape[1], alpha.shape[2]
    num_t = alpha.shape[0]
    n_listed = pix_in.shape[0] + pix_out.shape[0]
    parts_uv = np.empty((CHUNKS, grad_uv.shape[0], grad_uv.shape[1], 2), dtype=grad_uv.dtype)
    parts_depth = np.empty((CHUNKS, grad_depth.shape[0], grad_depth.shape[1]), dtype=grad_depth.dtype)
    parts_texture = np.empty((CHUNKS, 3, grad_texture.shape[1], grad_texture.shape[2]), dtype=grad_texture.dtype)
    for chunk in prange(CHUNKS):
        lo, hi = _chunk(n_listed, CHUNKS, chunk)
        part_uv, part_depth, part_texture = parts_uv[chunk], parts_depth[chunk], parts_texture[chunk]
        fill(part_uv, 0.0)
        fill(part_depth, 0.0)
        fill(part_texture, 0.0)
        raw = np.empty(3, dtype=np.float64)
        bary = np.empty(3, dtype=np.float64)
        g_bary = np.empty(3, dtype=np.float64)
        for n in range(lo, hi):
            # Spelled out in both passes: as an inlined helper returning this tuple it made the
            # passes 1.5x slower (measured at the paper's setting).
            inside = n < pix_in.shape[0]
            m = n if inside else n - pix_in.shape[0]
            pix = pix_in[m] if inside else pix_out[m]
            t = candidates[cand_in[m], 0] if inside else t_out[m]
            e, side = (0, 0) if inside else (edge_out[m], side_out[m])
            f = candidates[cand_in[m], 1] if inside else edge_faces[e, side]
            x, y = pix % width, (pix // width) % height
            px, py = float(x), float(y)
            # The forward pass again, keeping what the derivatives need.
            ax = ay = abx = aby = lam = dx = dy = v0 = v1 = total = 0.0
            a = b = 0
            if inside:
                total = _inside_bary(uv, depth, faces[f], t, px, py, raw, bary)
            else:
                a, b = edges[e, 0], edges[e, 1]
                ax, ay, abx, aby, lam, dx, dy, v0, v1 = _band_bary(
                    uv, depth, a, b, edge_slots[e, side, 0], edge_slots[e, side, 1], t, px, py, bary
                )
            s, tt = _texcoords(bary, face_uv, f)
            _, _, x0, y0, wx, wy, ds, dt = _sample(texture, s, tt)

            # Texture sampling: into the four texels, and into (s, t).
            g_ix = g_iy = 0.0
            g_alpha = grad_alpha[t, y, x]
            for c in range(3):
                v00, v01 = _texel(texture, c, y0, x0), _texel(texture, c, y0, x0 + 1)
                v10, v11 = _texel(texture, c, y0 + 1, x0), _texel(texture, c, y0 + 1, x0 + 1)
                if blur:
                    colour = _bilinear(v00, v01, v10, v11, wx, wy)
                    g_alpha += grad_rgb[0, c, y, x] * (colour - background[c, y, x]) / num_t
                    g = grad_rgb[0, c, y, x] * alpha[t, y, x] / num_t
                else:
                    g = grad_rgb[t, c, y, x]
                if g == 0.0:
                    continue
                g_ix += g * ((1 - wy) * (v01 - v00) + wy * (v11 - v10))
                g_iy += g * ((1 - wx) * (v10 - v00) + wx * (v11 - v01))
                _add_texel(part_texture, c, y0, x0, g * (1 - wx) * (1 - wy))
                _add_texel(part_texture, c, y0, x0 + 1, g * wx * (1 - wy))
                _add_texel(part_texture, c, y0 + 1, x0, g * (1 - wx) * wy)
                _add_texel(part_texture, c, y0 + 1, x0 + 1, g * wx * wy)
            g_s, g_t = g_ix * ds, g_iy * dt
            for i in range(3):
                g_bary[i] = g_s * face_uv[f, i, 0] + g_t * face_uv[f, i, 1]

            if inside:
                corners = faces[f]
                dot = g_bary[0] * bary[0] + g_bary[1] * bary[1] + g_bary[2] * bary[2]
                ox, oy = uv[t, corners[0], 0], uv[t, corners[0], 1]
                du, dv = px - ox, py - oy
                for i in range(3):
                    g_raw = (g_bary[i] - dot) / total
                    z = depth[t, corners[i]]
                    part_depth[t, corners[i]] -= g_raw * raw[i] / z
                    g_m = g_raw / z
                    # m_i is the cross product (q - p) x (r - p): the first corner (the origin)
                    # cancels out of it, so only the next two corners get its gradient.
                    j, k = corners[(i + 1) % 3], corners[(i + 2) % 3]
                    qx, qy = uv[t, j, 0] - ox, uv[t, j, 1] - oy
                    rx, ry = uv[t, k, 0] - ox, uv[t, k, 1] - oy
                    part_uv[t, j, 0] += g_m * (ry - dv)
                    part_uv[t, j, 1] += g_m * (du - rx)
                    part_uv[t, k, 0] += g_m * (dv - qy)
                    part_uv[t, k, 1] += g_m * (qx - du)
            else:
                # Edge weights w_k = v_k / (v0 + v1), v0 = (1 - lam) / z_a, v1 = lam / z_b.
                g_w0, g_w1 = g_bary[edge_slots[e, side, 0]], g_bary[edge_slots[e, side, 1]]
                total = v0 + v1
                dot = (g_w0 * v0 + g_w1 * v1) / total
                g_v0, g_v1 = (g_w0 - dot) / total, (g_w1 - dot) / total
                z_a, z_b = depth[t, a], depth[t, b]
                part_depth[t, a] -= g_v0 * v0 / z_a
                part_depth[t, b] -= g_v1 * v1 / z_b
                g_lam = -g_v0 / z_a + g_v1 / z_b
                # alpha = exp(-sigma_unit * d2), d = p - (a + lam ab).
                g_d2 = -g_alpha * alpha[t, y, x] * sigma_unit
                g_cx, g_cy = -2.0 * dx * g_d2, -2.0 * dy * g_d2
                g_ax, g_ay = g_cx, g_cy
                g_abx, g_aby = lam * g_cx, lam * g_cy
                g_lam += g_cx * abx + g_cy * aby
                length2 = abx * abx + aby * aby
                raw_lam = ((px - ax) * abx + (py - ay) * aby) / max(length2, 1e-20)
                if 0.0 <= raw_lam <= 1.0:
                    denominator = max(length2, 1e-20)
                    g_num = g_lam / denominator
                    g_ax -= g_num * abx
                    g_ay -= g_num * aby
                    g_abx += g_num * (px - ax)
                    g_aby += g_num * (py - ay)
                    if length2 >= 1e-20:
                        g_den = -g_lam * raw_lam / denominator
                        g_abx += 2.0 * g_den * abx
                        g_aby += 2.0 * g_den * aby
                part_uv[t, a, 0] += g_ax - g_abx
                part_uv[t, a, 1] += g_ay - g_aby
                part_uv[t, b, 0] += g_abx
                part_uv[t, b, 1] += g_aby
    add_parts(grad_uv, parts_uv)
    add_parts(grad_depth, parts_depth)
    add_parts(grad_texture, parts_texture)


def _swept_forward(alpha: np.ndarray, out: np.ndarray) -> None:
    """out (H, W) = 1 - prod_t (1 - alpha (T, H, W)); rows on numba's threads."""
    num_t, height, width = alpha.shape
    for y in prange(height):
        product = np.ones(width, dtype=np.float64)
        for t in range(num_t):
            for x in range(width):
                product[x] *= 1.0 - alpha[t, y, x]
        for x in range(width):
            out[y, x] = 1.0 - product[x]


def _swept_backward(alpha: np.ndarray, grad_out: np.ndarray, grad_alpha: np.ndarray) -> None:
    """d out / d alpha_t = prod over the other s of (1 - alpha_s), from prefix and suffix
    products (exact where some alpha is 1, unlike a division); rows on numba's threads, each
    swept along x (alpha's contiguous axis) one t at a time."""
    num_t, height, width = alpha.shape
    for y in prange(height):
        prefix = np.empty((num_t + 1, width), dtype=np.float64)
        prefix[0] = 1.0
        for t in range(num_t):
            for x in range(width):
                prefix[t + 1, x] = prefix[t, x] * (1.0 - alpha[t, y, x])
        suffix = np.ones(width, dtype=np.float64)
        for t in range(num_t - 1, -1, -1):
            for x in range(width):
                grad_alpha[t, y, x] = grad_out[y, x] * prefix[t, x] * suffix[x]
                suffix[x] *= 1.0 - alpha[t, y, x]


if kernels.njit is not None:
    _swept_forward = kernels.compile_kernel(_swept_forward, parallel=True)
    _swept_backward = kernels.compile_kernel(_swept_backward, parallel=True)
    _sample = kernels.compile_kernel(_sample, inline=True)
    _texel = kernels.compile_kernel(_texel, inline=True)
    _add_texel = kernels.compile_kernel(_add_texel, inline=True)
    _inside_bary = kernels.compile_kernel(_inside_bary, inline=True)
    _band_bary = kernels.compile_kernel(_band_bary, inline=True)
    _texcoords = kernels.compile_kernel(_texcoords, inline=True)
    _bilinear = kernels.compile_kernel(_bilinear, inline=True)
    _chunk = kernels.compile_kernel(_chunk, inline=True)
    _forward = kernels.compile_kernel(_forward, parallel=True)
    _backward = kernels.compile_kernel(_backward, parallel=True)


def _flat(uv: torch.Tensor, lists: PixelLists, topology: MeshTopology) -> _Lists:
    """The arrays of ``lists`` and ``topology`` the passes read, as contiguous numpy arrays (the
    passes look up the edges' ends, faces and corners themselves: gathered here, as tensors,
    they cost 150 us a call, two thirds of the forward pass itself)."""
    arrays = (
        topology.faces,
        topology.face_uv_coords().to(uv.dtype),
        lists.pix_in,
        lists.cand_in,
        lists.candidates,
        lists.pix_out,
        lists.t_out,
        lists.edge_out,
        lists.side_out,
        topology.edges,
        topology.edge_faces,
        topology.edge_slots,
    )
    return tuple(a.contiguous().numpy() for a in arrays)


class _Shade(torch.autograd.Function):
    """(T, V, 2) pixels, (T, V) depths and a (3, Ht, Wt) texture -> alpha (T, 1, H, W) and the
    colour at the listed pixels: as renders rgb (T, 3, H, W) (0 elsewhere), or with a
    background (3, H, W) given, composited into the blurred image (3, H, W); the backward pass
    compiled. The background gets no gradient."""

    @staticmethod
    def forward(  # type: ignore[override]
        ctx: torch.autograd.function.FunctionCtx,
        uv: torch.Tensor,
        depth: torch.Tensor,
        texture: torch.Tensor,
        background: torch.Tensor | None,
        flat: _Lists,
        size: tuple[int, int, int],
        sigma_unit: float,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        num_t, height, width = size
        blur = background is not None
        arrays = tuple(a.detach().contiguous() for a in (uv, depth, texture))
        if background is None:
            colour = torch.zeros(num_t, 3, height, width, dtype=uv.dtype)
            background = torch.zeros(1, 1, 1, dtype=uv.dtype)
        else:
            background = background.detach().to(uv.dtype).contiguous()
            colour = background.clone()
        alpha = torch.zeros(num_t, height, width, dtype=uv.dtype)
        out = colour.reshape(-1, 3, height, width).numpy()
        _forward(*(a.numpy() for a in arrays), *flat, sigma_unit, background.numpy(), blur, out, alpha.numpy())
        ctx.save_for_backward(*arrays, background, alpha)
        ctx.flat, ctx.sigma_unit, ctx.blur = flat, sigma_unit, blur
        return colour, alpha[:, None]

    @staticmethod
    def backward(  # type: ignore[override]
        ctx: torch.autograd.function.FunctionCtx, grad_colour: torch.Tensor | None, grad_alpha: torch.Tensor | None
    ) -> tuple[torch.Tensor | None, ...]:
        uv, depth, texture, background, alpha = ctx.saved_tensors  # type: ignore[attr-defined]
        blur: bool = ctx.blur  # type: ignore[attr-defined]
        if grad_colour is None:
            shape = (3, *alpha.shape[1:]) if blur else (alpha.shape[0], 3, *alpha.shape[1:])
            grad_colour = torch.zeros(shape, dtype=uv.dtype)
        grad_alpha = torch.zeros_like(alpha) if grad_alpha is None else grad_alpha[:, 0]
        grads = torch.zeros_like(uv), torch.zeros_like(depth), torch.zeros_like(texture)
        _backward(
            uv.numpy(),
            depth.numpy(),
            texture.numpy(),
            *ctx.flat,  # type: ignore[attr-defined]
            ctx.sigma_unit,  # type: ignore[attr-defined]
            background.numpy(),
            blur,
            alpha.numpy(),
            grad_colour.contiguous().reshape(-1, 3, *alpha.shape[1:]).numpy(),
            grad_alpha.contiguous().numpy(),
            *(g.numpy() for g in grads),
        )
        return (*grads, None, None, None, None)


def shade_lists(
    uv: torch.Tensor,
    depth: torch.Tensor,
    lists: PixelLists,
    topology: MeshTopology,
    texture: torch.Tensor,
    sigma_inv: float,
    pixel_unit: float,
    background: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Colour and soft silhouette of the listed pixels, compiled; the values and gradients of
    :func:`~sfb_video.render.rasterizer.interpolate` followed by the shader (and, with a
    background, by :func:`~sfb_video.model.formation.blend`).

    Args:
        uv: (T, V, 2) pixels and depth: (T, V) of the posed vertices, with gradient.
        lists: what :func:`~sfb_video.render.rasterizer.find_pixels` found.
        texture: (3, Ht, Wt), with gradient.
        pixel_unit: pixels per normalised image unit (the soft silhouette's distance unit).
        background: (3, H, W) (no gradient): composite the T renders over it.

    Returns:
        rgb: (T, 3, H, W), or with a background the blurred image (3, H, W); alpha: (T, 1, H, W).
    """
    flat = _flat(uv, lists, topology)
    return _Shade.apply(uv, depth, texture, background, flat, lists.size, sigma_inv / pixel_unit**2)


class _Swept(torch.autograd.Function):
    @staticmethod
    def forward(ctx: torch.autograd.function.FunctionCtx, alpha: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        alpha = alpha.detach().contiguous()
        out = torch.empty(alpha.shape[1:], dtype=alpha.dtype)
        _swept_forward(alpha.numpy(), out.numpy())
        ctx.save_for_backward(alpha)
        return out

    @staticmethod
    def backward(ctx: torch.autograd.function.FunctionCtx, grad_out: torch.Tensor) -> torch.Tensor:  # type: ignore[override]
        (alpha,) = ctx.saved_tensors  # type: ignore[attr-defined]
        grad = torch.empty_like(alpha)
        _swept_backward(alpha.numpy(), grad_out.contiguous().numpy(), grad.numpy())
        return grad


def swept(alpha: torch.Tensor) -> torch.Tensor:
    """(H, W) the region swept over the exposure, 1 - prod_t (1 - alpha_t), of (T, H, W)
    silhouettes: compiled where :func:`available` serves them, else as a tensor product."""
    if available(alpha, alpha):
        return _Swept.apply(alpha)
    return 1 - (1 - alpha).prod(0)
