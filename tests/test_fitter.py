"""The fitter on generated frames with ground truth (fast preset, 160x120 frames).

Thresholds come from measurement (see benchmarks/fit.py for the full-size table): on these
four frames the full loss reached mean TIoU 0.82, PSNR 30.0 dB and translation error 0.48
object sizes; with L_I switched off PSNR fell to 25.4 dB and the error rose to 1.55, which the
thresholds below must and do catch.
"""

from __future__ import annotations

import statistics

import pytest
import torch

from sfb_video.checks import SfbError
from sfb_video.config import load_config
from sfb_video.crop import make_crop
from sfb_video.evaluation.synthetic import FrameScore, crop_masks, fit_synthetic_frame, score_fit, synthetic_crop
from sfb_video.fitter import NoObjectError, WarmStart, fit_frame
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.motion import Motion
from sfb_video.synth import ClipSpec, generate_clip

FRAMES = (("ball", 0), ("box", 0), ("ball", 2), ("box", 2))
MIN_TIOU, MIN_PSNR, MAX_TRANSLATION = 0.78, 28.5, 0.6


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
    # Stands in for DeFMO's masks (paper, Table 2: L_S beats L_D); measured TIoU 0.84 vs 0.82
    # and PSNR 32.6 vs 30.0 dB.
    with_masks = _means([], use_true_masks=True)
    assert with_masks["tiou"] >= full["tiou"]
    assert with_masks["psnr"] >= full["psnr"] + 1.5


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
    assert score.translation_err <= 0.5  # measured 0.40 either way
    assert score.tiou >= 0.72  # measured 0.89 and 0.81 (cold: 0.89)


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
    config = load_config("fast", ["fit.iterations=30", "fit.prototypes=[sphere, torus]"])
    fit = fit_frame(synthetic_crop(_clip("ball", 0), 0, config), config.fit, config.render)
    assert set(fit.curves) == {"sphere", "torus"}
    assert all(len(c) == 30 for c in fit.curves.values())
    best = min(r["image"] for c in fit.curves.values() for r in c)
    assert fit.losses["image"] == pytest.approx(best)
    assert fit.prototype == min(fit.curves, key=lambda k: min(r["image"] for r in fit.curves[k]))


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
