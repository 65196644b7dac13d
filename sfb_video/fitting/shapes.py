"""The shape a window starts from, read off its streaks once the path and exposure are known.

A streak is the object's footprint swept along its travel within the exposure. With the path
fitted to the seeds (:func:`sfb_video.fitting.window.start_window`) the travel is known, so the
object's extent along the motion is the streak's length minus the travel, and across it the
streak's width (:func:`footprint`). A long footprint is a pen or a key lying along it (or across,
when the width is the larger), a round one a ball, a box or a disc seen face on.

Each prototype is then stretched to that footprint, turned so that its long axis lies along it
(a disc tilted so that its outline's short side matches), and sized so that its long side covers
the footprint's (:func:`shaped_start`). Every one is scored fairly, by the residual of the best
coarse texture on the window's frames at its own size and orientation
(:func:`sfb_video.fitting.spin.score_spin`), not by a few Adam steps from grey, which favour
whoever starts nearest in size.
"""

from __future__ import annotations

import math
import statistics
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from sfb_video.crop import Crop
from sfb_video.geometry.mesh import MeshTopology, normalize_vertices
from sfb_video.geometry.prototypes import capsule, load_prototype
from sfb_video.geometry.rotation import axis_angle_to_matrix

MAX_ASPECT = 8.0
"""The longest footprint taken from a streak: beyond it the travel ate the streak's length (an
exposure taken too long), and the measure says no more than "thin"."""


@dataclass(frozen=True)
class Footprint:
    """The object's outline in the image, as the window's streaks show it.

    Attributes:
        long_px, short_px: its longer and shorter extent in pixels (the medians over frames).
        axis: (2,) unit image direction of the long side in the reference frame's crop.
    """

    long_px: float
    short_px: float
    axis: torch.Tensor

    @property
    def aspect(self) -> float:
        return self.long_px / self.short_px


def frame_footprint(crop: Crop, start: torch.Tensor, end: torch.Tensor) -> tuple[float, float, torch.Tensor]:
    """One frame's object extent along and across its motion, and the motion's direction.

    From second moments of the difference from the background, not from a thresholded mask: a
    thin or faint object covers each pixel of its streak so briefly that a threshold keeps a
    fraction of it, and the ends of every streak, where coverage ramps up, fall below it. The
    streak is the object's outline swept by a box of the travel T, so along the motion the
    variances add: the object's own is the streak's less T^2 / 12. Extents are box-equivalent,
    sqrt(12 var): a bar's length, 0.87 of a disc's diameter.

    Args:
        crop: the frame's crop; its difference from the background, smoothed, is weighed above
            the crop's noise.
        start, end: (2,) the object centre's image positions at the exposure's ends (crop pixels).

    Returns:
        the extent along the motion (at least a pixel), the extent across it, and the (2,) unit
        direction of the motion.
    """
    difference = F.avg_pool2d((crop.image - crop.background).abs().sum(0)[None, None], 3, 1, 1, False)[0, 0]
    # Most of a crop is background: its median and spread are the noise, which weighs nothing.
    level = difference.median()
    spread = (difference - level).abs().median()
    weight = (difference - level - 4 * 1.4826 * spread).clamp_min(0)
    if not bool((weight > 0).any()):
        # The whole streak within the noise: the object's mask, each pixel alike, is all there is.
        weight = crop.object_mask.to(difference.dtype)
    ys, xs = torch.nonzero(weight > 0, as_tuple=True)
    w = weight[ys, xs].double()
    pts = torch.stack((xs, ys), -1).double()
    centre = (w[:, None] * pts).sum(0) / w.sum()
    cov = ((pts - centre).T * w) @ (pts - centre) / w.sum()
    travel = (end - start).double()
    # With no travel to take off, the streak's own principal axis is the motion's best guess.
    direction = torch.linalg.eigh(cov)[1][:, -1] if float(travel.norm()) < 1.0 else travel / travel.norm()
    normal = torch.stack((-direction[1], direction[0]))
    var_along = float(direction @ cov @ direction) - float(travel.norm()) ** 2 / 12
    along = math.sqrt(max(12 * var_along, 1.0))
    return along, math.sqrt(max(12 * float(normal @ cov @ normal), 1.0)), direction.float()


def footprint(crops: list[Crop], starts: torch.Tensor, ends: torch.Tensor, reference: int) -> Footprint:
    """The window's footprint: the medians of its frames' extents, oriented as in frame ``reference``.

    Args:
        crops: the window's crops; starts, ends: (F, 2) each frame's centre at the exposure's ends.
        reference: the frame whose motion direction orients the long axis.
    """
    extents = [frame_footprint(c, s, e) for c, s, e in zip(crops, starts, ends, strict=True)]
    along = statistics.median(a for a, _, _ in extents)
    across = statistics.median(b for _, b, _ in extents)
    direction = extents[reference][2]
    axis = direction if along >= across else torch.stack((-direction[1], direction[0]))
    long_px, short_px = max(along, across), min(along, across)
    short_px = max(short_px, long_px / MAX_ASPECT)
    return Footprint(long_px, short_px, axis)


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
    # The footprint's extents are box-equivalent (sqrt(12 var)): a round outline's diameter is
    # 4 / sqrt(12) of them, a bar's length the same.
    round_ = 4 / math.sqrt(12) if name in ("sphere", "sphere_large", "disc", "torus") else 1.0
    if name in ("sphere", "sphere_large"):
        size_px = round_ * math.sqrt(print_.long_px * print_.short_px) / long_units
    else:
        size_px = round_ * print_.long_px / long_units
    dx, dy = (float(v) for v in print_.axis)
    # Columns: the object's x, y (long) and z axes in camera space, z toward the scene.
    frame = torch.tensor([[dy, dx, 0.0], [-dx, dy, 0.0], [0.0, 0.0, 1.0]])
    tilt_about_long = axis_angle_to_matrix(frame[:, 1] * tilt)
    return ShapedStart(name, vertices, topology, tilt_about_long @ frame, size_px)
