"""The spin of a window, searched by how well one texture can explain every frame.

A single frame does not tell the spin: some texture explains its blur for any rotation
(benchmarks/RESULTS.md, "Rotation identifiability"). A window of frames does, once the texture
is allowed to follow each candidate spin: with the mesh and the path held, the blurred image
is linear in the texture (each pixel averages alpha times a bilinear texture sample over the
exposure), so the texture that explains all frames best is a linear least-squares solve, and
its residual scores the spin. Adam cannot do this search: from a wrong spin its texture and
spin drift together into a nearby minimum (measured, RESULTS "The spin and the texture").

The score is taken with a coarse texture (``joint.spin_texture`` texels a side): a fine one
explains the frames with a wrong spin too. A grid of axes and magnitudes is scored, then the
best candidate is refined by a pattern search; the texture of the winner starts the joint fit.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import scipy.sparse
import torch
import torch.nn.functional as F

from sfb_video.config import RenderConfig
from sfb_video.crop import Crop
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.geometry.pose import pose_vertices
from sfb_video.render.rasterizer import rasterize
from sfb_video.render.shader import silhouette_values, texture_coords

Poses = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
"""Spin (3,) -> rotations (F, T, 3, 3) and positions (F, T, 3) of a window's frames."""


@dataclass(frozen=True)
class SpinScore:
    """One candidate spin and how well a texture explains the window with it.

    Attributes:
        spin: (3,) axis-angle per frame interval, camera coordinates.
        residual: the squared error of the best texture's blurred images, summed over the
            window's crops and channels.
        texture: (3, S, S) that texture (least squares, not clamped to [0, 1]).
    """

    spin: torch.Tensor
    residual: float
    texture: torch.Tensor


def fibonacci_axes(count: int) -> torch.Tensor:
    """(count, 3) unit vectors spread evenly over the sphere."""
    i = torch.arange(count, dtype=torch.float64) + 0.5
    polar = torch.acos(1 - 2 * i / count)
    azimuth = math.pi * (1 + math.sqrt(5)) * i
    axes = torch.stack((torch.cos(azimuth) * torch.sin(polar), torch.sin(azimuth) * torch.sin(polar), torch.cos(polar)))
    return axes.T.float()


def spin_grid(magnitudes_deg: Sequence[float], axes: int) -> torch.Tensor:
    """(1 + len(magnitudes) * axes, 3) candidate spins: none, then each magnitude about each axis."""
    directions = fibonacci_axes(axes)
    spins = [torch.zeros(1, 3)] + [directions * math.radians(m) for m in magnitudes_deg]
    return torch.cat(spins)


def _bilinear_taps(uv: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Texel indices (P, 4) and weights (P, 4) of bilinear samples at ``uv`` (P, 2), as
    ``grid_sample`` takes them (align_corners False, border padding)."""
    xy = (uv.clamp(0, 1) * size - 0.5).clamp(0, size - 1)
    lo = xy.floor().clamp(max=size - 2)
    f = xy - lo
    x0, y0 = lo[:, 0].long(), lo[:, 1].long()
    index = torch.stack((y0 * size + x0, y0 * size + x0 + 1, (y0 + 1) * size + x0, (y0 + 1) * size + x0 + 1), -1)
    fx, fy = f[:, 0], f[:, 1]
    weight = torch.stack(((1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy), -1)
    return index, weight


@dataclass(frozen=True)
class TextureSystem:
    """The linear map from a texture to a window's blurred images, as a least-squares system:
    the blurred images are ``A @ texels + (1 - mean alpha) * background``, and ``A @ texels -
    target`` is their error.

    Attributes:
        rows, cols, values: (E,) each, A's entries; entries at one place add up (a pixel sees
            the same texel at several instants).
        shape: (N, size * size): N pixels over the window's crops.
        target: (N, 3) the b.
    """

    rows: torch.Tensor
    cols: torch.Tensor
    values: torch.Tensor
    shape: tuple[int, int]
    target: torch.Tensor


def texture_system(
    crops: Sequence[Crop],
    posed: Sequence[torch.Tensor],
    topology: MeshTopology,
    size: int,
    settings: RenderConfig,
) -> TextureSystem:
    """The :class:`TextureSystem` of a window's crops for a texture of ``size`` texels a side.

    Args:
        crops: the window's crops; posed: per crop, (T, V, 3) its exposure's camera-space
            vertices.
    """
    rows, cols, values, targets = [], [], [], []
    offset = 0
    face_uv = topology.face_uv_coords()
    for crop, vertices in zip(crops, posed, strict=True):
        with torch.no_grad():
            fragments = rasterize(vertices, topology, crop.camera, settings)
        steps, height, width = fragments.size
        alpha = silhouette_values(fragments, settings.sigma_inv) / steps
        index, weight = _bilinear_taps(texture_coords(fragments, face_uv.to(fragments.bary)), size)
        pixel = fragments.pix % (height * width)
        rows.append((pixel + offset)[:, None].expand_as(index).reshape(-1))
        cols.append(index.reshape(-1))
        values.append((weight * alpha[:, None]).reshape(-1))
        coverage = torch.zeros(height * width, device=alpha.device).index_add_(0, pixel, alpha)
        image, background = crop.image.reshape(3, -1), crop.background.reshape(3, -1)
        targets.append((image - (1 - coverage) * background).T)
        offset += height * width
    return TextureSystem(torch.cat(rows), torch.cat(cols), torch.cat(values), (offset, size * size), torch.cat(targets))


class _Products:
    """What the solve needs of a :class:`TextureSystem`'s A: A^T A, A^T b and A x. On the CPU
    through SciPy's CSR (its products and its summing of repeated entries take a third of the
    time of torch's sparse COO with its coalescing); on a GPU through torch's, on the device."""

    def __init__(self, system: TextureSystem, scipy_csr: bool | None = None) -> None:
        if scipy_csr is None:
            scipy_csr = system.values.device.type == "cpu"
        if scipy_csr:
            at = (system.cols.numpy(), system.rows.numpy())
            self.at = scipy.sparse.csr_matrix((system.values.numpy(), at), shape=system.shape[::-1])
            self.a = self.at.T.tocsr()
        else:
            self.a = torch.sparse_coo_tensor(
                torch.stack((system.rows, system.cols)), system.values, system.shape, check_invariants=False
            ).coalesce()
            self.at = self.a.t().coalesce()

    def gram(self) -> torch.Tensor:
        """(n, n) A^T A, float32."""
        if isinstance(self.at, torch.Tensor):
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
                return torch.sparse.mm(self.at, self.a).to_dense()
        return torch.from_numpy((self.at @ self.a).toarray())

    def transposed_times(self, x: torch.Tensor) -> torch.Tensor:
        """(n, 3) A^T x of (N, 3) ``x``."""
        if isinstance(self.at, torch.Tensor):
            return torch.sparse.mm(self.at, x)
        return torch.from_numpy(self.at @ x.numpy())

    def times(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) A x of (n, 3) ``x``."""
        if isinstance(self.a, torch.Tensor):
            return torch.sparse.mm(self.a, x)
        return torch.from_numpy(self.a @ x.numpy())


@functools.cache
def _grid_laplacian(size: int, device: torch.device) -> torch.Tensor:
    """(n, n) the graph Laplacian of a size x size texel grid (4-neighbours), n = size^2, in
    float64; built once per size, as every candidate spin of a search solves with it."""
    n = size * size
    index = torch.arange(n, device=device).reshape(size, size)
    laplacian = torch.zeros(n, n, device=device, dtype=torch.float64)
    for a, b in ((index[:, 1:], index[:, :-1]), (index[1:], index[:-1])):
        a, b = a.reshape(-1), b.reshape(-1)
        laplacian.index_put_((a, a), torch.ones_like(a, dtype=laplacian.dtype), accumulate=True)
        laplacian.index_put_((b, b), torch.ones_like(b, dtype=laplacian.dtype), accumulate=True)
        laplacian.index_put_((a, b), -torch.ones_like(a, dtype=laplacian.dtype), accumulate=True)
        laplacian.index_put_((b, a), -torch.ones_like(a, dtype=laplacian.dtype), accumulate=True)
    return laplacian


def solve_texture(system: TextureSystem, size: int, smoothness: float) -> tuple[torch.Tensor, float]:
    """The texture that minimises ||A x - b||^2 + smoothness * (squared texel differences).

    Args:
        system: A and b (:func:`texture_system`).

    Returns:
        the texture (3, size, size) and its residual ||A x - b||^2.
    """
    n = size * size
    products = _Products(system)
    gram = products.gram()
    # A tiny ridge keeps texels that no pixel sees (and the Laplacian's constant null space)
    # solvable; float64, as float32 Cholesky fails on such nearly singular systems.
    eye = torch.eye(n, device=gram.device, dtype=torch.float64)
    matrix = gram.double() + smoothness * _grid_laplacian(size, gram.device) + 1e-6 * eye
    rhs = products.transposed_times(system.target).double()
    texels = torch.cholesky_solve(rhs, torch.linalg.cholesky(matrix)).to(system.target.dtype)
    residual = float((products.times(texels) - system.target).square().sum())
    return texels.T.reshape(3, size, size), residual


def score_spin(
    spin: torch.Tensor,
    poses: Poses,
    crops: Sequence[Crop],
    vertices: torch.Tensor,
    topology: MeshTopology,
    size: int,
    smoothness: float,
    settings: RenderConfig,
) -> SpinScore:
    """The best coarse texture's residual over the window for one candidate ``spin`` (3,)."""
    rotations, positions = poses(spin)
    posed = [pose_vertices(vertices, r, p) for r, p in zip(rotations, positions, strict=True)]
    texture, residual = solve_texture(texture_system(crops, posed, topology, size, settings), size, smoothness)
    return SpinScore(spin, residual, texture)


def search_spin(
    candidates: torch.Tensor,
    score: Callable[[torch.Tensor], SpinScore],
    refine_deg: Sequence[float],
    known: Sequence[SpinScore] = (),
) -> tuple[SpinScore, int]:
    """The candidate spin of lowest residual, refined by a pattern search.

    Args:
        candidates: (K, 3) spins to score (per frame interval).
        score: spin (3,) -> its :class:`SpinScore`.
        refine_deg: the pattern search's step sizes, largest first: at each, the spin moves by
            that angle along +-x, +-y, +-z while a move lowers the residual.
        known: spins scored already, candidates too but not scored again.

    Returns:
        the best score and the number of spins scored.
    """
    best = min([*known, *(score(s) for s in candidates)], key=lambda s: s.residual)
    scored = len(candidates)
    for step_deg in refine_deg:
        step = math.radians(step_deg)
        moved = True
        while moved:
            moves = [
                best.spin + sign * step * axis for axis in torch.eye(3, device=best.spin.device) for sign in (1.0, -1.0)
            ]
            trial = min((score(s) for s in moves), key=lambda s: s.residual)
            scored += len(moves)
            moved = trial.residual < best.residual
            if moved:
                best = trial
    return best, scored


def upsample_texture(texture: torch.Tensor, size: int) -> torch.Tensor:
    """A (3, s, s) texture resampled to (3, size, size), clamped to [0, 1]."""
    resized = F.interpolate(texture[None], size=(size, size), mode="bilinear", align_corners=False)[0]
    return resized.clamp(0, 1)
