"""Jobs without Ray (one after another here): each job's error is its own, threads come back."""

from __future__ import annotations

import torch

from sfb_video.cluster import Outcome, Resources, run_here
from sfb_video.errors import SfbError


def _job(kind: str) -> tuple[str, int]:
    if kind == "bad input":
        raise SfbError("video not found: a.mp4")
    if kind == "bug":
        raise ValueError("frames\nand a second line")
    return kind, torch.get_num_threads()


def test_each_job_ends_with_its_value_or_its_one_line_error_and_threads_are_restored() -> None:
    before = torch.get_num_threads()
    outcomes: dict[int, Outcome] = {}
    run_here(_job, [("ok",), ("bad input",), ("bug",), ("ok",)], Resources(cpus=1), outcomes.__setitem__)
    assert outcomes[0].value == ("ok", 1) and outcomes[3].value == ("ok", 1)  # the job's share of threads
    assert outcomes[1].error == "video not found: a.mp4"
    assert outcomes[2].error == "ValueError: frames"  # its first line, named by its type
    assert all(o.retries == 0 for o in outcomes.values())
    assert torch.get_num_threads() == before
