"""Continuing a motion across the gap between exposures, and joining frames end to start."""

from __future__ import annotations

import dataclasses
import math

import torch

from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.geometry.rotation import axis_angle_to_matrix, rotation_angle_deg
from sfb_video.model.motion import Motion, continue_motion
from sfb_video.model.scene import ObjectState
from sfb_video.results import FrameResult, load_result, save_result
from sfb_video.stages.tracking.prediction import join, join_gap, predict, ray_gap

CAMERA = PinholeCamera.from_fov(320, 240, 45.0)


def _motion(x0: tuple[float, float, float], dx: tuple[float, float, float], spin: float = 0.0) -> Motion:
    return Motion(torch.tensor(x0), torch.tensor(dx), torch.eye(3), torch.tensor([0.0, 0.0, spin]))


def _result(index: int, motion: Motion) -> FrameResult:
    vertices, topology = load_prototype("sphere")
    state = ObjectState(vertices, topology, torch.rand(3, 8, 8, generator=torch.Generator().manual_seed(index)), motion)
    box = (10, 20, 30, 40)
    return FrameResult(index, box, box, CAMERA, state, "cold", "sphere", {"image": 0.1}, [{"image": 0.1}], 1.0)


def test_continue_motion_crosses_the_gap_at_constant_velocity_and_spin() -> None:
    m = _motion((0.0, 0.0, 5.0), (1.0, 0.5, 0.0), spin=0.4)
    nxt = continue_motion(m, 1, 0.8)  # the next exposure starts 1 / 0.8 exposures later
    assert torch.allclose(nxt.x0, torch.tensor([1.25, 0.625, 5.0]))
    assert torch.allclose(nxt.dx, m.dx)
    expected = axis_angle_to_matrix(torch.tensor([0.0, 0.0, 0.5]))
    assert float(rotation_angle_deg(nxt.rot0, expected)) < 1e-3
    two = continue_motion(m, 2, 1.0)
    assert torch.allclose(two.x0, torch.tensor([2.0, 1.0, 5.0]))


def test_prediction_is_the_projected_middle_of_the_next_streak() -> None:
    m = _motion((0.0, 0.0, 5.0), (1.0, 0.0, 0.0))
    p = predict(m, CAMERA)
    assert math.isclose(p.centre[0], CAMERA.cx + CAMERA.fx * 0.5 / 5, rel_tol=1e-5)
    assert math.isclose(p.diameter, CAMERA.fy / 5, rel_tol=1e-5)


def test_join_reverses_the_frame_that_runs_backwards() -> None:
    first = _result(0, _motion((0.0, 0.0, 5.0), (1.0, 0.0, 0.0)))
    # Frame 1 was fitted end-to-start: its start is where the true motion ends.
    second = _result(1, _motion((2.0, 0.0, 5.0), (-1.0, 0.0, 0.0)))
    a, b = join(first, second, CAMERA, 1.0, may_flip_previous=False)
    assert a is first
    assert torch.allclose(b.state.motion.x0, torch.tensor([1.0, 0.0, 5.0]))
    assert torch.allclose(b.state.motion.dx, torch.tensor([1.0, 0.0, 0.0]))


def test_join_may_reverse_the_first_frame_of_a_track() -> None:
    first = _result(0, _motion((1.0, 0.0, 5.0), (-1.0, 0.0, 0.0)))  # reversed
    second = _result(1, _motion((1.0, 0.0, 5.0), (1.0, 0.0, 0.0)))
    a, b = join(first, second, CAMERA, 1.0, may_flip_previous=True)
    assert torch.allclose(a.state.motion.x0, torch.tensor([0.0, 0.0, 5.0]))
    assert b is second
    kept, _ = join(first, second, CAMERA, 1.0, may_flip_previous=False)
    assert kept is first


def test_the_ray_gap_joins_streaks_a_short_shutter_leaves_far_apart() -> None:
    first = _result(0, _motion((0.0, 0.0, 5.0), (0.3, 0.0, 0.0)))
    # A shutter open 30% of the interval: the next streak starts 1 / 0.3 streak lengths later.
    ahead = _result(1, _motion((1.0, 0.0, 5.0), (0.3, 0.0, 0.0)))
    assert join_gap(first, ahead, CAMERA, 1.0) > 30  # told e = 1, the gap looks like a miss
    assert join_gap(first, ahead, CAMERA, 0.3) < 1e-3
    assert ray_gap(first, ahead, CAMERA) < 1e-3
    aside = _result(1, _motion((1.0, 0.5, 5.0), (0.3, 0.0, 0.0)))
    assert math.isclose(ray_gap(first, aside, CAMERA), CAMERA.fy * 0.5 / 5, rel_tol=1e-4)
    behind = _result(1, _motion((-0.5, 0.0, 5.0), (0.3, 0.0, 0.0)))
    assert math.isclose(ray_gap(first, behind, CAMERA), CAMERA.fx * 0.8 / 5, rel_tol=1e-4)
    # Beyond what a shutter open 20% of the interval leaves (4 streak lengths past the end).
    far = _result(1, _motion((2.0, 0.0, 5.0), (0.3, 0.0, 0.0)))
    assert math.isclose(ray_gap(first, far, CAMERA), CAMERA.fx * 0.5 / 5, rel_tol=1e-4)


def test_results_round_trip_through_the_run_folder(tmp_path) -> None:
    result = _result(7, _motion((0.1, 0.2, 5.0), (1.0, 0.5, 0.2), spin=0.3))
    save_result(tmp_path, result)
    back = load_result(tmp_path / "frames" / "frame_00007_track_00.pt")
    assert back.index == 7 and back.crop_camera == CAMERA and back.losses == result.losses
    assert torch.equal(back.state.texture, result.state.texture)
    assert torch.equal(back.state.topology.edges, result.state.topology.edges)
    for name in ("x0", "dx", "rot0", "omega"):
        assert torch.equal(getattr(back.state.motion, name), getattr(result.state.motion, name))
    assert isinstance(back.state.topology, MeshTopology)


def test_subframe_masks_are_saved_and_turn_with_the_result(tmp_path) -> None:
    masks = torch.rand(4, 6, 8, generator=torch.Generator().manual_seed(1))
    plain = _result(3, _motion((0.1, 0.2, 5.0), (1.0, 0.5, 0.2)))
    result = dataclasses.replace(plain, mask_source="defmo", masks=masks)
    save_result(tmp_path, result)
    back = load_result(tmp_path / "frames" / "frame_00003_track_00.pt")
    assert back.mask_source == "defmo" and not back.masks_reversed
    assert (back.masks - masks).abs().max() <= 0.5 / 255 + 1e-6  # kept as 8 bits
    turned = result.reversed()
    assert torch.equal(turned.masks, masks.flip(0)) and turned.masks_reversed
    assert not turned.reversed().masks_reversed
    save_result(tmp_path, plain)
    again = load_result(tmp_path / "frames" / "frame_00003_track_00.pt")
    assert again.mask_source == "diff" and again.masks is None
    assert plain.reversed().masks is None
