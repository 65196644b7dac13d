import math

import pytest
import torch

from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.rotation import axis_angle_to_matrix, rotation_angle_deg
from sfb_video.model.motion import (
    Motion,
    MotionParams,
    cap_rotation,
    continue_motion,
    continue_turning,
    streak_from_mask,
)

CAMERA = PinholeCamera.from_fov(320, 240, 45.0).crop(60, 40, 160, 120, 160, 120)


def test_positions_stay_inside_the_crop_and_the_size_range() -> None:
    params = MotionParams(CAMERA, (0.05, 1.0), 1.5, 120.0, 0.4)
    with torch.no_grad():
        params.ends.copy_(torch.randn(2, 3) * 10)
    uv, depth = CAMERA.project(params.positions())
    # tanh saturates to the crop's edge in float32; the centre never leaves the crop.
    eps = 1e-3
    inside = (uv[:, 0] >= -0.5 - eps) & (uv[:, 0] <= 159.5 + eps) & (uv[:, 1] >= -0.5 - eps) & (uv[:, 1] <= 119.5 + eps)
    assert bool(inside.all())
    diameter_frac = CAMERA.fy / depth / CAMERA.height
    assert 0.05 - 1e-6 <= diameter_frac[0] <= 1.0 + 1e-6
    assert 1 / 1.5 - 1e-5 <= diameter_frac[1] / diameter_frac[0] <= 1.5 + 1e-5


def test_rotation_cap_is_smooth_and_bounded() -> None:
    cap = math.radians(120)
    small = torch.tensor([1e-3, -2e-3, 0.5e-3])
    assert torch.allclose(cap_rotation(small, cap), small, rtol=1e-4)
    assert cap_rotation(torch.tensor([50.0, 0.0, 0.0]), cap).norm() <= cap + 1e-6
    assert cap_rotation(torch.tensor([2.0, 0.0, 0.0]), cap).norm() < 2.0


def test_load_motion_round_trips() -> None:
    motion = Motion(
        x0=CAMERA.unproject(torch.tensor([40.0, 70.0]), torch.tensor(5.0)),
        dx=torch.tensor([0.8, -0.3, 0.4]),
        rot0=axis_angle_to_matrix(torch.tensor([0.3, -0.2, 1.0])),
        omega=torch.tensor([0.0, 1.2, 0.4]),
    )
    params = MotionParams(CAMERA, (0.05, 1.0), 1.5, 120.0, 0.4)
    params.load_motion(motion)
    back = params.motion()
    assert torch.allclose(back.x0, motion.x0, atol=1e-4)
    assert torch.allclose(back.dx, motion.dx, atol=1e-4)
    assert rotation_angle_deg(back.rot0, motion.rot0) < 1e-2
    assert torch.allclose(back.omega, motion.omega, atol=1e-4)


def test_reversed_motion_runs_the_same_path_backwards() -> None:
    motion = Motion(
        torch.tensor([0.0, 0.0, 4.0]), torch.tensor([1.0, 0.5, 0.0]), torch.eye(3), torch.tensor([0, 1.0, 0])
    )
    taus = torch.tensor([0.0, 0.3, 1.0])
    rot_f, pos_f = motion.at(taus)
    rot_b, pos_b = motion.reversed().at(1 - taus)
    assert torch.allclose(pos_f, pos_b, atol=1e-6)
    assert torch.allclose(rot_f, rot_b, atol=1e-5)


def test_streak_from_a_capsule_mask() -> None:
    ys, xs = torch.meshgrid(torch.arange(100.0), torch.arange(200.0), indexing="ij")
    a, b, r = torch.tensor([50.0, 40.0]), torch.tensor([150.0, 60.0]), 12.0
    ab = b - a
    lam = (((torch.stack((xs, ys), -1) - a) @ ab) / ab.dot(ab)).clamp(0, 1)
    closest = a + lam[..., None] * ab
    mask = ((torch.stack((xs, ys), -1) - closest).norm(dim=-1) <= r).float()
    streak = streak_from_mask(mask)
    ends = sorted([streak.start.tolist(), streak.end.tolist()])
    assert ends[0] == pytest.approx(a.tolist(), abs=3.0)
    assert ends[1] == pytest.approx(b.tolist(), abs=3.0)
    assert streak.diameter == pytest.approx(2 * r, rel=0.05)


def test_streak_of_a_still_disc_has_the_disc_diameter() -> None:
    ys, xs = torch.meshgrid(torch.arange(60.0), torch.arange(60.0), indexing="ij")
    mask = (((xs - 30) ** 2 + (ys - 25) ** 2) <= 15**2).float()
    streak = streak_from_mask(mask)
    assert streak.diameter == pytest.approx(30, rel=0.05)
    assert (streak.end - streak.start).norm() <= 2.0


def test_a_zero_rotation_cap_fits_no_rotation() -> None:
    params = MotionParams(CAMERA, (0.05, 1.0), 1.5, 0.0, 0.4)
    assert not params.omega_raw.requires_grad
    x0 = CAMERA.unproject(torch.tensor([80.0, 60.0]), torch.tensor(5.0))
    params.load_motion(Motion(x0, torch.ones(3), torch.eye(3), torch.ones(3)))
    assert torch.equal(params.motion().omega, torch.zeros(3))
    rotations, _ = params(torch.tensor([0.0, 1.0]))
    assert torch.equal(rotations[0], rotations[1])


@pytest.mark.parametrize("spin", [0.0, 1e-5, 0.7])
def test_the_cpu_node_matches_the_tensor_chain_in_value_and_gradient(spin: float) -> None:
    # The CPU's one-node forward (complex-step Jacobian) against autograd through the formulas,
    # at a spin of 0 and in the Taylor branch, where a Jacobian is easiest to get wrong.
    params = MotionParams(CAMERA, (0.05, 1.0), 1.5, 120.0, 0.4).double()
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        params.ends.copy_(torch.randn(2, 3, generator=generator, dtype=torch.float64))
        params.quat0.copy_(torch.randn(4, generator=generator, dtype=torch.float64))
        params.omega_raw.copy_(torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64) * spin)
    taus = (torch.arange(8, dtype=torch.float64) + 0.5) / 8
    weights = (
        torch.randn(8, 3, 3, generator=generator, dtype=torch.float64),
        torch.randn(8, 3, generator=generator, dtype=torch.float64),
    )
    results = []
    for forward in (params.forward, params.tensor_forward):
        params.zero_grad()
        rotations, positions = forward(taus)
        ((rotations * weights[0]).sum() + (positions * weights[1]).sum()).backward()
        results.append([rotations.detach(), positions.detach(), *(p.grad.clone() for p in params.parameters())])
    for node, reference in zip(*results, strict=True):
        assert torch.allclose(node, reference, rtol=1e-10, atol=1e-12)


def _on_circle(frame: int, turn: float, exposure: float) -> Motion:
    """The exposure of frame ``frame`` on a unit circle at depth 5 turning ``turn`` rad a frame:
    the chord from its start to its end."""
    start, end = turn * frame, turn * (frame + exposure)

    def point(a: float) -> torch.Tensor:
        return torch.tensor([math.cos(a), math.sin(a), 5.0])

    return Motion(point(start), point(end) - point(start), torch.eye(3), torch.zeros(3))


@pytest.mark.parametrize("turn", [0.3, -0.8])
def test_a_circular_swing_is_continued_round_its_circle(turn: float) -> None:
    e = 0.5
    earlier, motion, truth = (_on_circle(k, turn, e) for k in range(3))
    turning = continue_turning(earlier, motion, 1, e)
    straight = continue_motion(motion, 1, e)
    start_error = float((turning.x0 - truth.x0).norm())
    assert start_error < 0.3 * float((straight.x0 - truth.x0).norm())
    assert float((turning.dx - truth.dx).norm()) < 0.05 * float(truth.dx.norm())


def test_a_straight_track_continues_straight() -> None:
    earlier = Motion(torch.tensor([0.0, 0.0, 5.0]), torch.tensor([0.5, 0.1, 0.0]), torch.eye(3), torch.zeros(3))
    motion = Motion(earlier.x0 + 2 * earlier.dx, earlier.dx, torch.eye(3), torch.zeros(3))
    turning, straight = continue_turning(earlier, motion, 1, 0.5), continue_motion(motion, 1, 0.5)
    assert torch.allclose(turning.x0, straight.x0) and torch.allclose(turning.dx, straight.dx)
