"""The footprint a streak shows once its travel is known, and the prototypes fitted to it."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from sfb_video.fitting.shapes import Footprint, footprint, frame_footprint, shaped_start
from sfb_video.geometry.mesh import box_fill
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.geometry.rotation import axis_angle_to_matrix


def _bar(length: float, width: float, angle_deg: float, shift: float = 0.0, size: int = 120) -> torch.Tensor:
    """(size, size) mask of a length x width bar at ``angle_deg``, ``shift`` px along itself
    from the centre."""
    ys, xs = torch.meshgrid(torch.arange(size).float(), torch.arange(size).float(), indexing="ij")
    a = math.radians(angle_deg)
    along = (xs - size / 2) * math.cos(a) + (ys - size / 2) * math.sin(a) - shift
    across = -(xs - size / 2) * math.sin(a) + (ys - size / 2) * math.cos(a)
    return ((along.abs() < length / 2) & (across.abs() < width / 2)).float()


def _streak(
    length: float, width: float, angle_deg: float, travel: float, across_motion: bool = False
) -> SimpleNamespace:
    """A crop whose image is a grey background with a bright bar blurred by ``travel`` px of
    motion along ``angle_deg`` (the bar lies along the motion, or across it), and the
    exposure's ends of its centre."""
    bar_angle = angle_deg + (90.0 if across_motion else 0.0)
    a = math.radians(angle_deg)
    coverage = torch.zeros(120, 120)
    for tau in torch.linspace(-0.5, 0.5, 65):
        shift = float(tau) * travel
        if across_motion:
            # Moving across the bar: its centre shifts along the motion, normal to the bar.
            dx, dy = shift * math.cos(a), shift * math.sin(a)
            coverage += torch.roll(_bar(length, width, bar_angle), (round(dy), round(dx)), (0, 1))
        else:
            coverage += _bar(length, width, bar_angle, shift)
    coverage /= 65
    background = torch.full((3, 120, 120), 0.3)
    image = background + 0.5 * coverage
    mask = coverage > 0.05
    half = 0.5 * travel * torch.tensor([math.cos(a), math.sin(a)])
    centre = torch.tensor([60.0, 60.0])
    return SimpleNamespace(image=image, background=background, object_mask=mask, ends=(centre - half, centre + half))


@pytest.mark.parametrize("angle", [0.0, 30.0, 115.0])
def test_the_travel_is_taken_off_the_streak_length(angle: float) -> None:
    # A 12 px wide pen 30 px long that moved 40 px along itself leaves a 70 px streak, fainter
    # at its ends, where a threshold would cut it.
    crop = _streak(30, 12, angle, 40.0)
    along, across, direction = frame_footprint(crop, *crop.ends)
    assert along == pytest.approx(30.0, rel=0.1)
    assert across == pytest.approx(12.0, rel=0.1)
    assert float(direction @ torch.tensor([math.cos(math.radians(angle)), math.sin(math.radians(angle))])) > 0.999


def test_a_streak_lost_in_the_noise_is_measured_on_its_mask() -> None:
    # Constant noise-free crops: nothing stands above the noise floor, and the mask still
    # holds the 70 x 12 streak; the footprint must come from it, not be NaN.
    crop = _streak(30, 12, 0.0, 40.0)
    flat = SimpleNamespace(image=crop.background.clone(), background=crop.background, object_mask=crop.object_mask)
    along, across, _ = frame_footprint(flat, *crop.ends)
    assert math.isfinite(along) and math.isfinite(across)
    assert across == pytest.approx(12.0, rel=0.15)


def test_a_pen_moving_across_itself_lies_across_its_streak() -> None:
    # A pen 40 px long and 6 wide lying across its motion, moved 20 px.
    crop = _streak(40, 6, 0.0, 20.0, across_motion=True)
    outline = footprint([crop], crop.ends[0][None], crop.ends[1][None], 0)
    assert outline.long_px == pytest.approx(40.0, rel=0.1) and outline.short_px == pytest.approx(6.0, rel=0.25)
    assert abs(float(outline.axis[1])) > 0.999  # the long side is vertical, across the motion


def _projected_extents(name: str, outline: Footprint) -> tuple[float, float]:
    start = shaped_start(name, outline)
    posed = start.vertices @ start.rotation.T * start.size_px  # pixels, the camera looking along z
    axis = outline.axis
    normal = torch.stack((-axis[1], axis[0]))
    xy = posed[:, :2]
    along, across = xy @ axis, xy @ normal
    return float(along.max() - along.min()), float(across.max() - across.min())


@pytest.mark.parametrize("name", ["capsule", "box", "disc", "torus"])
def test_each_shaped_start_covers_the_footprint_along_its_axis(name: str) -> None:
    outline = Footprint(long_px=60.0, short_px=20.0, axis=torch.tensor([0.6, 0.8]))
    along, across = _projected_extents(name, outline)
    # The footprint's extents are box-equivalent: a round outline is 4 / sqrt(12) of them across.
    wide = 4 / math.sqrt(12) if name in ("disc", "torus") else 1.0
    assert along == pytest.approx(60.0 * wide, rel=0.02)
    # Its outline's short side matches the footprint's (the disc and ring tilted so).
    assert across == pytest.approx(20.0 * wide, rel=0.15)


def test_a_round_footprint_starts_a_sphere_of_its_diameter() -> None:
    along, across = _projected_extents("sphere", Footprint(30.0, 30.0, torch.tensor([1.0, 0.0])))
    diameter = 30.0 * 4 / math.sqrt(12)  # a disc's box-equivalent extent is sqrt(12) / 4 of its diameter
    assert along == pytest.approx(diameter, rel=0.02) and across == pytest.approx(diameter, rel=0.02)


def test_the_box_has_flat_faces_and_the_disc_is_flat() -> None:
    box, _ = load_prototype("box")
    # Every vertex lies on one of the six faces: its largest coordinate is the half side.
    assert float((box.abs().amax(-1) - box.abs().amax()).abs().max()) < 1e-3
    disc, _ = load_prototype("disc")
    extent = disc.amax(0) - disc.amin(0)
    assert float(extent[2]) == pytest.approx(0.25 * float(extent[0]), rel=0.02)


def test_box_fill_tells_a_box_from_a_ball() -> None:
    box, topology = load_prototype("box")
    sphere, _ = load_prototype("sphere")
    stretched = box * torch.tensor([1.0, 2.5, 0.6])
    turned = stretched @ axis_angle_to_matrix(torch.tensor([0.4, -0.7, 0.2])).T
    assert box_fill(turned, topology.faces) > 0.95
    assert box_fill(sphere, topology.faces) == pytest.approx(math.pi / 6, abs=0.02)
