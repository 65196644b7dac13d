"""The shape a window starts from, read off its streaks once the path and exposure are known.

A streak is the object's outline swept along its travel within the exposure. With the path
fitted to the seeds (:func:`sfb_video.fitting.window.start_window`) the travel is known, so the
sweep can be undone: the streak's region eroded by the travel's segment is the outline, however
the object lies to its motion (:func:`unswept`, :func:`footprint`). A long outline is a pen or
a key, a round one a ball, a box or a disc seen face on; an outline that is round in every frame
gives a long or flat prototype no evidence over the ball (:meth:`Footprint.shows`).

Each prototype is then stretched to that footprint, turned so that its long axis lies along it
(a disc tilted so that its outline's short side matches), and sized so that its long side covers
the footprint's (:func:`shaped_start`). Every one is scored fairly, by the residual of the best
coarse texture on the window's frames at its own size and orientation
(:func:`sfb_video.fitting.spin.score_spin`), not by a few Adam steps from grey, which favour
whoever starts nearest in size.
"""

from __future__ import annotations

import itertools
import math
import statistics
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from sfb_video.crop import Crop
from sfb_video.geometry.mesh import MeshTopology, normalize_vertices
from sfb_video.geometry.prototypes import capsule, load_prototype
from sfb_video.geometry.rotation import axis_angle_to_matrix

MAX_ASPECT = 8.0
"""The longest footprint taken from a streak: beyond it the travel ate the streak's length (an
exposure taken too long), and the measure says no more than "thin"."""

ELONGATED = 1.4
"""A footprint whose frames' outlines are at least this long to one, in the median, shows a long
object: below it a capsule has no evidence over a ball (a ball's outline measures 1.0-1.25)."""

EDGE_ON = 1.8
"""A frame whose outline is at least this long to one shows a flat object near its edge: a disc
or ring seen face on in every frame draws a ball's outline, and the ball is the simpler answer."""

NEEDS = {"capsule": "long", "disc": "flat", "torus": "flat"}
"""The prototypes that need the footprint's evidence (:meth:`Footprint.shows`) to enter a trial."""


@dataclass(frozen=True)
class Footprint:
    """The object's outline in the image, as the window's streaks show it.

    Attributes:
        long_px, short_px: its longer and shorter extent in full-frame pixels (the medians
            over frames of each frame's longer and shorter side: a spinning pen lies along its
            motion in one frame and across it in the next).
        axis: (2,) unit image direction of the long side in the reference frame.
        aspects: each frame's outline, long to short.
    """

    long_px: float
    short_px: float
    axis: torch.Tensor
    aspects: tuple[float, ...] = ()

    @property
    def aspect(self) -> float:
        return self.long_px / self.short_px

    def shows(self, evidence: str) -> bool:
        """Whether the frames show a "long" object (median aspect >= :data:`ELONGATED`) or a
        "flat" one (some frame at least :data:`EDGE_ON`)."""
        if evidence == "long":
            return statistics.median(self.aspects or (self.aspect,)) >= ELONGATED
        return max(self.aspects or (self.aspect,)) >= EDGE_ON


def _filled(mask: torch.Tensor) -> torch.Tensor:
    """(H, W) bool ``mask`` with its holes filled: what the border cannot reach is inside."""
    flooded = np.pad(mask.cpu().numpy().astype(np.uint8), 1)
    cv2.floodFill(flooded, None, (0, 0), 1)
    return mask | torch.from_numpy(flooded[1:-1, 1:-1] == 0).to(mask.device)


def _offsets(track: torch.Tensor) -> list[tuple[int, int]]:
    """The whole-pixel offsets from ``track``'s (K, 2) first position that its polyline passes,
    at most a pixel apart."""
    offsets = {(0, 0)}
    for a, b in itertools.pairwise(track):
        steps = max(1, math.ceil(float((b - a).norm())))
        for k in range(1, steps + 1):
            dx, dy = (round(float(v)) for v in a + (b - a) * k / steps - track[0])
            offsets.add((dx, dy))
    return sorted(offsets)


def unswept(mask: torch.Tensor, track: torch.Tensor) -> torch.Tensor:
    """The object's outline whose sweep along ``track`` made the streak ``mask`` (H, W).

    A streak is the outline swept along the object's track within the exposure, a Minkowski sum
    with that curve; eroding the streak by the curve undoes it (exactly for a convex outline),
    whatever way the object lies to its motion. The track's curve matters: a ball swung on a
    string draws an arc, which its straight chord would erode into a long outline.

    Args:
        mask: (H, W) bool streak region.
        track: (K, 2) the object centre's image positions over the exposure, K >= 2, in order.

    Returns:
        (H, W) bool outline, placed where the exposure starts.
    """
    height, width = mask.shape
    out = mask.clone()
    for dx, dy in _offsets(track.double()):
        if abs(dx) >= width or abs(dy) >= height:
            # A travel longer than the crop: no outline fits inside it (the caller falls back).
            return torch.zeros_like(mask)
        shifted = torch.zeros_like(mask)
        # shifted(p) = mask(p + (dx, dy)), False beyond the crop.
        target = slice(max(0, -dy), height - max(0, dy)), slice(max(0, -dx), width - max(0, dx))
        shifted[target] = mask[max(0, dy) : height - max(0, -dy), max(0, dx) : width - max(0, -dx)]
        out &= shifted
    return out


def _extents(points: torch.Tensor, axis: torch.Tensor) -> tuple[float, float]:
    """Spans (pixels, a pixel included) of (P, 2) ``points`` along ``axis`` (2,) and across it."""
    normal = torch.stack((-axis[1], axis[0]))
    along, across = points @ axis, points @ normal
    return float(along.max() - along.min()) + 1.0, float(across.max() - across.min()) + 1.0


def frame_footprint(crop: Crop, track: torch.Tensor) -> tuple[float, float, torch.Tensor]:
    """One frame's object outline: its long and short side, and the (2,) direction of the long one.

    From the crop's streak, its object region grown into the faint parts
    (:func:`sfb_video.crop.object_region`), its holes filled and the sweep undone
    (:func:`unswept`); the outline's sides are its spans along and across its principal axis.
    Where nothing survives the erosion (a streak broken by an occluder, or smeared wider by a
    spin), the region's spans along and across the motion stand in, the travel taken off the
    first. Extents, not moments: moments of the difference weigh the pixels by contrast, and a
    striped grey pen shows contrast at one end only.

    Args:
        crop: the frame's crop.
        track: (K, 2) the object centre's image positions over the exposure (crop pixels), K >= 2.

    Returns:
        the long side, the short side (each at least a pixel) and the long side's direction.
    """
    track = track.double()
    travel = track[-1] - track[0]
    direction = travel / travel.norm().clamp_min(1e-9)
    region = _filled(crop.streak)
    outline = unswept(region, track)
    ys, xs = torch.nonzero(outline if int(outline.sum()) >= 2 else region, as_tuple=True)
    if len(xs) < 2:
        return 1.0, 1.0, direction.float()
    pts = torch.stack((xs, ys), -1).double()
    if int(outline.sum()) >= 2:
        centred = pts - pts.mean(0)
        axis = torch.linalg.eigh(centred.T @ centred)[1][:, -1]
        long_, short = _extents(pts, axis)
    else:
        along, across = _extents(pts, direction)
        along = max(along - float(travel.norm()), 1.0)
        axis = direction if along >= across else torch.stack((-direction[1], direction[0]))
        long_, short = max(along, across), min(along, across)
    return long_, short, axis.float()


def footprint(crops: list[Crop], tracks: torch.Tensor, reference: int, fy: float) -> Footprint:
    """The window's footprint in full-frame pixels, oriented as in frame ``reference``.

    Args:
        crops: the window's crops; tracks: (F, K, 2) each frame's centre over its exposure, in
            its crop's pixels.
        reference: the frame whose outline orients the long axis.
        fy: the full frame's focal length in pixels (a crop may be downsampled).
    """
    extents = []
    for crop, track in zip(crops, tracks, strict=True):
        long_, short, axis = frame_footprint(crop, track)
        scale = fy / float(crop.camera.fy)
        extents.append((long_ * scale, short * scale, axis))
    long_px = statistics.median(a for a, _, _ in extents)
    short_px = max(statistics.median(b for _, b, _ in extents), long_px / MAX_ASPECT)
    aspects = tuple(min(a / b, MAX_ASPECT) for a, b, _ in extents)
    return Footprint(long_px, short_px, extents[reference][2], aspects)


@dataclass(frozen=True)
class ShapedStart:
    """A prototype fitted to a footprint.

    Attributes:
        name: the prototype's name.
        vertices: (V, 3) at unit scale, its long axis along y; topology: its faces and UVs.
        rotation: (3, 3) object to camera: y along the footprint's axis, tilted about it.
        size_px: pixels per object unit that make its long side cover the footprint's.
    """

    name: str
    vertices: torch.Tensor
    topology: MeshTopology
    rotation: torch.Tensor
    size_px: float


def _stretched(name: str, aspect: float) -> tuple[torch.Tensor, MeshTopology]:
    """The prototype ``name`` at unit scale with its long axis along y and ``aspect`` to one
    (long to short, within the shape's own limits; a flat one is tilted instead)."""
    if name == "capsule":
        # Thinner than 1.5 to one a capsule is a sphere; the trial then has nothing to choose.
        return capsule(half_length=max(aspect, 1.5) - 1)
    vertices, topology = load_prototype(name)
    if name == "box":
        return normalize_vertices(vertices * torch.tensor([1.0, aspect, 1.0])), topology
    if name == "torus":  # its ring in x-z; the disc's faces are normal to z, as here
        vertices = vertices[:, [0, 2, 1]] * torch.tensor([1.0, 1.0, -1.0])
    return vertices, topology


def _tilt(vertices: torch.Tensor, aspect: float) -> float:
    """The tilt (rad) about y that makes a flat object's outline (x extent, thickness included)
    1 / ``aspect`` of its diameter (y extent): a round flat object seen at a slant."""
    diameter = float(vertices[:, 1].max() - vertices[:, 1].min())
    angles = torch.linspace(0, math.pi / 2, 91)
    x = vertices[:, 0:1] * torch.cos(angles) + vertices[:, 2:3] * torch.sin(angles)  # (V, 91)
    outline = (x.amax(0) - x.amin(0)) / diameter
    return float(angles[(outline - 1 / aspect).abs().argmin()])


def shaped_start(name: str, print_: Footprint) -> ShapedStart:
    """Prototype ``name`` stretched, turned and sized to the footprint (see the module docstring)."""
    vertices, topology = _stretched(name, print_.aspect)
    tilt = _tilt(vertices, print_.aspect) if name in ("disc", "torus") else 0.0
    long_units = float(vertices[:, 1].max() - vertices[:, 1].min())
    if name in ("sphere", "sphere_large"):
        size_px = math.sqrt(print_.long_px * print_.short_px) / long_units
    else:
        size_px = print_.long_px / long_units
    dx, dy = (float(v) for v in print_.axis)
    # Columns: the object's x, y (long) and z axes in camera space, z toward the scene.
    frame = torch.tensor([[dy, dx, 0.0], [-dx, dy, 0.0], [0.0, 0.0, 1.0]])
    tilt_about_long = axis_angle_to_matrix(frame[:, 1] * tilt)
    return ShapedStart(name, vertices, topology, tilt_about_long @ frame, size_px)
