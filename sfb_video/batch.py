"""``sfb-video batch``: many clips, one run folder each, on Ray or one after another here.

A clip is the unit of work: :func:`run_clip` is ``sfb-video process`` on it, into
``OUT/<clip name>``, so a clip that is run again (a retry after its worker died, or the same
batch started again) resumes from its saved frames, and a finished one is not redone. What
happened to every clip goes to ``batch.csv`` and ``batch.json`` in ``OUT``, rewritten as each
clip ends, so an interrupted batch still says which clips are done.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import io
import shutil
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sfb_video.atomic import atomic_write_bytes, write_json
from sfb_video.cluster import Outcome, Resources, run_here, run_on_ray
from sfb_video.config import Config
from sfb_video.devices import resolve_device
from sfb_video.errors import OutputError, SfbError, printable
from sfb_video.stages.process import ClipOptions, finished_summary, process_clip
from sfb_video.stages.types import FrameStatus

VIDEO_SUFFIXES = frozenset({".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv", ".flv"})
"""A folder's files with these suffixes are its clips."""

LIST_SUFFIXES = frozenset({".txt", ".lst", ".list"})
"""An input with one of these suffixes lists clips, one path per line (``#`` starts a comment;
relative paths are relative to the list's folder)."""

CSV_NAME, JSON_NAME = "batch.csv", "batch.json"

DONE, NO_OBJECT, FAILED, PENDING = "done", "no_object", "failed", "pending"


@dataclass(frozen=True)
class ClipJob:
    """One clip of a batch and the run folder it goes to."""

    name: str
    video: Path
    out: Path


@dataclass(frozen=True)
class ClipRow:
    """What happened to one clip: ``done``, ``no_object`` (it ran; no moving object was found),
    ``failed`` (with its one-line ``error``) or ``pending``. ``seconds`` is the last attempt's
    time; ``retries`` how often its worker died and it started again."""

    clip: str
    video: str
    out: str
    status: str
    frames: int = 0
    fitted: int = 0
    seconds: float = 0.0
    retries: int = 0
    error: str = ""
    note: str = ""


def gather_clips(inputs: Sequence[str]) -> tuple[list[Path], list[str]]:
    """The clips named by ``inputs``: clips, folders of clips (their video files, sorted), or
    lists of clips (:data:`LIST_SUFFIXES`). A clip that does not exist is kept: it fails with its
    own one-line error, and the others go on.

    Returns:
        the clips in order, and notes on inputs that named none (an empty folder or list).

    Raises:
        SfbError: a list does not exist or cannot be read.
    """
    clips: list[Path] = []
    notes: list[str] = []
    for text in inputs:
        path = Path(text)
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_SUFFIXES)
            if not found:
                notes.append(f"no video files in {printable(str(path))}")
            clips += found
        elif path.suffix.lower() in LIST_SUFFIXES and not path.exists():
            # A missing clip fails alone; a missing list names no clip at all.
            raise SfbError(f"list of clips not found: {printable(str(path))}")
        elif path.suffix.lower() in LIST_SUFFIXES and path.is_file():
            try:
                lines = path.read_text().splitlines()
            except (OSError, UnicodeDecodeError) as exc:
                raise SfbError(
                    f"cannot read the list of clips {path}: {getattr(exc, 'strerror', None) or exc}"
                ) from None
            listed = [line.split("#", 1)[0].strip() for line in lines]
            listed = [entry for entry in listed if entry]
            if not listed:
                notes.append(f"no clips listed in {printable(str(path))}")
            clips += [(path.parent / entry) if not Path(entry).is_absolute() else Path(entry) for entry in listed]
        else:
            clips.append(path)
    return clips, notes


def plan_jobs(clips: Sequence[Path], out: Path) -> list[ClipJob]:
    """One job per clip, its run folder ``out/<clip name>``, names made unique in order
    (``a``, ``a-2``, ...)."""
    jobs: list[ClipJob] = []
    taken: set[str] = set()
    for video in clips:
        stem = video.stem or "clip"
        name, k = stem, 1
        while name in taken:
            k += 1
            name = f"{stem}-{k}"
        taken.add(name)
        # Absolute: a Ray worker does not start in this process's working folder.
        jobs.append(ClipJob(name, video.absolute(), out.absolute() / name))
    return jobs


def run_clip(
    job: ClipJob, options: ClipOptions, config: Config, device: str, report: Callable[[str, int], None] | None = None
) -> ClipRow:
    """``sfb-video process`` on one clip into ``job.out``: resumed from its saved frames, or
    nothing at all when it finished with the same clip and config before.

    Bad input and outputs that cannot be written are the clip's ``failed`` row; anything
    else raises (the batch reports it as the clip's error).

    Args:
        options: what every clip of the batch is asked; device: ``auto``, ``cpu`` or ``cuda``,
            resolved where the clip runs.
        report: called with the clip's name and the number of its frames done so far.
    """
    started = time.perf_counter()
    row = ClipRow(job.name, str(job.video), str(job.out), FAILED)
    try:
        where = resolve_device(device)
        process = options.for_clip(job.video, job.out)
        summary = finished_summary(process, config, where)
        note = "finished before: nothing to do"
        if summary is None:
            done: set[int] = set()

            def on_frame(status: FrameStatus) -> None:
                done.add(status.index)  # a frame of several objects reports each
                if report is not None:
                    report(job.name, len(done))

            summary = process_clip(process, config, where, quiet=True, on_frame=on_frame)
            note = ""
    except (SfbError, OutputError) as exc:
        return dataclasses.replace(row, seconds=time.perf_counter() - started, error=printable(str(exc)))
    status = DONE if summary["frames_fitted"] else NO_OBJECT
    return dataclasses.replace(
        row,
        status=status,
        frames=summary["frames_read"],
        fitted=summary["frames_fitted"],
        seconds=time.perf_counter() - started,
        note=note,
    )


def check_writable(out: Path) -> None:
    """Raise :class:`SfbError` unless a file can be made and removed in ``out`` (made if missing)
    from where this runs: a Ray worker, when it runs there."""
    probe = out / f".sfb-video-write-check-{uuid.uuid4().hex}"
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise SfbError(f"output folder {out} is not writable: {exc.strerror or exc}") from None


def write_report(out: Path, rows: Sequence[ClipRow], record: dict[str, Any], finished: bool) -> None:
    """``batch.csv`` and ``batch.json`` in ``out``, atomically."""
    fields = [f.name for f in dataclasses.fields(ClipRow)]
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    writer.writerows(dataclasses.asdict(r) for r in rows)
    atomic_write_bytes(out / CSV_NAME, text.getvalue().encode())
    write_json(out / JSON_NAME, record | {"finished": finished, "clips": [dataclasses.asdict(r) for r in rows]})


def table(rows: Sequence[ClipRow]) -> str:
    """The closing Markdown table, one row per clip."""
    lines = ["| clip | status | frames | fitted | s | retries | error |", "|---|---|---:|---:|---:|---:|---|"]
    for r in rows:
        error = r.error or r.note
        lines.append(
            f"| {printable(r.clip)} | {r.status} | {r.frames} | {r.fitted} | {r.seconds:.1f} | {r.retries} | {error} |"
        )
    return "\n".join(lines)


@dataclass(frozen=True)
class BatchPlan:
    """A whole batch: its clips' jobs, what every clip is run with, and where and how they run."""

    jobs: list[ClipJob]
    options: ClipOptions
    config: Config
    out: Path
    device: str = "auto"
    resources: Resources = field(default_factory=Resources)
    max_retries: int = 3
    ray_address: str | None = None
    use_ray: bool = True
    local_cpus: int | None = None


def run_batch(
    plan: BatchPlan,
    on_row: Callable[[int, ClipRow], None] | None = None,
    on_frames: Callable[[int], None] | None = None,
    on_retry: Callable[[ClipJob, str], None] | None = None,
) -> list[ClipRow]:
    """Run every clip of ``plan`` and return their rows (in the plan's order), keeping
    ``batch.csv`` and ``batch.json`` up to date as clips end.

    Args:
        on_row: told each clip's row as it ends.
        on_frames: told the number of frames done over all clips, as it grows.
        on_retry: told a clip whose worker died and which starts again.

    Raises:
        SfbError: the output folder cannot be written (here or from a worker); Ray cannot be
            started or reached.
    """
    rows = [ClipRow(j.name, str(j.video), str(j.out), PENDING) for j in plan.jobs]
    record = {
        "format": "sfb-video batch",
        "ray_address": plan.ray_address if plan.use_ray else None,
        "cpus_per_clip": plan.resources.cpus,
        "gpus_per_clip": plan.resources.gpus,
        "max_retries": plan.max_retries,
    }
    frames_done = [0] * len(plan.jobs)
    index = {job.name: i for i, job in enumerate(plan.jobs)}

    def frame_report(name: str, done: int) -> None:
        frames_done[index[name]] = done
        if on_frames is not None:
            on_frames(sum(frames_done))

    def done(i: int, outcome: Outcome) -> None:
        job = plan.jobs[i]
        if outcome.error:
            row = ClipRow(job.name, str(job.video), str(job.out), FAILED, error=outcome.error)
        else:
            row = outcome.value
        rows[i] = dataclasses.replace(row, retries=outcome.retries)
        write_report(plan.out, rows, record, finished=all(r.status != PENDING for r in rows))
        if on_row is not None:
            on_row(i, rows[i])

    if not plan.use_ray:
        check_writable(plan.out)
        write_report(plan.out, rows, record, finished=not rows)
        jobs = [(job, plan.options, plan.config, plan.device, frame_report) for job in plan.jobs]
        run_here(run_clip, jobs, plan.resources, done)
        return rows
    from sfb_video.cluster import connected

    progress = plan.out.absolute() / PROGRESS
    with connected(plan.ray_address, plan.local_cpus):  # first: a batch that cannot start writes nothing
        import ray
        from ray.exceptions import RayTaskError

        check_writable(plan.out)
        try:
            ray.get(ray.remote(check_writable).options(num_cpus=0).remote(progress))
        except RayTaskError as exc:
            raise SfbError(f"{exc.cause if exc.cause is not None else exc} (checked from a Ray worker)") from None
        write_report(plan.out, rows, record, finished=not rows)
        reporter = _FileReport(progress)
        jobs = [(job, plan.options, plan.config, plan.device, reporter) for job in plan.jobs]

        def poll() -> None:
            for i, job in enumerate(plan.jobs):
                count = reporter.read(job.name)
                if count is not None and count != frames_done[i]:
                    frame_report(job.name, count)

        def retried(i: int, why: str) -> None:
            if on_retry is not None:
                on_retry(plan.jobs[i], why)

        try:
            run_on_ray(run_clip, jobs, plan.resources, plan.max_retries, done, retried, on_tick=poll)
            poll()
        finally:
            shutil.rmtree(progress, ignore_errors=True)
    return rows


PROGRESS = ".sfb-video-batch-progress"
"""The folder in a batch's output where Ray workers count each clip's frames done."""


class _FileReport:
    """A worker's count of a clip's frames done, written where the batch's driver reads it (Ray
    tasks that call an actor as they go are not given the same worker again, which would pay a
    worker's start for every clip)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder

    def __call__(self, name: str, done: int) -> None:
        with contextlib.suppress(OSError):  # progress only: never the clip's failure
            (self.folder / name).write_text(str(done))

    def read(self, name: str) -> int | None:
        try:
            return int((self.folder / name).read_text())
        except (OSError, ValueError):
            return None
