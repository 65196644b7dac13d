"""The joint fit's trajectory: piecewise polynomials through anchors, a constant spin, the
exposure as a learnt fraction, and each frame's exposure as a chord."""

from __future__ import annotations

import math

import pytest
import torch

from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.rotation import axis_angle_to_matrix
from sfb_video.model.trajectory import Trajectory, TrajectoryParams, anchor_times, interpolate

CAMERA = PinholeCamera.from_fov(320, 240, 45.0)


def _quadratic(t: torch.Tensor) -> torch.Tensor:
    return torch.stack((0.5 * t - 2, 0.1 * t**2 - 0.3 * t, 8 + 0.05 * t), -1)


def test_a_quadratic_is_reproduced_exactly_by_its_three_anchors() -> None:
    breaks = torch.tensor([0.0, 5.0])
    anchors = _quadratic(anchor_times(breaks, 2))
    t = torch.linspace(-0.5, 5.5, 25)  # also beyond the window: the ends extend
    assert torch.allclose(interpolate(anchors, breaks, 2, t), _quadratic(t), atol=1e-5)


def test_a_bounce_is_continuous_at_its_break_and_its_velocity_jumps() -> None:
    breaks = torch.tensor([0.0, 2.5, 5.0])
    times = anchor_times(breaks, 2)
    assert times.tolist() == [0.0, 1.25, 2.5, 3.75, 5.0]
    # Falling then rising, like a ball off the floor (y down).
    anchors = torch.tensor([[0.0, 0.0, 8], [1, 1, 8], [2, 2.5, 8], [3, 1, 8], [4, 0, 8]])
    eps = 1e-3
    before, at, after = interpolate(anchors, breaks, 2, torch.tensor([2.5 - eps, 2.5, 2.5 + eps]))
    assert torch.allclose(before, at, atol=1e-2) and torch.allclose(after, at, atol=1e-2)
    v_before, v_after = (at - before) / eps, (after - at) / eps
    assert v_before[1] > 0.5 and v_after[1] < -0.5


def test_a_frame_s_motion_is_the_chord_of_its_exposure() -> None:
    breaks = torch.tensor([0.0, 4.0])
    spin = torch.tensor([0.0, 0.3, 0.1])
    path = Trajectory(10, breaks, _quadratic(anchor_times(breaks, 2)), 2, torch.eye(3), spin, 0.6, "bounce")
    motion = path.frame_motion(12)
    assert path.time(12, 1.0) == pytest.approx(2.6)
    assert torch.allclose(motion.x0, _quadratic(torch.tensor([2.0]))[0], atol=1e-5)
    assert torch.allclose(motion.x0 + motion.dx, _quadratic(torch.tensor([2.6]))[0], atol=1e-5)
    assert torch.allclose(motion.rot0, axis_angle_to_matrix(2.0 * spin), atol=1e-5)
    assert torch.allclose(motion.omega, 0.6 * spin)


def test_anchors_and_rotation_load_back_as_given() -> None:
    breaks = torch.tensor([0.0, 4.0])
    params = TrajectoryParams(CAMERA, breaks, 2, 30.0, 0.7, True, 90.0)
    anchors = _quadratic(params.times)
    params.load_anchors(anchors)
    rot0, spin = axis_angle_to_matrix(torch.tensor([0.2, -0.4, 0.1])), torch.tensor([0.0, 0.5, 0.2])
    params.load_rotation(rot0, spin)
    path = params.trajectory(0, "constant_acceleration")
    assert torch.allclose(path.anchors, anchors, atol=1e-4)
    assert torch.allclose(path.rot0, rot0, atol=1e-5)
    assert torch.allclose(path.spin, spin, atol=1e-5)
    assert path.exposure_fraction == pytest.approx(0.7)


def test_the_exposure_fraction_gets_a_gradient_only_when_learnt() -> None:
    for learn in (True, False):
        params = TrajectoryParams(CAMERA, torch.tensor([0.0, 3.0]), 2, 30.0, 0.5, learn, 90.0)
        params.load_anchors(_quadratic(params.times))
        _, positions = params(torch.tensor([0.0, 1.0]), torch.linspace(0, 1, 4))
        positions.sum().backward()
        grad = params.exposure_raw.grad
        assert (grad is not None and math.isfinite(float(grad)) and float(grad) != 0) == learn
