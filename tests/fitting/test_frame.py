"""The fitter on generated frames with ground truth (fast preset, 160x120 frames).

Thresholds come from measurement (see benchmarks/fit.py for the full-size table): on these
four frames the full loss reached mean TIoU 0.84, PSNR 31.1 dB and translation error 0.43
object sizes; with L_I switched off PSNR fell to 25.7 dB and the error rose to 1.55, which the
thresholds below must and do catch.
"""

from __future__ import annotations

import statistics

import pytest
import torch

from sfb_video.config import load_config
from sfb_video.crop import make_crop
from sfb_video.errors import NoObjectError, SfbError
from sfb_video.evaluation.synthetic import FrameScore, crop_masks, fit_synthetic_frame, score_fit, synthetic_crop
from sfb_video.fitting.frame import WarmStart, fit_frame, planned_steps
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.rotation import axis_angle_to_matrix
from sfb_video.model.motion import Motion, streak_from_mask
from sfb_video.synth import ClipSpec, generate_clip

FRAMES = (("ball", 0), ("box", 0), ("ball", 2), ("box", 2))
MIN_TIOU, MIN_PSNR, MAX_TRANSLATION = 0.8, 29.5, 0.55


def _clip(shape: str, seed: int):
    return generate_clip(
        ClipSpec(shape=shape, seed=seed, width=160, height=120, size_px_range=(24, 48), num_subframes=4)
    )


def _means(overrides: list[str], use_true_masks: bool = False) -> dict[str, float]:
    config = load_config("fast", overrides)
    scores: list[FrameScore] = [fit_synthetic_frame(_clip(*f), 0, config, use_true_masks)[1] for f in FRAMES]
    return {k: statistics.mean(getattr(s, k) for s in scores) for k in ("tiou", "psnr", "translation_err")}


@pytest.fixture(scope="module")
def full() -> dict[str, float]:
    return _means([])


def test_fit_recovers_subframes_and_trajectory(full: dict[str, float]) -> None:
    assert full["tiou"] >= MIN_TIOU
    assert full["psnr"] >= MIN_PSNR
    assert full["translation_err"] <= MAX_TRANSLATION


def test_thresholds_catch_a_fit_without_the_image_loss() -> None:
    broken = _means(["fit.w_image=0"])
    assert broken["psnr"] < MIN_PSNR or broken["translation_err"] > MAX_TRANSLATION


def test_true_subframe_masks_fit_better_than_the_difference_mask(full: dict[str, float]) -> None:
    # Stands in for DeFMO's masks (paper, Table 2: L_S beats L_D); measured PSNR 32.6 vs 31.1 dB
    # and TIoU 0.842 vs 0.841 (since L_D fades out, the difference mask no longer costs TIoU here).
    with_masks = _means([], use_true_masks=True)
    assert with_masks["psnr"] >= full["psnr"] + 1.0
    assert with_masks["tiou"] >= full["tiou"] - 0.01


@pytest.mark.parametrize("reverse", [False, True])
def test_warm_start_takes_its_direction_from_the_prediction_and_its_place_from_the_streak(reverse: bool) -> None:
    config = load_config("fast")
    # The ball, which the sphere prototype can match, warm-started from the cold fit's shape,
    # texture and rotation (which belong together, as a previous frame's do) and the true path
    # (or the true path reversed): the fit runs in the predicted direction.
    clip = _clip("ball", 0)
    crop = synthetic_crop(clip, 0, config)
    truth = clip.truth[0].motion
    cold, _ = fit_synthetic_frame(clip, 0, config)
    path = (torch.from_numpy(a).float() for a in (truth.x0, truth.dx))
    motion = Motion(*path, cold.state.motion.rot0, cold.state.motion.omega)
    start = motion.reversed() if reverse else motion
    warm = fit_frame(
        crop, config.fit, config.render, warm=WarmStart("sphere", cold.state.vertices, cold.state.texture, start)
    )
    score = score_fit(warm, clip, 0, config)
    assert warm.iterations <= config.fit.warm_iterations
    assert score.flipped == reverse
    assert score.translation_err <= 0.7  # measured 0.51 and 0.62
    # Measured 0.61-0.81 over rounding-level changes to the step (the fast preset's short fit
    # is that sensitive); cold: 0.94.
    assert score.tiou >= 0.55


def test_with_the_objects_appearance_known_the_fit_recovers_its_rotation() -> None:
    # One frame cannot tell the rotation from a texture that is free to change (the README's fit
    # section has the evidence); given the true mesh and texture, only the motion is fitted, from
    # no rotation and a start orientation 27 degrees off. T = 32 because eight time steps bias
    # it (measured 9.5 degrees here, 4.5 with 300 steps, 13 with T = 16); a fit of no rotation
    # errs by the whole 86 degrees, and so would one without L_I (a sphere's silhouette has none).
    config = load_config("default", ["fit.deform=false", "fit.learn_texture=false", "render.time_steps=32"])
    clip = generate_clip(ClipSpec(shape="ball", seed=0))
    truth, mesh = clip.truth[0].motion, clip.scene.mesh
    as_tensor = lambda a: torch.from_numpy(a).float()  # noqa: E731
    rot0 = axis_angle_to_matrix(torch.tensor([0.3, -0.3, 0.2])) @ as_tensor(truth.rotation)
    start = Motion(as_tensor(truth.x0), as_tensor(truth.dx), rot0, torch.zeros(3))
    texture = torch.from_numpy(mesh.texture).permute(2, 0, 1).float() / 255
    warm = WarmStart("sphere", mesh.vertices, texture, start)
    fit = fit_frame(synthetic_crop(clip, 0, config), config.fit, config.render, warm=warm)
    score = score_fit(fit, clip, 0, config)
    assert torch.allclose(fit.state.vertices, mesh.vertices, atol=1e-6)
    assert torch.allclose(fit.state.texture, texture, atol=1e-3)
    assert score.rotation_err_deg <= 15.0
    assert score.translation_err <= 0.4  # measured 0.22


def test_fit_is_deterministic() -> None:
    config = load_config("fast", ["fit.iterations=20"])
    crop = synthetic_crop(_clip("ball", 0), 0, config)
    a = fit_frame(crop, config.fit, config.render)
    b = fit_frame(crop, config.fit, config.render)
    assert torch.equal(a.state.vertices, b.state.vertices)
    assert torch.equal(a.state.motion.x0, b.state.motion.x0)
    assert a.curves == b.curves


def test_rotations_take_their_own_step_size() -> None:
    crop = synthetic_crop(_clip("box", 0), 0, load_config("fast"))
    frozen = load_config("fast", ["fit.iterations=20", "fit.lr_rotation=0"])
    fit = fit_frame(crop, frozen.fit, frozen.render)
    assert torch.equal(fit.state.motion.rot0, torch.eye(3)) and torch.equal(fit.state.motion.omega, torch.zeros(3))
    assert fit.iterations == 20 and fit.losses["image"] < fit.curves["sphere"][0]["image"]
    moving = load_config("fast", ["fit.iterations=20"])
    assert float(fit_frame(crop, moving.fit, moving.render).state.motion.omega.norm()) > 0


def test_the_difference_loss_fades_out_over_the_stated_fraction_of_the_iterations() -> None:
    config = load_config("fast", ["fit.iterations=8", "fit.difference_fade=0.5"])
    fit = fit_frame(synthetic_crop(_clip("box", 0), 0, config), config.fit, config.render)
    weights = config.fit
    for step, record in enumerate(fit.curves["sphere"]):
        rest = (
            weights.w_image * record["image"]
            + weights.w_texture * record["texture"]
            + weights.w_laplacian * record["laplacian"]
        )
        fade = max(0.0, 1 - step / 4)
        assert record["total"] == pytest.approx(rest + weights.w_difference * fade * record["difference"], rel=1e-5)
        assert (record["total"] > rest * (1 + 1e-3)) == (step < 4)


def test_the_fit_runs_deterministic_kernels_and_restores_the_setting_after() -> None:
    # A busy machine made the parallel index_put_ add in another order (fourth decimal of a fit);
    # that needs load to show, so this checks the switch that prevents it.
    config = load_config("fast", ["fit.iterations=3"])
    seen: list[bool] = []
    fit_frame(
        synthetic_crop(_clip("ball", 0), 0, config),
        config.fit,
        config.render,
        on_step=lambda step, record: seen.append(torch.are_deterministic_algorithms_enabled()),
    )
    assert seen == [True] * 3
    assert not torch.are_deterministic_algorithms_enabled()


def test_loss_curve_is_reported_and_the_kept_fit_is_the_best_seen() -> None:
    config = load_config("fast", ["fit.iterations=30", "fit.prototypes=[sphere, torus]", "fit.prototype_trial=1"])
    fit = fit_frame(synthetic_crop(_clip("ball", 0), 0, config), config.fit, config.render)
    assert set(fit.curves) == {"sphere", "torus"}
    assert all(len(c) == 30 for c in fit.curves.values())
    best = min(r["image"] for c in fit.curves.values() for r in c)
    assert fit.losses["image"] == pytest.approx(best)
    assert fit.prototype == min(fit.curves, key=lambda k: min(r["image"] for r in fit.curves[k]))


def test_a_prototype_trial_goes_on_with_the_leader_only() -> None:
    overrides = ["fit.iterations=30", "fit.prototypes=[sphere, torus, sphere_large]", "fit.prototype_trial=0.2"]
    config = load_config("fast", overrides)
    crop = synthetic_crop(_clip("ball", 0), 0, config)
    fit = fit_frame(crop, config.fit, config.render)
    leader = min(fit.curves, key=lambda k: min(r["image"] for r in fit.curves[k][:6]))
    assert fit.prototype == leader and len(fit.curves[leader]) == 30
    assert sorted(len(c) for c in fit.curves.values()) == [6, 6, 30]
    assert planned_steps(config.fit, 3) == 42
    # The leader's run goes on from its trial: the same as running it alone from the start.
    alone = load_config("fast", ["fit.iterations=30", f"fit.prototypes=[{leader}]"])
    assert fit.losses == fit_frame(crop, alone.fit, alone.render).losses


def _images() -> tuple[torch.Tensor, torch.Tensor, PinholeCamera]:
    background = torch.rand(3, 60, 80, generator=torch.Generator().manual_seed(0))
    return background.clone(), background, PinholeCamera.from_fov(80, 60, 45.0)


def test_image_identical_to_background_is_no_object() -> None:
    image, background, camera = _images()
    config = load_config("fast")
    crop = make_crop(image, background, (30, 20, 10, 10), camera, config.crop)
    with pytest.raises(NoObjectError, match="no object"):
        fit_frame(crop, config.fit, config.render)


def test_mismatched_sizes_and_empty_boxes_are_clear_errors() -> None:
    image, background, camera = _images()
    config = load_config("fast")
    with pytest.raises(SfbError, match="differ in size"):
        make_crop(image[:, :50], background, (30, 20, 10, 10), camera, config.crop)
    with pytest.raises(SfbError, match="empty or outside"):
        make_crop(image, background, (30, 20, 0, 10), camera, config.crop)
    with pytest.raises(SfbError, match="empty or outside"):
        make_crop(image, background, (100, 20, 10, 10), camera, config.crop)


def test_non_finite_input_is_rejected_before_fitting() -> None:
    image, background, camera = _images()
    image[:, 25, 35] = float("nan")
    config = load_config("fast")
    crop = make_crop(image, background, (30, 20, 10, 10), camera, config.crop)
    with pytest.raises(SfbError, match="NaN"):
        fit_frame(crop, config.fit, config.render)


@pytest.mark.parametrize("reverse", [False, True])
def test_subframe_masks_set_the_time_direction_of_a_cold_fit(reverse: bool) -> None:
    config = load_config("fast", ["fit.iterations=60"])
    clip = _clip("ball", 0)
    crop = synthetic_crop(clip, 0, config)
    masks = crop_masks(clip, 0, crop)
    fit = fit_frame(crop, config.fit, config.render, masks=masks.flip(0) if reverse else masks)
    assert score_fit(fit, clip, 0, config).flipped == reverse


def test_weights_that_leave_nothing_to_optimise_stop_the_fit_without_an_error() -> None:
    # L_D alone, faded out after the first step: the total no longer depends on a parameter.
    overrides = ["fit.iterations=6", "fit.difference_fade=0.1", "fit.w_image=0", "fit.w_texture=0"]
    config = load_config("fast", [*overrides, "fit.w_laplacian=0", "fit.w_silhouette=0"])
    fit = fit_frame(synthetic_crop(_clip("ball", 0), 0, config), config.fit, config.render)
    assert fit.iterations == 2
    assert fit.losses["total"] == pytest.approx(config.fit.w_difference * fit.losses["difference"])


def test_a_mask_of_one_pixel_is_no_object_not_a_bare_value_error() -> None:
    image, background, camera = _images()
    image[:, 30, 40] = 1 - background[:, 30, 40]
    config = load_config("fast")
    crop = make_crop(image, background, (38, 28, 5, 5), camera, config.crop)
    with pytest.raises(NoObjectError, match="fewer than 2 pixels"):
        fit_frame(crop, config.fit, config.render)
    with pytest.raises(NoObjectError, match="1 pixel"):
        streak_from_mask(torch.zeros(8, 8).index_put_((torch.tensor([3]), torch.tensor([4])), torch.tensor(1.0)))


def test_a_fit_leaves_the_callers_random_state_as_it_was() -> None:
    config = load_config("fast", ["fit.iterations=2"])
    crop = synthetic_crop(_clip("ball", 0), 0, config)
    torch.manual_seed(7)
    expected = torch.rand(4)
    torch.manual_seed(7)
    fit_frame(crop, config.fit, config.render)
    assert torch.equal(torch.rand(4), expected)
