import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation
from skimage.metrics import structural_similarity

from sfb_video import metrics


def test_identical_subframes_score_perfectly() -> None:
    frames = np.random.default_rng(0).random((4, 16, 16, 3))
    assert metrics.psnr(frames, frames) == 100.0
    assert metrics.ssim(frames, frames) == pytest.approx(1.0)


def test_psnr_of_a_constant_offset() -> None:
    truth = np.zeros((2, 8, 8, 3))
    assert metrics.psnr(truth + 0.1, truth) == pytest.approx(20.0, abs=1e-5)


def test_psnr_is_one_mse_over_all_subframes_not_a_mean_of_psnrs() -> None:
    truth = np.zeros((2, 8, 8, 3))
    estimate = truth.copy()
    estimate[0] += 0.1  # sub-frame PSNRs 20 and 100; one MSE of 0.005 gives 23.01
    assert metrics.psnr(estimate, truth) == pytest.approx(10 * math.log10(1 / 0.005), abs=1e-4)


def test_ssim_uses_the_estimates_data_range_like_the_benchmark() -> None:
    rng = np.random.default_rng(2)
    truth = rng.random((3, 24, 24, 3))
    estimate = 0.3 * truth + 0.3 + 0.02 * rng.standard_normal(truth.shape)
    span = estimate.max() - estimate.min()
    expected = np.mean(
        [structural_similarity(t, e, channel_axis=-1, data_range=span) for t, e in zip(truth, estimate, strict=True)]
    )
    assert metrics.ssim(estimate, truth) == pytest.approx(expected)
    # With a data range of 1 the score differs: the convention is what is being tested.
    unit = np.mean(
        [structural_similarity(t, e, channel_axis=-1, data_range=1.0) for t, e in zip(truth, estimate, strict=True)]
    )
    assert abs(metrics.ssim(estimate, truth) - unit) > 1e-3


def test_disc_iou_by_hand() -> None:
    assert metrics.disc_iou(0.0, 5.0) == pytest.approx(1.0)
    assert metrics.disc_iou(10.0, 5.0) == pytest.approx(0.0)


def test_trajectory_one_radius_off_gives_the_lens_iou() -> None:
    # Two discs of radius r with centres r apart overlap in a lens of (2 pi / 3 - sqrt(3) / 2) r^2.
    lens = 2 * math.pi / 3 - math.sqrt(3) / 2
    truth = np.stack([np.linspace(10, 50, 8), np.full(8, 20.0)], axis=1)
    shifted = truth + np.array([0.0, 5.0])
    assert metrics.tiou(shifted, truth, 5.0) == pytest.approx(lens / (2 * math.pi - lens))


def test_tiou_takes_the_better_time_direction_unless_told_not_to() -> None:
    truth = np.stack([np.linspace(10, 50, 8), np.full(8, 20.0)], axis=1)
    assert metrics.tiou(truth[::-1], truth, 5.0) == pytest.approx(1.0)
    assert metrics.tiou(truth[::-1], truth, 5.0, may_flip=False) < 0.5


def test_reversed_estimate_is_flipped_by_the_first_subframe_rule() -> None:
    truth = np.random.default_rng(1).random((5, 4, 4, 3))
    assert metrics.should_flip(truth[::-1], truth)
    assert not metrics.should_flip(truth, truth)
    # Only the first sub-frame decides: a good start with a bad rest is not flipped.
    estimate = truth.copy()
    estimate[1:] = truth[0]
    assert not metrics.should_flip(estimate, truth)


def test_rotation_error() -> None:
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    assert metrics.rotation_error_deg(rot, np.eye(3)) == pytest.approx(30.0)


def test_mesh_distance_ignores_scale_position_and_a_small_misalignment() -> None:
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.3))
    turn = Rotation.from_euler("xyz", [4, -3, 5], degrees=True).as_matrix()
    moved = 2.5 * box.vertices @ turn.T + np.array([3.0, -1.0, 7.0])
    assert metrics.mesh_distance(moved, box.faces, box.vertices, box.faces) < 1e-3
    # Without the alignment the 5-degree turn shows.
    assert metrics.mesh_distance(moved, box.faces, box.vertices, box.faces, align=False) > 5e-3


def test_mesh_distance_of_a_sphere_and_a_cube_by_hand() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=3)
    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    # In the unit cube the sphere has radius 0.5; a sphere vertex in direction u lies
    # 0.5 (1 - max |u_i|) inside the cube's surface, and the cube's corners sqrt(3) / 2 - 0.5
    # outside the sphere (its faces lie a little inside the true sphere: allow for that).
    u = sphere.vertices / np.linalg.norm(sphere.vertices, axis=1, keepdims=True)
    sphere_to_cube = float(np.mean(0.5 * (1 - np.abs(u).max(axis=1))))
    cube_to_sphere = math.sqrt(3) / 2 - 0.5
    expected = 0.5 * (sphere_to_cube + cube_to_sphere)
    got = metrics.mesh_distance(sphere.vertices, sphere.faces, cube.vertices, cube.faces, align=False)
    assert got == pytest.approx(expected, abs=3e-3)
