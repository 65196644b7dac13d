"""A slice of the labelled shape benchmark (benchmarks/shapes.py): its small plain ball through
the joint mode with every shape on trial, three perturbed runs, and the tables it prints."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from benchmarks.shapes import SequenceRun, perturbations, print_tables, score_sequence, shown_prototype
from sfb_video.config import load_config
from sfb_video.evaluation.runner import FrameRow
from sfb_video.evaluation.synthetic_set import ensure_set, list_synthetic, shape_specs

# The fast preset with the trial on (it has none) over every shape the default preset tries.
OVERRIDES = ["joint.prototypes=[sphere,capsule,box,disc,torus]", "video.tsr=2"]


@pytest.fixture(scope="module")
def ball_plain(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("shapes")
    ensure_set(root, {"ball_plain": shape_specs()["ball_plain"]}, quiet=True)
    return list_synthetic(root, "shapes")[0]


def test_a_generated_ball_is_never_drawn_as_a_box_or_a_ring_over_three_perturbed_runs(ball_plain) -> None:
    config = load_config("fast", OVERRIDES)
    runs = []
    for scale in perturbations(3):
        perturbed = dataclasses.replace(
            config, fit=dataclasses.replace(config.fit, w_texture=config.fit.w_texture * scale)
        )
        runs.append(score_sequence(ball_plain, perturbed, torch.device("cpu")))
    assert [r.chosen for r in runs] == ["ball"] * 3, [r.prototype for r in runs]
    assert all(r.psnr > r.im for r in runs), [(r.psnr, r.im) for r in runs]


def test_a_sequence_shows_the_prototype_most_of_its_frames_show() -> None:
    def row(prototype: str) -> FrameRow:
        return FrameRow("shapes", "s", 0, "joint", "fitted", 0.5, 20.0, 0.5, 1.0, prototype=prototype)

    assert shown_prototype([row("box"), row("sphere"), row("sphere")]) == "sphere"
    assert shown_prototype([row("box"), row("sphere")]) == "box"  # a tie: the earlier frame's
    assert shown_prototype([row("")]) == ""


def test_the_tables_count_a_choice_that_flips_as_not_held(capsys: pytest.CaptureFixture[str]) -> None:
    def run(name: str, prototype: str) -> SequenceRun:
        return SequenceRun(name, name.rsplit("_", 1)[0], prototype, 25.0, 21.0, 0.8, 0.1, 2.0)

    runs = [[run("ball_a", "sphere"), run("box_a", "box")], [run("ball_a", "sphere"), run("box_a", "sphere")]]
    print_tables(runs)
    lines = {line.split(" | ")[0].strip("| "): line for line in capsys.readouterr().out.splitlines()}
    # ball: right in both runs and held; box: right in one run of two, not held.
    assert lines["ball"].split(" | ")[2:4] == ["1.00", "1.00"]
    assert lines["box"].split(" | ")[2:4] == ["0.50", "0.00"]
