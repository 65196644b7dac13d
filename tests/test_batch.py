"""``sfb-video batch`` and ``sfb-video eval --ray-address`` on a local Ray (fast preset, tiny clips).

A local Ray takes a few seconds to start; each test that needs one starts its own through the
command, as a user's run does.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

import sfb_video.cluster
from benchmarks.batch import write_clips
from sfb_video.batch import gather_clips, plan_jobs
from sfb_video.cli import main
from sfb_video.config import load_config
from sfb_video.demo import demo_config
from tests.evaluation.fmo_fixture import write_fixture

pytest.importorskip("ray")

QUICK = ["--config", "fast", "--set", "fit.iterations=60", "--set", "fit.warm_iterations=30", "--device", "cpu"]
BATCH = [*QUICK, "--masks", "diff", "--quiet", "--cpus-per-clip", "1"]


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    config = demo_config(load_config("fast"))
    return write_clips(tmp_path_factory.mktemp("clips"), 2, 5, config, small=True)


@pytest.fixture(scope="module")
def batch(clips: list[Path], tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[str], int]:
    """Two good clips and a corrupt one, on a local Ray."""
    root = tmp_path_factory.mktemp("batch")
    corrupt = root / "corrupt.mp4"
    corrupt.write_bytes(b"\x00\x00\x00\x18ftypmp42 this is not a video")
    out = root / "runs"
    args = ["batch", *map(str, clips), str(corrupt), "--out", str(out), *BATCH]
    return out, args, main(args)


def _rows(path: Path) -> dict[str, dict[str, str]]:
    with path.open() as f:
        return {r["clip"]: r for r in csv.DictReader(f)}


def test_inputs_are_clips_folders_and_lists_with_unique_names(tmp_path: Path) -> None:
    folder = tmp_path / "season"
    folder.mkdir()
    for name in ("b.mp4", "a.AVI", "notes.md"):
        (folder / name).write_bytes(b"")
    listing = tmp_path / "more.txt"
    listing.write_text("# two more\nseason/a.AVI\n\n/elsewhere/c.mkv  # absolute\n")
    clips, notes = gather_clips([str(folder), str(listing), str(tmp_path / "missing.mp4"), str(tmp_path / "empty")])
    assert clips == [
        folder / "a.AVI",
        folder / "b.mp4",
        folder / "a.AVI",
        Path("/elsewhere/c.mkv"),
        tmp_path / "missing.mp4",
        tmp_path / "empty",
    ]
    assert notes == []
    (tmp_path / "empty").mkdir()
    assert gather_clips([str(tmp_path / "empty")]) == ([], [f"no video files in {tmp_path / 'empty'}"])
    names = [j.name for j in plan_jobs(clips, tmp_path / "runs")]
    assert names == ["a", "b", "a-2", "c", "missing", "empty"]


def test_good_clips_finish_and_a_corrupt_one_fails_alone(batch: tuple[Path, list[str], int]) -> None:
    out, _, code = batch
    assert code == 5
    rows = _rows(out / "batch.csv")
    assert [rows[k]["status"] for k in ("clip0", "clip1", "corrupt")] == ["done", "done", "failed"]
    assert "corrupt.mp4" in rows["corrupt"]["error"] and "\n" not in rows["corrupt"]["error"]
    for name in ("clip0", "clip1"):
        assert int(rows[name]["fitted"]) == int(rows[name]["frames"]) == 5
        assert float(rows[name]["seconds"]) > 0 and rows[name]["retries"] == "0"
        assert json.loads((out / name / "run.json").read_text())["finished"]
    record = json.loads((out / "batch.json").read_text())
    assert record["finished"] and [c["status"] for c in record["clips"]] == ["done", "done", "failed"]


def test_a_finished_batch_run_again_does_no_work(batch: tuple[Path, list[str], int]) -> None:
    out, args, _ = batch
    frames = sorted((out / "clip0" / "frames").iterdir())
    before = {p: p.stat().st_mtime_ns for p in [*frames, out / "clip0" / "tsr.mp4"]}
    assert main(args) == 5  # the corrupt clip fails again, and only it
    rows = _rows(out / "batch.csv")
    assert rows["clip0"]["note"] == rows["clip1"]["note"] == "finished before: nothing to do"
    assert {p: p.stat().st_mtime_ns for p in before} == before


def _ray_worker_pids() -> list[int]:
    """Processes running one of our jobs (Ray titles a worker by the task it runs)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                title = (entry / "cmdline").read_bytes()
            except OSError:
                continue
            if title.startswith(b"ray::_limited"):
                pids.append(int(entry.name))
    return pids


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the worker through /proc")
def test_a_clip_whose_worker_is_killed_resumes_and_ends_as_an_uninterrupted_run(
    clips: list[Path], batch: tuple[Path, list[str], int], tmp_path: Path
) -> None:
    out = tmp_path / "runs"
    command = [sys.executable, "-m", "sfb_video.cli", "batch", str(clips[0]), "--out", str(out), *BATCH]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 300
    killed = None
    while killed is None and time.monotonic() < deadline and process.poll() is None:
        if (out / "clip0" / "frames").is_dir() and any((out / "clip0" / "frames").glob("frame_*.pt")):
            for pid in _ray_worker_pids():
                os.kill(pid, signal.SIGKILL)
                killed = pid
        time.sleep(0.05)
    _, err = process.communicate(timeout=300)
    assert killed is not None, "the clip finished before its worker could be killed"
    assert process.returncode == 0, err
    row = _rows(out / "batch.csv")["clip0"]
    assert row["status"] == "done" and row["retries"] == "1"
    # The same outputs as the uninterrupted run of the same clip in the first batch.
    uninterrupted, _, _ = batch
    assert (out / "clip0" / "trajectory.csv").read_text() == (uninterrupted / "clip0" / "trajectory.csv").read_text()


def test_without_ray_the_clips_run_here_one_after_another(
    clips: list[Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(sfb_video.cluster, "ray_installed", lambda: False)
    out = tmp_path / "runs"
    args = ["batch", str(clips[1]), "--out", str(out), *[a for a in BATCH if a != "--quiet"]]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "Ray is not installed" in captured.err and "pip install 'sfb-video[cluster]'" in captured.err
    assert "| clip1 | done | 5 | 5 |" in captured.out
    assert main([*args, "--ray-address", "auto"]) == 2  # asked for a cluster without Ray: bad options


def test_eval_tables_are_the_same_with_and_without_ray(tmp_path: Path) -> None:
    root = tmp_path / "tbd3d"
    write_fixture(root, "tbd3d")
    common = ["eval", "--dataset", "tbd3d", "--root", str(root), "--max-frames", "2", "--mode", "all", *QUICK]
    assert main([*common, "--out", str(tmp_path / "here"), "--quiet"]) == 0
    assert main([*common, "--out", str(tmp_path / "ray"), "--quiet", "--ray-address", "local"]) == 0
    for name in ("frames.csv", "sequences.csv"):
        with (tmp_path / "here" / name).open() as a, (tmp_path / "ray" / name).open() as b:
            here, ray = list(csv.DictReader(a)), list(csv.DictReader(b))
        assert len(here) == len(ray) > 0
        for x, y in zip(here, ray, strict=True):
            x.pop("seconds"), y.pop("seconds")  # measured time, never the same twice
            assert x == y


def test_a_cluster_that_cannot_be_reached_is_one_line_and_writes_nothing(
    clips: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "runs"
    args = ["batch", str(clips[0]), "--out", str(out), *BATCH, "--ray-address", "127.0.0.1:1"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sfb-video: error: cannot reach the Ray cluster at 127.0.0.1:1") and "\n" not in err
    assert not out.exists()


def test_a_list_of_clips_that_does_not_exist_is_refused_before_ray_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_ray(*args: object, **kwargs: object) -> None:
        raise AssertionError("Ray was started for a batch with no clips")

    monkeypatch.setattr(sfb_video.cluster, "connected", no_ray)
    out = tmp_path / "runs"
    assert main(["batch", str(tmp_path / "missing.txt"), "--out", str(out), *BATCH]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"sfb-video: error: list of clips not found: {tmp_path / 'missing.txt'}"
    assert not out.exists()
