"""Output folders from the user's side: what every command does with an existing folder, and what
a run does when it is replaced, fails, is interrupted, runs out of disk, loses its folder or its
permission mid-run. The old outputs must stay whole, the finished frames kept, no temporary file
left, and the next run must resume."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

import sfb_video.stages.frame_buffer
import sfb_video.stages.process
import sfb_video.stages.track
from sfb_video.cli import main
from sfb_video.config import load_config
from sfb_video.demo import demo_clip, demo_config
from sfb_video.imageio import write_image
from sfb_video.run_folder import NEW_SUFFIX, read_marker, sibling
from sfb_video.video import VideoWriter

TINY = ["demo.frames=4", "demo.width=120", "demo.height=90", "demo.size_px=[14.0, 16.0]"]
QUICK = ["--config", "fast", "--device", "cpu", "--quiet", "--masks", "diff"]
QUICK += ["--set", "fit.iterations=20", "--set", "fit.warm_iterations=10", "--set", "video.exposure_fraction=0.8"]
# One object: no track looks back, so each frame is written as soon as the next one is fitted.
QUICK += ["--set", "video.max_objects=1"]


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4-frame 120x90 clip of a ball flying past a photo."""
    frames = demo_clip(demo_config(load_config("fast", TINY))).frames
    path = tmp_path_factory.mktemp("clip") / "ball.mp4"
    with VideoWriter(path, 30.0, frames[0].shape[1], frames[0].shape[0]) as video:
        for frame in frames:
            video.write(frame)
    return path


@pytest.fixture(scope="module")
def finished(clip: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished run of ``clip`` (copy it before changing it)."""
    out = tmp_path_factory.mktemp("finished") / "run"
    assert main(["process", str(clip), "--out", str(out), *QUICK]) == 0
    return out


def _copy(run: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    return copy


def _contents(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _one_line(capsys: pytest.CaptureFixture[str], *words: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("sfb-video") and "\n" not in err and "Traceback" not in err, err
    for word in words:
        assert word in err, err
    return err


def _temporaries(folder: Path) -> list[Path]:
    return [p for p in folder.parent.rglob("*") if ".tmp" in p.name]


# --------------------------------------------------------------------------------------------
# Replacing a run


def test_overwrite_with_a_bad_option_leaves_the_finished_run_whole(
    clip: Path, finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = _copy(finished, tmp_path)
    before = _contents(out)
    other = tmp_path / "other-size.png"
    write_image(other, np.zeros((48, 64, 3), np.uint8))
    args = ["process", str(clip), "--out", str(out), "--overwrite", "--background", str(other), *QUICK]
    assert main(args) == 2
    _one_line(capsys, "the background is 64x48 but the frames are 120x90")
    assert _contents(out) == before
    assert not sibling(out, NEW_SUFFIX).exists() and not _temporaries(out)


def test_a_replacement_interrupted_keeps_the_old_run_and_resumes(
    clip: Path, finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = _copy(finished, tmp_path)
    before = _contents(out)
    real_fit = sfb_video.stages.track.fit_detection
    calls: list[int] = []

    def interrupt_the_third(*args: object, **kwargs: object) -> object:
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real_fit(*args, **kwargs)

    args = ["process", str(clip), "--out", str(out), "--overwrite", "--tsr", "2", *QUICK]
    with monkeypatch.context() as patch:
        patch.setattr(sfb_video.stages.track, "fit_detection", interrupt_the_third)
        assert main(args) == 130
    _one_line(capsys, "interrupted", "stays as it was", "resume")
    assert _contents(out) == before
    staged = sibling(out, NEW_SUFFIX)
    assert sorted(p.name for p in (staged / "frames").iterdir()) == [f"frame_0000{i}_track_00.pt" for i in (0, 1)]
    args_loud = [a for a in args if a != "--quiet"]
    assert main(args_loud) == 0
    assert "resuming the unfinished replacement" in capsys.readouterr().out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["tsr"] == 2 and summary["frames_fitted"] == 4
    assert not staged.exists() and not _temporaries(out)


@pytest.mark.usefixtures("ctrl_c")
def test_a_replacement_stopped_by_sigint_keeps_the_old_run(clip: Path, finished: Path, tmp_path: Path) -> None:
    out = _copy(finished, tmp_path)
    before = _contents(out)
    staged = sibling(out, NEW_SUFFIX)
    command = [sys.executable, "-m", "sfb_video.cli", "process", str(clip), "--out", str(out), "--overwrite"]
    command += [*QUICK, "--set", "fit.warm_iterations=400", "--set", "fit.plateau_patience=400"]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not list((staged / "frames").glob("*.pt")) and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.05)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert _contents(out) == before
    assert list((staged / "frames").glob("*.pt")) and not _temporaries(out)


@pytest.mark.usefixtures("ctrl_c")
def test_ctrl_c_at_any_moment_of_an_export_ends_it_with_130_or_its_finish(finished: Path, tmp_path: Path) -> None:
    # Through the console command, from its start-up (torch loading, trimesh's imports, which
    # once swallowed the KeyboardInterrupt) through the export and the folder's swap to Python's
    # shutdown (where the process once died of the signal: -2): 130 with the run as it was, or 0
    # with the export done; one line at most, never a traceback.
    out = _copy(finished, tmp_path)
    command = [str(Path(sys.executable).parent / "sfb-video"), "export", str(out), "--tsr", "16", "--quiet"]
    start = time.monotonic()
    subprocess.run(command, check=True)
    whole = time.monotonic() - start
    # An export is deterministic, finished or not (but for the recording's random row ids).
    before = _contents(out)
    del before["recording.rrd"]
    codes = []
    for fraction in (0.05, 0.2, 0.4, 0.6, 0.8, 0.9, 0.97):
        process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
        time.sleep(whole * fraction)
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=120)
        codes.append(process.returncode)
        assert process.returncode in (0, 130), (fraction, process.returncode, err)
        assert "Traceback" not in err and len(err.strip().splitlines()) <= 1, err
        after = _contents(out)
        assert after.pop("recording.rrd") and after == before and not _temporaries(out)
    assert 130 in codes  # the early ones land during the run


# --------------------------------------------------------------------------------------------
# Faults during a run: a full disk, the folder removed, the folder made read-only


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 3 MB tmpfs, where this test may mount one (root on Linux); skipped elsewhere."""
    disk = tmp_path / "disk"
    disk.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(disk)], capture_output=True)
    if done.returncode != 0:
        pytest.skip("cannot mount a tmpfs here")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def _fill(disk: Path) -> Path:
    filler = disk / "filler"
    with open(filler, "wb") as f, pytest.raises(OSError):
        while True:
            f.write(b"\0" * (1 << 16))
            f.flush()
            os.fsync(f.fileno())
    return filler


def _after_saves(monkeypatch: pytest.MonkeyPatch, count: int, fault: Callable[[], None]) -> None:
    """Run ``fault`` once, just before the fit written after ``count`` written ones."""
    real_save = sfb_video.stages.frame_buffer.save_result
    saved: list[int] = []

    def save(folder: Path, result: object, followed: object = None) -> None:
        if len(saved) == count:
            saved.append(-1)
            fault()
        real_save(folder, result, followed)
        saved.append(1)

    monkeypatch.setattr(sfb_video.stages.frame_buffer, "save_result", save)


def test_no_file_of_a_run_folder_is_written_twice(clip: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # Results flow one way: a fit, a window, an export is written once, when it is final (a
    # track's first frame, reversed by its second, too); only the folder's marker is written
    # when the run starts and again when it has finished.
    out = tmp_path / "run"
    writes: list[Path] = []
    real_replace = os.replace

    def replace(source: str | Path, target: str | Path) -> None:
        writes.append(Path(target))
        real_replace(source, target)

    monkeypatch.setattr(os, "replace", replace)
    assert main(["process", str(clip), "--out", str(out), "--tsr", "2", *QUICK]) == 0
    counts = {path.relative_to(out).as_posix(): writes.count(path) for path in set(writes) if path.is_relative_to(out)}
    assert counts.pop("run.json") == 2
    assert set(counts.values()) == {1}, counts
    assert {"tsr.mp4", "summary.json", "detections.json", "frames/frame_00000_track_00.pt"} <= set(counts)


@pytest.mark.parametrize("saved_before", [0, 1])
def test_a_full_disk_mid_run_is_one_line_keeps_the_frames_and_resumes(
    clip: Path, small_disk: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, saved_before: int
) -> None:
    out = small_disk / "run"
    filler: list[Path] = []
    args = ["process", str(clip), "--out", str(out), *QUICK]
    with monkeypatch.context() as patch:
        _after_saves(patch, saved_before, lambda: filler.append(_fill(small_disk)))
        assert main(args) == 4
    _one_line(capsys, "No space left on device", "run the same command again to resume")
    assert not (out / "summary.json").exists() and not _temporaries(out)
    kept = sorted(p.name for p in (out / "frames").iterdir()) if out.exists() else []
    assert kept == [f"frame_{i:05d}_track_00.pt" for i in range(saved_before)]
    filler[0].unlink()
    assert main([a for a in args if a != "--quiet"]) == 0
    resumed = capsys.readouterr().out
    assert ("resuming" in resumed) == bool(saved_before)
    assert json.loads((out / "summary.json").read_text())["frames_fitted"] == 4


def test_a_full_disk_during_the_exports_keeps_every_frame(
    clip: Path, small_disk: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = small_disk / "run"
    real_export = sfb_video.stages.process.export_frames
    filler: list[Path] = []

    def fill_then_export(*args: object, **kwargs: object) -> object:
        filler.append(_fill(small_disk))
        return real_export(*args, **kwargs)

    args = ["process", str(clip), "--out", str(out), *QUICK]
    with monkeypatch.context() as patch:
        patch.setattr(sfb_video.stages.process, "export_frames", fill_then_export)
        assert main(args) == 4
    _one_line(capsys, "No space left on device")
    assert len(list((out / "frames").iterdir())) == 4
    assert not (out / "summary.json").exists() and not (out / "tsr.mp4").exists() and not _temporaries(out)
    filler[0].unlink()
    assert main(args) == 0
    assert json.loads((out / "summary.json").read_text())["frames_fitted"] == 4


def test_the_run_folder_removed_mid_run_is_one_line(
    clip: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "run"
    args = ["process", str(clip), "--out", str(out), *QUICK]
    with monkeypatch.context() as patch:
        _after_saves(patch, 1, lambda: shutil.rmtree(out))
        assert main(args) == 4
    _one_line(capsys, str(out), "does not exist")
    assert not out.exists() and not _temporaries(out)  # not re-created half-empty
    assert main(args) == 0


def test_the_folder_made_read_only_mid_run_keeps_the_frames_and_resumes(
    clip: Path, small_disk: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # Root ignores permission bits, so the change of permission is a read-only remount.
    out = small_disk / "run"

    def read_only() -> None:
        subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)

    args = ["process", str(clip), "--out", str(out), *QUICK]
    with monkeypatch.context() as patch:
        _after_saves(patch, 2, read_only)
        assert main(args) == 4
    _one_line(capsys, "Read-only file system")
    subprocess.run(["mount", "-o", "remount,rw", str(small_disk)], check=True)
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["frame_00000_track_00.pt", "frame_00001_track_00.pt"]
    assert not (out / "summary.json").exists() and not _temporaries(out)
    assert main(args) == 0


def test_a_clip_whose_name_is_not_utf8_is_processed_like_any_other(clip: Path, tmp_path: Path) -> None:
    odd = Path(os.fsdecode(bytes(tmp_path) + b"/ball\xff\xfe.mp4"))
    shutil.copy(clip, odd)
    out = tmp_path / "run"
    command = [sys.executable, "-m", "sfb_video.cli", "process", str(odd), "--out", str(out)]
    command += [a for a in QUICK if a != "--quiet"]
    done = subprocess.run(command, capture_output=True, env=os.environ | {"LC_ALL": "C.UTF-8"}, timeout=300)
    assert done.returncode == 0, done.stderr.decode(errors="replace")
    assert b"Traceback" not in done.stderr and "wrote" in done.stdout.decode()
    assert json.loads((out / "summary.json").read_text())["frames_fitted"] == 4
    assert (out / "recording.rrd").is_file() and not _temporaries(out)


# --------------------------------------------------------------------------------------------
# A folder that is not ours, and every command's own folder


def test_a_foreign_run_json_is_not_taken_for_a_run(
    clip: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "analysis"
    out.mkdir()
    (out / "run.json").write_text(json.dumps({"experiment": 3, "video": "match.mp4"}))
    (out / "results.csv").write_text("a,b\n1,2\n")
    (out / "notes.md").write_text("keep me")
    before = _contents(out)
    image, background = _pair(tmp_path)
    for command in (
        ["process", str(clip), "--out", str(out), "--overwrite", *QUICK],
        ["fit", "--image", str(image), "--background", str(background), "--out", str(out), "--overwrite", *QUICK],
        ["eval", "--dataset", "tbd", "--root", str(tmp_path / "nowhere"), "--out", str(out), "--overwrite", *QUICK],
        ["export", str(out), "--quiet"],
    ):
        assert main(command) == 2
        _one_line(capsys, "not an sfb-video")
    assert _contents(out) == before


def _pair(tmp_path: Path) -> tuple[Path, Path]:
    """A blurred frame of the tiny clip and its background, as PNG."""
    clip = demo_clip(demo_config(load_config("fast", TINY)))
    image, background = tmp_path / "im.png", tmp_path / "bgr.png"
    write_image(image, clip.frames[1])
    write_image(background, clip.scene.background)
    return image, background


def test_fit_replaces_its_folder_only_with_a_finished_fit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    image, background = _pair(tmp_path)
    out = tmp_path / "fit"
    args = ["fit", "--image", str(image), "--background", str(background), "--out", str(out), *QUICK]
    assert main(args) == 0
    assert read_marker(out)["kind"] == "fit" and read_marker(out)["finished"]
    before = _contents(out)
    assert main(args) == 2
    _one_line(capsys, "holds a finished fit output", "--overwrite")

    def interrupted(*args: object, **kwargs: object) -> object:
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr("sfb_video.fitting.frame.fit_frame", interrupted)
        assert main([*args, "--overwrite"]) == 130
    assert _contents(out) == before
    assert main([*args, "--overwrite", "--tsr", "3"]) == 0
    assert json.loads((out / "run.json").read_text())["tsr"] == 3
    assert not sibling(out, NEW_SUFFIX).exists()


def test_an_export_that_fails_leaves_the_run_as_it_was(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = _copy(finished, tmp_path)
    before = _contents(out)

    def broken(*args: object, **kwargs: object) -> object:
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(sfb_video.stages.process, "write_csv", broken)
        assert main(["export", str(out), "--tsr", "2", "--quiet"]) == 130
    assert _contents(out) == before
    assert not sibling(out, NEW_SUFFIX).exists() and not _temporaries(out)
    assert main(["export", str(out), "--tsr", "2", "--quiet"]) == 0
    assert json.loads((out / "summary.json").read_text())["tsr"] == 2
    assert not sibling(out, NEW_SUFFIX).exists()


def test_an_export_of_a_run_made_by_another_version_says_so(
    finished: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # video.background_tolerance was deleted (2026-12-05); folders made before still carry it.
    out = _copy(finished, tmp_path)
    config = out / "config.yaml"
    config.write_text(config.read_text().replace("video:\n", "video:\n  background_tolerance: 0.05\n", 1))
    before = _contents(out)
    assert main(["export", str(out), "--quiet"]) == 2
    _one_line(capsys, "background_tolerance", "another version")
    assert _contents(out) == before
    assert main(["export", str(out), "--quiet", "--set", "video.nonsense=1"]) == 2  # the folder's fault first
    _one_line(capsys, "another version")
