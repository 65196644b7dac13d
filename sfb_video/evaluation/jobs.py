"""An evaluation split into independent jobs for Ray (:mod:`sfb_video.cluster`).

A ``video`` or ``joint`` run of a sequence is one job (its frames depend on each other); a
``per-frame`` run is split into jobs of :data:`FRAMES_PER_JOB` frames, each fitted on its own.
The jobs' rows, put back in the jobs' order, are the rows a local run gives in its own order,
so the tables come out the same (but for the measured seconds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sfb_video.config import Config
from sfb_video.evaluation.runner import FrameRow, run_sequence

FRAMES_PER_JOB = 4
"""Frames of a per-frame run fitted by one job: enough to outweigh a job's start."""


@dataclass(frozen=True)
class EvalJob:
    """One sequence in one mode, or (per-frame) ``count`` of its frames from ``first``."""

    sequence: Any
    mode: str
    first: int = 0
    count: int | None = None


def plan_jobs(runs: list[tuple[Any, str]], max_frames: int | None) -> list[EvalJob]:
    """The jobs of ``runs`` ((sequence, mode) in the local run's order)."""
    jobs: list[EvalJob] = []
    for sequence, mode in runs:
        frames = min(sequence.num_frames, max_frames or sequence.num_frames)
        if mode != "per-frame":
            jobs.append(EvalJob(sequence, mode, 0, max_frames))
            continue
        for k in range(math.ceil(frames / FRAMES_PER_JOB)):
            first = k * FRAMES_PER_JOB
            jobs.append(EvalJob(sequence, mode, first, min(frames, first + FRAMES_PER_JOB) - first))
    return jobs


def run_job(
    job: EvalJob, config: Config, device: str, masks: str, weights: Path | None, with_video: bool
) -> list[FrameRow]:
    """Fit and score one job's frames (on a worker: its own device and mask source)."""
    from sfb_video.devices import resolve_device
    from sfb_video.stages.masks import choose_masks

    where = resolve_device(device)
    source = choose_masks(masks, weights, config.crop, where, log=None)
    stop = None if job.count is None else job.first + job.count
    return run_sequence(
        job.sequence, config, job.mode, where, stop, masks=source, with_video=with_video, first=job.first
    )
