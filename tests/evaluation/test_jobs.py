"""Splitting an evaluation into Ray jobs: whole sequences where frames depend on each other,
runs of frames where they do not, in the local run's order."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import pytest
import torch

from sfb_video.config import load_config
from sfb_video.evaluation.datasets import list_sequences
from sfb_video.evaluation.jobs import FRAMES_PER_JOB, plan_jobs
from sfb_video.evaluation.runner import run_sequence
from tests.evaluation.fmo_fixture import write_fixture


@dataclass(frozen=True)
class _Sequence:
    name: str
    num_frames: int


def test_per_frame_runs_are_split_and_video_runs_are_whole() -> None:
    a, b = _Sequence("a", 10), _Sequence("b", 3)
    jobs = plan_jobs([(a, "per-frame"), (a, "joint"), (b, "per-frame"), (b, "video")], None)
    assert FRAMES_PER_JOB == 4
    assert [(j.sequence.name, j.mode, j.first, j.count) for j in jobs] == [
        ("a", "per-frame", 0, 4),
        ("a", "per-frame", 4, 4),
        ("a", "per-frame", 8, 2),
        ("a", "joint", 0, None),
        ("b", "per-frame", 0, 3),
        ("b", "video", 0, None),
    ]


def test_max_frames_bounds_every_job() -> None:
    jobs = plan_jobs([(_Sequence("a", 10), "per-frame"), (_Sequence("a", 10), "video")], 6)
    assert [(j.first, j.count) for j in jobs] == [(0, 4), (4, 2), (0, 6)]


def test_a_per_frame_job_from_the_middle_scores_its_frames_as_the_whole_run_does(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd3d")
    sequence = list_sequences(tmp_path, "tbd3d")[0]
    assert sequence.num_frames >= 3
    config = load_config("fast", ["fit.iterations=60"])
    whole = run_sequence(sequence, config, "per-frame", torch.device("cpu"), 3)
    tail = run_sequence(sequence, config, "per-frame", torch.device("cpu"), 3, first=2)
    assert [r.frame for r in tail] == [whole[2].frame]
    assert dataclasses.replace(tail[0], seconds=0.0) == dataclasses.replace(whole[2], seconds=0.0)
    with pytest.raises(ValueError, match="per-frame"):
        run_sequence(sequence, config, "video", torch.device("cpu"), 3, first=2)
