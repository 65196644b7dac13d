"""The footprint a streak shows once its travel is known, and the prototypes fitted to it."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
import torch

from sfb_video.config import CropConfig
from sfb_video.crop import object_region
from sfb_video.fitting.shapes import Footprint, footprint, frame_footprint, shaped_start, unswept
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
    mask = object_region(image, background, CropConfig().region_threshold, CropConfig().region_noise)
    half = 0.5 * travel * torch.tensor([math.cos(a), math.sin(a)])
    centre = torch.tensor([60.0, 60.0])
    return SimpleNamespace(
        image=image,
        background=background,
        streak=mask,
        ends=(centre - half, centre + half),
        camera=SimpleNamespace(fy=1.0),
    )


@pytest.mark.parametrize("angle", [0.0, 30.0, 115.0])
def test_the_travel_is_taken_off_the_streak_length(angle: float) -> None:
    # A 12 px wide pen 30 px long that moved 40 px along itself leaves a 70 px streak, fainter
    # at its ends, where a threshold would cut it.
    crop = _streak(30, 12, angle, 40.0)
    along, across, direction = frame_footprint(crop, torch.stack(crop.ends))
    assert along == pytest.approx(30.0, rel=0.1)
    assert across == pytest.approx(12.0, rel=0.1)
    assert abs(float(direction @ torch.tensor([math.cos(math.radians(angle)), math.sin(math.radians(angle))]))) > 0.999


def test_a_pen_lying_at_a_slant_to_its_motion_is_measured_whole() -> None:
    # A 40 x 6 pen at 45 degrees to its 30 px of motion: the streak's spans along and across the
    # motion would say 28 x 34; undoing the sweep gives the pen.
    a = math.radians(10.0)
    coverage = torch.zeros(120, 120)
    for tau in torch.linspace(-0.5, 0.5, 61):
        dx, dy = float(tau) * 30 * math.cos(a), float(tau) * 30 * math.sin(a)
        coverage += torch.roll(_bar(40, 6, 55.0), (round(dy), round(dx)), (0, 1))
    coverage /= 61
    background = torch.full((3, 120, 120), 0.3)
    image = background + 0.5 * coverage
    config = CropConfig()
    crop = SimpleNamespace(image=image, background=background)
    crop.streak = object_region(image, background, config.region_threshold, config.region_noise)
    half = 15 * torch.tensor([math.cos(a), math.sin(a)])
    centre = torch.tensor([60.0, 60.0])
    long_, short, axis = frame_footprint(crop, torch.stack((centre - half, centre + half)))
    assert long_ == pytest.approx(40.0, rel=0.1) and short == pytest.approx(6.0, abs=2.5)
    assert abs(float(axis @ torch.tensor([math.cos(math.radians(55.0)), math.sin(math.radians(55.0))]))) > 0.99


@pytest.mark.parametrize("travel", [(-130.0, 20.0), (5.0, 125.0), (-60.0, -70.0)])
def test_a_travel_longer_than_the_crop_leaves_no_outline(travel: tuple[float, float]) -> None:
    # Real footage: a path that overshoots a small crop (falling_pen crashed here).
    mask = torch.zeros(27, 29, dtype=torch.bool)
    mask[5:20, 5:25] = True
    assert not bool(unswept(mask, torch.tensor([(0.0, 0.0), travel])).any())
    crop = SimpleNamespace(streak=mask)
    long_, short, _ = frame_footprint(crop, torch.tensor([(0.0, 0.0), travel]))
    assert long_ >= 1.0 and short >= 1.0


def test_unswept_undoes_a_short_sweep_in_every_direction() -> None:
    mask = torch.zeros(40, 40, dtype=torch.bool)
    mask[10:30, 10:30] = True
    for travel in ((6.0, 0.0), (-6.0, 0.0), (0.0, 6.0), (0.0, -6.0)):
        assert int(unswept(mask, torch.tensor([(0.0, 0.0), travel])).sum()) == 20 * 14


def test_a_ball_swung_along_an_arc_stays_round() -> None:
    # A 20 px ball swept along a quarter circle of radius 40 (a ball on a string): eroded by
    # the arc it is a ball again; the arc's 57 px chord would leave a sliver.
    size, radius, ball = 120, 40.0, 10.0
    ys, xs = torch.meshgrid(torch.arange(size).float(), torch.arange(size).float(), indexing="ij")
    angles = torch.linspace(0.0, math.pi / 2, 91)
    centres = torch.stack((20 + radius * torch.cos(angles), 20 + radius * torch.sin(angles)), -1)
    mask = torch.zeros(size, size, dtype=torch.bool)
    for cx, cy in centres:
        mask |= (xs - cx) ** 2 + (ys - cy) ** 2 <= ball**2
    crop = SimpleNamespace(streak=mask)
    long_, short, _ = frame_footprint(crop, centres[::10])
    assert long_ == pytest.approx(21.0, abs=3.0) and short == pytest.approx(21.0, abs=3.0)
    chord_long, chord_short, _ = frame_footprint(crop, centres[[0, -1]])
    assert chord_long / chord_short > 1.5  # the straight chord reads it long


def test_a_region_of_one_pixel_has_a_footprint() -> None:
    crop = _streak(30, 12, 0.0, 40.0)
    crop.streak = torch.zeros(120, 120, dtype=torch.bool)
    crop.streak[60, 60] = True
    along, across, direction = frame_footprint(crop, torch.stack(crop.ends))
    assert (along, across) == (1.0, 1.0) and float(direction[0]) == pytest.approx(1.0)


def test_a_pen_moving_across_itself_lies_across_its_streak() -> None:
    # A pen 40 px long and 6 wide lying across its motion, moved 20 px.
    crop = _streak(40, 6, 0.0, 20.0, across_motion=True)
    outline = footprint([crop], torch.stack(crop.ends)[None], 0, 1.0)
    assert outline.long_px == pytest.approx(40.0, rel=0.1) and outline.short_px == pytest.approx(6.0, rel=0.25)
    assert abs(float(outline.axis[1])) > 0.999  # the long side is vertical, across the motion


def test_a_spinning_pen_shows_a_long_object_and_a_ball_does_not() -> None:
    # A 36 x 8 pen that lies along its motion in one frame and across it in the next: the
    # medians of each frame's long and short sides, not of its along and across extents.
    frames = [_streak(36, 8, 20.0, 30.0, across_motion=k % 2 == 1) for k in range(3)]
    outline = footprint(frames, torch.stack([torch.stack(f.ends) for f in frames]), 1, 1.0)
    assert outline.long_px == pytest.approx(36.0, rel=0.1) and outline.short_px == pytest.approx(8.0, rel=0.3)
    assert outline.shows("long") and outline.shows("flat")
    assert abs(float(outline.axis @ torch.tensor([math.cos(math.radians(20.0)), math.sin(math.radians(20.0))]))) < 0.02
    balls = [_streak(24, 24, 20.0, 30.0) for _ in range(3)]
    round_ = footprint(balls, torch.stack([torch.stack(f.ends) for f in balls]), 0, 1.0)
    assert not round_.shows("long") and not round_.shows("flat")


def test_the_footprint_is_in_full_frame_pixels() -> None:
    # The same streak in a crop downsampled by 2 (its focal length halved) measures the same.
    crop = _streak(30, 12, 0.0, 40.0)
    crop.camera = SimpleNamespace(fy=0.5)
    outline = footprint([crop], torch.stack(crop.ends)[None], 0, 1.0)
    assert outline.long_px == pytest.approx(60.0, rel=0.1) and outline.short_px == pytest.approx(24.0, rel=0.1)


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
    assert along == pytest.approx(60.0, rel=0.02)
    # Its outline's short side matches the footprint's (the disc and ring tilted so).
    assert across == pytest.approx(20.0, rel=0.15)


def test_a_round_footprint_starts_a_sphere_of_its_diameter() -> None:
    along, across = _projected_extents("sphere", Footprint(30.0, 30.0, torch.tensor([1.0, 0.0])))
    assert along == pytest.approx(30.0, rel=0.02) and across == pytest.approx(30.0, rel=0.02)


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
