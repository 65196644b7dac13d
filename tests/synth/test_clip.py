"""Blurred frames, sub-frames, masks and motion ground truth of generated clips."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from sfb_video.errors import ConfigError, SfbError
from sfb_video.geometry.rotation import axis_angle_to_matrix, exposure_rotations, quaternion_to_matrix
from sfb_video.synth import (
    SHAPE_NAMES,
    ClipSpec,
    SyntheticClip,
    exposure_renders,
    generate_clip,
    make_background,
    make_scene,
    render_exposure,
    render_frame,
)
from sfb_video.synth.clip import FENCE_COLOUR
from sfb_video.synth.trajectory import BOUNCE_RESTITUTION

SMALL = ClipSpec(
    width=160,
    height=120,
    num_frames=3,
    num_subframes=4,
    sub_exposures=16,
    max_step_px=0.0,
    size_px_range=(14.0, 20.0),
    speed_range=(1.2, 1.5),
    noise_sigma=0.0,
    shape="ball",
    texture_size=64,
    seed=1,
)


@pytest.fixture(scope="module")
def clip() -> SyntheticClip:
    return generate_clip(SMALL)


@pytest.fixture(scope="module")
def noisy_clip() -> SyntheticClip:
    return generate_clip(dataclasses.replace(SMALL, noise_sigma=0.01, num_frames=2))


def test_same_seed_is_bit_identical_and_another_seed_differs(noisy_clip: SyntheticClip) -> None:
    again = generate_clip(noisy_clip.spec)
    np.testing.assert_array_equal(again.frames, noisy_clip.frames)
    for a, b in zip(again.truth, noisy_clip.truth, strict=True):
        np.testing.assert_array_equal(a.subframes, b.subframes)
        np.testing.assert_array_equal(a.masks, b.masks)
        np.testing.assert_array_equal(a.motion.x0, b.motion.x0)
    other = generate_clip(dataclasses.replace(noisy_clip.spec, seed=2))
    assert not np.array_equal(other.frames, noisy_clip.frames)
    assert not np.array_equal(other.scene.mesh.texture, noisy_clip.scene.mesh.texture)
    # A frame rendered on its own (as a streaming writer does) is the same frame.
    frame, _ = render_frame(make_scene(noisy_clip.spec), 1)
    np.testing.assert_array_equal(frame, noisy_clip.frames[1])


def test_blurred_frame_is_the_background_where_nothing_passed(clip: SyntheticClip) -> None:
    scene = clip.scene
    for k in range(clip.spec.num_frames):
        _, coverage = render_exposure(scene, k)
        untouched = coverage.max(0) == 0
        assert 0.5 < untouched.mean() < 1.0
        np.testing.assert_array_equal(clip.frames[k][untouched], scene.background[untouched])
        assert np.abs(clip.frames[k].astype(int) - scene.background).max() > 20  # the streak shows


def test_noise_is_mild_and_only_noise_off_the_streak(noisy_clip: SyntheticClip) -> None:
    scene = noisy_clip.scene
    _, coverage = render_exposure(scene, 0)
    untouched = coverage.max(0) == 0
    diff = noisy_clip.frames[0].astype(float) - scene.background
    sigma = noisy_clip.spec.noise_sigma * 255
    # Clipping at 0 and 255 only shrinks the noise, quantisation adds 1/12 level^2 of variance.
    assert 0.7 * sigma < diff[untouched].std() < 1.1 * sigma
    assert abs(diff[untouched].mean()) < 0.1 * sigma


def test_subframes_average_to_the_blurred_frame(clip: SyntheticClip) -> None:
    for frame, truth in zip(clip.frames, clip.truth, strict=True):
        mean = truth.subframes.astype(float).mean(0)
        # Both are rounded to 8 bit from the same float images: at most one level apart.
        assert np.abs(mean - frame).max() <= 1.0


def test_masks_and_tight_box(clip: SyntheticClip) -> None:
    h, w = clip.spec.height, clip.spec.width
    for truth in clip.truth:
        n = clip.spec.num_subframes
        assert truth.masks.shape == (n, h, w) and truth.masks.dtype == np.float32
        assert truth.masks.min() >= 0 and truth.masks.max() <= 1
        assert truth.masks.max() == 1.0  # the ball's core stays covered for a whole sub-frame
        assert truth.masks_binary.any(axis=(1, 2)).all()
        x, y, bw, bh = truth.bbox
        touched = truth.masks.max(0) > 0
        inside = np.zeros_like(touched)
        inside[y : y + bh, x : x + bw] = True
        assert not (touched & ~inside).any()
        # Tight: every edge row and column of the box holds a touched pixel.
        assert touched[y].any() and touched[y + bh - 1].any()
        assert touched[:, x].any() and touched[:, x + bw - 1].any()


def test_object_stays_in_frame_and_streaks_are_longer_than_the_object(clip: SyntheticClip) -> None:
    margin = int(clip.spec.margin_px)
    for truth in clip.truth:
        touched = truth.masks.max(0) > 0
        assert not touched[:margin].any() and not touched[-margin:].any()
        assert not touched[:, :margin].any() and not touched[:, -margin:].any()
        n = clip.spec.num_subframes
        streak = np.linalg.norm(truth.centres[-1] - truth.centres[0]) * n / (n - 1)
        assert streak > 2 * truth.radius_px * 0.9


def test_centres_are_the_projection_of_the_posed_mesh_centre(clip: SyntheticClip) -> None:
    cam, mesh = clip.camera, clip.scene.mesh
    for truth in clip.truth:
        m = truth.motion
        taus = torch.from_numpy(truth.subframe_taus)
        x = torch.from_numpy(m.x0) + taus[:, None] * torch.from_numpy(m.dx)
        uv, depth = cam.project(x)
        np.testing.assert_allclose(truth.centres, uv.numpy(), atol=1e-9)
        assert depth.min() > 0
        # The same through the full pose p = R(tau) v + x(tau) of the mesh vertices.
        rots = exposure_rotations(torch.from_numpy(m.rotation), torch.from_numpy(m.omega), taus)
        posed = torch.einsum("tij,vj->tvi", rots, mesh.vertices.double()) + x[:, None]
        uv_mesh, _ = cam.project(posed.mean(1))
        np.testing.assert_allclose(uv_mesh.numpy(), truth.centres, atol=1e-4)
        # And the ball's silhouette is centred there (perspective shifts it by < 0.5 px).
        rows, cols = np.mgrid[0 : cam.height, 0 : cam.width]
        for j, mask in enumerate(truth.masks):
            centroid = np.array([(mask * cols).sum(), (mask * rows).sum()]) / mask.sum()
            np.testing.assert_allclose(centroid, truth.centres[j], atol=0.5)


def test_radius_matches_the_ball_projection(clip: SyntheticClip) -> None:
    f = clip.camera.fy
    for truth in clip.truth:
        depth = truth.motion.x0[2] + 0.5 * truth.motion.dx[2]
        assert truth.radius_px == pytest.approx(f * 0.5 / depth, rel=0.05)


def test_motion_is_continuous_across_frames(clip: SyntheticClip) -> None:
    traj, e = clip.scene.trajectory, clip.spec.exposure_fraction
    truth = clip.truth
    for k in range(len(truth) - 1):
        a, b = truth[k].motion, truth[k + 1].motion
        # Constant velocity: the gap after an exposure continues the exposure's own motion.
        np.testing.assert_allclose(b.x0, a.x0 + a.dx / e, atol=1e-12)
        np.testing.assert_allclose(b.x0, traj.positions(np.array([k + 1.0]))[0], atol=1e-12)
        np.testing.assert_allclose(b.omega, a.omega, atol=1e-15)
        step = axis_angle_to_matrix(torch.from_numpy(a.omega / e))
        np.testing.assert_allclose(b.rotation, (step @ torch.from_numpy(a.rotation)).numpy(), atol=1e-12)
    for k, t in enumerate(truth):
        m = t.motion
        assert m.quaternion[0] >= 0
        np.testing.assert_allclose(quaternion_to_matrix(torch.from_numpy(m.quaternion)).numpy(), m.rotation, atol=1e-12)
        angle = np.degrees(np.linalg.norm(m.omega))
        assert clip.spec.rotation_deg_range[0] <= angle <= clip.spec.rotation_deg_range[1]
        taus = np.linspace(0, 1, 5)
        expected = exposure_rotations(torch.from_numpy(m.rotation), torch.from_numpy(m.omega), torch.from_numpy(taus))
        np.testing.assert_allclose(traj.rotations(traj.exposure_times(k, taus)), expected.numpy(), atol=1e-12)


def test_absent_frames_show_only_the_background() -> None:
    spec = dataclasses.replace(SMALL, num_frames=2, absent_frames=(0,))
    clip = generate_clip(spec)
    t0, t1 = clip.truth
    assert not t0.present and t1.present
    np.testing.assert_array_equal(clip.frames[0], clip.scene.background)
    assert t0.bbox is None and t0.centres is None and t0.radius_px is None
    assert not t0.masks.any()
    assert t1.bbox is not None and t1.masks.any()
    np.testing.assert_allclose(t1.motion.x0, t0.motion.x0 + t0.motion.dx / spec.exposure_fraction, atol=1e-12)


def test_gravity_bends_the_path_and_dx_is_the_chord() -> None:
    spec = dataclasses.replace(SMALL, num_frames=2, gravity=0.4)
    clip = generate_clip(spec)
    traj, e = clip.scene.trajectory, spec.exposure_fraction
    np.testing.assert_allclose(traj.acceleration, [0.0, 0.4, 0.0])
    for k, truth in enumerate(clip.truth):
        np.testing.assert_allclose(truth.motion.dx, traj.positions(np.array([k + e]))[0] - truth.motion.x0)
    a, b = clip.truth[0].motion, clip.truth[1].motion
    # Downward (+y) acceleration: the start of frame 1 lies below the straight continuation.
    straight = a.x0 + a.dx / e
    assert b.x0[1] - straight[1] == pytest.approx(0.5 * 0.4 * (1 - e), rel=1e-9)


def test_a_bounce_reverses_the_vertical_velocity_and_keeps_the_path_whole() -> None:
    spec = dataclasses.replace(SMALL, num_frames=3, bounce_time=1.4, speed_range=(1.0, 1.2))
    traj = make_scene(spec).trajectory
    eps = 1e-6
    before, at, after = traj.positions(np.array([1.4 - eps, 1.4, 1.4 + eps]))
    v_before, v_after = (at - before) / eps, (after - at) / eps
    assert np.allclose(before, after, atol=1e-4)
    assert v_before[1] > 0 and v_after[1] == pytest.approx(-BOUNCE_RESTITUTION * v_before[1], rel=1e-4)
    assert v_after[0] == pytest.approx(v_before[0], rel=1e-4)


def test_a_swing_goes_round_a_circle_at_the_drawn_speed_and_closes_after_its_period() -> None:
    spec = dataclasses.replace(SMALL, num_frames=4, swing_period=4.0, speed_range=(1.0, 1.2))
    scene = make_scene(spec)
    traj, diameter = scene.trajectory, 2 * float(np.linalg.norm(scene.mesh.vertices.numpy(), axis=-1).max())
    t = np.linspace(0, 4, 41)
    centre, radius = traj.swing[:3], traj.swing[3]
    assert np.allclose(np.linalg.norm(traj.positions(t) - centre, axis=-1), radius)
    assert np.allclose(traj.positions(np.array([0.5])), traj.positions(np.array([4.5])))
    # The speed along the circle is the drawn one: 1.0-1.2 object sizes a frame's exposure.
    per_exposure = radius * abs(traj.swing[4]) * spec.exposure_fraction / diameter
    assert 1.0 - 1e-9 <= per_exposure <= 1.2 + 1e-9
    assert np.allclose(traj.positions(np.array([0.0, 3.0]))[:, 2], centre[2])


def test_a_fence_stands_in_front_of_the_background_and_the_object() -> None:
    spec = dataclasses.replace(SMALL, num_frames=1, fence_period_px=8)
    clip = generate_clip(spec)
    wire = FENCE_COLOUR * 255
    np.testing.assert_allclose(clip.scene.background[0:2, :], np.broadcast_to(wire, (2, spec.width, 3)), atol=1)
    truth = clip.truth[0]
    np.testing.assert_allclose(
        truth.subframes[:, :, 0:2], np.broadcast_to(wire, truth.subframes[:, :, 0:2].shape), atol=1
    )
    assert not truth.masks[:, :, 0:2].any() and truth.masks.any()


def test_a_faint_object_is_pulled_towards_the_background_s_colour() -> None:
    spec = dataclasses.replace(SMALL, num_frames=1)
    strong, faint = make_scene(spec), make_scene(dataclasses.replace(spec, contrast=0.25))
    mean = strong.background.reshape(-1, 3).mean(0)
    textures = [s.mesh.texture.reshape(-1, 3).astype(float) for s in (strong, faint)]
    assert textures[1].std(0) == pytest.approx(0.25 * textures[0].std(0), rel=0.05)
    assert np.abs(textures[1].mean(0) - mean).max() <= 0.25 * np.abs(textures[0].mean(0) - mean).max() + 1


def test_a_split_background_is_dark_on_the_left_and_bright_on_the_right() -> None:
    plain = make_scene(dataclasses.replace(SMALL, num_frames=1)).background.astype(float)
    split = make_scene(dataclasses.replace(SMALL, num_frames=1, split_background=True)).background.astype(float)
    half = SMALL.width // 2
    assert split[:, :half].mean() < 0.4 * plain[:, :half].mean()
    assert 255 - split[:, half:].mean() < 0.4 * (255 - plain[:, half:].mean())


@pytest.mark.parametrize("shape", SHAPE_NAMES)
def test_every_shape_makes_a_visible_streak(shape: str) -> None:
    spec = dataclasses.replace(SMALL, shape=shape, num_frames=1, sub_exposures=8, num_subframes=2)
    clip = generate_clip(spec)
    truth = clip.truth[0]
    assert truth.bbox is not None and truth.radius_px > 2
    assert np.abs(clip.frames[0].astype(int) - clip.scene.background).max() > 10


def test_fast_exposures_get_more_renders() -> None:
    spec = dataclasses.replace(SMALL, num_frames=1, max_step_px=1.0, max_sub_exposures=128)
    scene = make_scene(spec)
    renders = exposure_renders(scene, 0)
    assert spec.sub_exposures < renders <= 128 and renders % spec.num_subframes == 0
    assert exposure_renders(make_scene(dataclasses.replace(spec, max_step_px=0.0)), 0) == spec.sub_exposures


def test_default_spec_runs_at_320x240() -> None:
    spec = ClipSpec(seed=0)
    assert (spec.width, spec.height, spec.sub_exposures, spec.num_subframes) == (320, 240, 32, 8)
    clip = generate_clip(spec)
    assert clip.frames.shape == (1, 240, 320, 3) and clip.frames.dtype == np.uint8
    truth = clip.truth[0]
    assert truth.subframes.shape == (8, 240, 320, 3)
    assert 20 * 0.8 < 2 * truth.radius_px < 72 * 1.2
    assert exposure_renders(clip.scene, 0) >= 32


def test_backgrounds_are_real_photos_of_the_frame_size() -> None:
    bg, name = make_background(np.random.default_rng(0), 96, 64, "camera", (0.5, 1.0))
    assert bg.shape == (64, 96, 3) and bg.dtype == np.uint8 and name == "camera"
    np.testing.assert_array_equal(bg[..., 0], bg[..., 2])  # a grey photo, repeated
    colour, _ = make_background(np.random.default_rng(0), 96, 64, "coffee", (0.5, 1.0))
    assert np.abs(colour[..., 0].astype(int) - colour[..., 2]).mean() > 5
    again, _ = make_background(np.random.default_rng(0), 96, 64, "coffee", (0.5, 1.0))
    np.testing.assert_array_equal(colour, again)
    assert bg.std() > 10


def test_invalid_or_infeasible_specs_are_refused() -> None:
    with pytest.raises(ConfigError, match="multiple"):
        ClipSpec(sub_exposures=12, num_subframes=8)
    with pytest.raises(ConfigError, match="every frame"):
        ClipSpec(num_frames=2, absent_frames=(0, 1))
    with pytest.raises(ConfigError, match="unknown shape"):
        ClipSpec(shape="teapot")
    with pytest.raises(SfbError, match="no trajectory"):
        make_scene(dataclasses.replace(SMALL, num_frames=8, speed_range=(3.0, 3.0), max_tries=20))
