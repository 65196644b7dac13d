"""The one optimisation engine: the frame fit and the window fit give, through it, the losses
the two separate loops gave before (curves recorded from them in ``engine_curves.json``, on the
fixed scenes below), and its stop rules, race and random state behave as stated."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from sfb_video.config import load_config
from sfb_video.errors import DivergenceError, PoseError
from sfb_video.evaluation.synthetic import synthetic_crop
from sfb_video.fitting.engine import Optimisation, Step, race, read_terms, seeded
from sfb_video.fitting.frame import WarmStart, fit_frame
from sfb_video.fitting.path import Seed
from sfb_video.fitting.window import fit_window
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.synth import ClipSpec, generate_clip
from tests.fitting.clips import window_frames

RECORDED = json.loads((Path(__file__).with_name("engine_curves.json")).read_text())
# Recorded on CPU with torch 2.13.0 before the two loops became one; the refactored engine gave
# them bit for bit on the machine that recorded them. The window's were recorded again when its
# candidates became the footprint's shape trial and its Laplacian weight an annealed one (issue
# 32), and again when the crop's object region grew into the streak's faint parts and the
# trial's shape was fitted rigid (issue 32, the next session), and when the footprint was unswept
# along the path's arc, and on an AMD EPYC (AVX2) when CI moved to such machines: the window's
# race drifts from one CPU kind to another (up to 1e-2 by its fifth step, see DRIFT), the frame
# fits do not. The tolerance only allows for
# another CPU's float rounding: a changed step order, stop rule or loss changes them in the
# first decimals.
REL = 1e-5
DRIFT = 2e-2
"""The window race's tolerance from its third step on: on an Intel Xeon its curve left the EPYC's
recording by 2e-4 at step 2 and 1e-2 at step 4 (its first two steps within 1e-5, its trials,
shapes, prototype and final loss within REL)."""


def _same_curves(
    got: dict[str, list[dict[str, float]]], want: dict[str, list[dict[str, float]]], drift_from: int | None = None
) -> None:
    """The curves equal within REL (from step ``drift_from`` on, within DRIFT)."""
    assert set(got) == set(want)
    for name in want:
        assert len(got[name]) == len(want[name]), name
        for step, (a, b) in enumerate(zip(got[name], want[name], strict=True)):
            assert a.keys() == b.keys()
            rel = DRIFT if drift_from is not None and step >= drift_from else REL
            assert list(a.values()) == pytest.approx(list(b.values()), rel=rel, abs=1e-9), (name, step)


def test_a_cold_race_and_a_warm_start_give_the_recorded_losses() -> None:
    config = load_config("fast", ["fit.iterations=12", "fit.prototypes=[sphere, torus]", "fit.prototype_trial=0.25"])
    clip = generate_clip(
        ClipSpec(shape="box", seed=0, num_frames=2, width=160, height=120, size_px_range=(24, 48), num_subframes=4)
    )
    cold = fit_frame(synthetic_crop(clip, 0, config), config.fit, config.render)
    _same_curves(cold.curves, RECORDED["cold"])
    warm_config = load_config("fast", ["fit.warm_iterations=15", "fit.plateau_patience=3"])
    s = cold.state
    warm = WarmStart(cold.prototype, s.vertices, s.texture, s.motion)
    fit = fit_frame(synthetic_crop(clip, 1, warm_config), warm_config.fit, warm_config.render, warm=warm)
    _same_curves(fit.curves, RECORDED["warm"])  # 8 of 15 steps: the plateau rule stopped it


def test_a_window_race_with_a_shape_trial_and_a_searched_spin_gives_the_recorded_losses() -> None:
    overrides = ["joint.iterations=10", "joint.spin_magnitudes=[30,90]", "joint.trial_fraction=0.3"]
    config = load_config("fast", overrides)
    spec = ClipSpec(
        num_frames=3,
        exposure_fraction=0.7,
        num_subframes=4,
        sub_exposures=8,
        shape="ball",
        texture_size=32,
        size_px_range=(24.0, 28.0),
        speed_range=(1.2, 1.6),
        rotation_deg_range=(60.0, 65.0),
        seed=1,
    )
    clip = generate_clip(spec)
    frames = window_frames(clip, config.crop)
    vertices, topology = load_prototype("sphere")
    grey = torch.full((3, config.fit.texture_size, config.fit.texture_size), 0.5)
    seeds = []
    for truth, scale in zip(clip.truth, [0.8, 1.2, 0.9], strict=True):
        x0, dx = (torch.tensor(v, dtype=torch.float32) for v in (truth.motion.x0, truth.motion.dx))
        motion = Motion(scale * x0, scale * dx, torch.eye(3), torch.zeros(3))
        seeds.append(Seed(truth.index, ObjectState(vertices, topology, grey, motion), "sphere", 0.1))
    result = fit_window(frames, seeds, clip.camera, config.fit, config.joint, config.render, 0.4, ("capsule", "box"))
    want = RECORDED["window"]
    _same_curves({"kept": result.curve}, {"kept": want["curve"]}, drift_from=2)
    assert result.trials == pytest.approx(want["trials"], rel=REL)
    assert list(result.trials) == list(want["trials"])  # none: the trial's shape starts the window alone
    assert result.shapes == pytest.approx(want["shapes"], rel=REL)
    assert result.prototype == want["prototype"] and result.loss == pytest.approx(want["loss"], rel=REL)


class _Quadratic:
    """(x - target)^2 as L_I, NaN from step ``nan_from`` on."""

    def __init__(self, target: float, nan_from: int | None = None, behind_from: int | None = None) -> None:
        self.x = torch.nn.Parameter(torch.zeros(()))
        self.module = torch.nn.Module()
        self.module.x = self.x
        self.modules = (self.module,)
        self.target, self.nan_from, self.behind_from, self.calls = target, nan_from, behind_from, 0

    def __call__(self, progress: float) -> Step:
        self.calls += 1
        if self.behind_from is not None and self.calls > self.behind_from:
            raise PoseError("the mesh reaches behind the camera")
        loss = (self.x - self.target) ** 2
        if self.nan_from is not None and self.calls > self.nan_from:
            loss = loss * float("nan")
        return Step(loss, {"image": float(loss.detach()), "total": float(loss.detach())})


def _optimisation(objective: _Quadratic, iterations: int = 20) -> Optimisation:
    return Optimisation(objective, torch.optim.SGD([objective.x], lr=0.1), iterations)


def test_a_non_finite_step_stops_the_candidate_for_good_and_keeps_its_best() -> None:
    objective = _Quadratic(1.0, nan_from=3)
    fit = _optimisation(objective)
    fit.run(10)
    fit.run(10)  # a stopped candidate does not evaluate its loss again
    assert fit.done and len(fit.curve) == 3 and objective.calls == 4
    best = fit.restore()
    assert best.record["image"] == min(r["image"] for r in fit.curve)
    assert float(objective.x.detach()) == pytest.approx(float(best.states[0]["x"]))


def test_a_step_behind_the_camera_stops_the_candidate_and_keeps_its_best() -> None:
    objective = _Quadratic(1.0, behind_from=3)
    fit = _optimisation(objective)
    fit.run(10)
    assert fit.done and len(fit.curve) == 3
    assert fit.restore().record["image"] == min(r["image"] for r in fit.curve)
    with pytest.raises(DivergenceError):  # behind from the first step: nothing to keep
        race({"a": _optimisation(_Quadratic(1.0, behind_from=0))}, None)


def test_the_race_lets_the_leader_go_on_and_fails_only_when_every_candidate_diverged() -> None:
    near, far = _Quadratic(0.5), _Quadratic(3.0)
    fits = {"near": _optimisation(near), "far": _optimisation(far)}
    winner, trials = race(fits, 4)
    assert winner == "near" and set(trials) == {"near", "far"}
    assert len(fits["near"].curve) == 20 and len(fits["far"].curve) == 4
    with pytest.raises(DivergenceError):
        race({"a": _optimisation(_Quadratic(1.0, nan_from=0))}, None)


def test_a_seeded_fit_leaves_the_callers_random_state_as_it_was() -> None:
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    with seeded(0):
        inside = torch.rand(3)
    assert torch.equal(torch.rand(3), expected)
    with seeded(0):
        assert torch.equal(torch.rand(3), inside)


def test_the_loss_terms_are_read_at_once_as_each_alone_would_be() -> None:
    terms = {"image": torch.tensor(0.1234567), "total": torch.tensor(3.0, dtype=torch.float64), "x": torch.ones(1)}
    read = read_terms(terms)
    assert list(read) == ["image", "total", "x"]
    assert list(read.values()) == [float(v) for v in terms.values()]  # bit for bit, float32 widened
    assert read_terms({}) == {}
