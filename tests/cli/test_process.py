"""``sfb-video process`` on bad input: one-line errors or a clean "nothing found", right exit codes."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest

import sfb_video.stages.track
from sfb_video.cli import main
from sfb_video.config import load_config
from sfb_video.demo import demo_clip, demo_config
from sfb_video.video import VideoWriter
from tests.media import write_keyframeless

FAST = ["--config", "fast", "--device", "cpu", "--quiet"]


def _write(path: Path, frames: list[np.ndarray], fps: float = 30.0) -> Path:
    with VideoWriter(path, fps, frames[0].shape[1], frames[0].shape[0]) as video:
        for frame in frames:
            video.write(frame)
    return path


def _one_line_error(capsys: pytest.CaptureFixture[str], *words: str) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("sfb-video: error:") and "\n" not in err, err
    assert "Traceback" not in err
    for word in words:
        assert word in err, err
    return err


def _static(n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    scene = rng.integers(40, 200, (96, 128, 3), dtype=np.uint8)
    return [scene for _ in range(n)]


def test_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["process", str(tmp_path / "nope.mp4"), "--out", str(tmp_path / "o"), *FAST]) == 2
    _one_line_error(capsys, "not found", "nope.mp4")
    assert not (tmp_path / "o").exists()


def test_not_a_video(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "notes.mp4"
    path.write_text("this is not a video\n")
    assert main(["process", str(path), "--out", str(tmp_path / "o"), *FAST]) == 2
    _one_line_error(capsys, "notes.mp4")
    assert not (tmp_path / "o").exists()


def test_zero_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write_keyframeless(tmp_path / "empty.mkv")
    assert main(["process", str(path), "--out", str(tmp_path / "o"), *FAST]) == 2
    _one_line_error(capsys, "no frames")
    assert not (tmp_path / "o").exists()


def test_one_frame(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path / "one.mp4", _static(1))
    assert main(["process", str(path), "--out", str(tmp_path / "o"), *FAST]) == 2
    _one_line_error(capsys, "at least 2 frames", "background")
    assert not (tmp_path / "o").exists()


def test_tiny_frames(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path / "tiny.mp4", [np.zeros((8, 10, 3), np.uint8)] * 3)
    assert main(["process", str(path), "--out", str(tmp_path / "o"), *FAST]) == 2
    _one_line_error(capsys, "too small")


def test_no_moving_object_is_a_clean_nothing_found(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path / "static.mp4", _static(6))
    out = tmp_path / "o"
    assert main(["process", str(path), "--out", str(out), "--config", "fast", "--device", "cpu"]) == 3
    captured = capsys.readouterr()
    assert "no moving object" in captured.out and "Traceback" not in captured.err
    assert (out / "summary.json").is_file()  # a finished run that found nothing
    with av.open(str(out / "tsr.mp4")) as container:  # the clip passed through at N x the rate
        assert sum(1 for _ in container.decode(video=0)) == 6 * load_config("fast").video.tsr


def test_object_leaving_the_frame(tmp_path: Path) -> None:
    config = demo_config(load_config("fast"))
    clip = demo_clip(config)
    # Cut the frames so that the object's last streak is half outside the right border, and the
    # clip then goes on without it.
    x, _, w, _ = clip.truth[-1].bbox
    frames = [f[:, : x + w // 2] for f in clip.frames]
    frames += [clip.scene.background[:, : x + w // 2]] * 2
    path = _write(tmp_path / "leaving.mp4", [np.ascontiguousarray(f) for f in frames])
    out = tmp_path / "o"
    assert main(["process", str(path), "--out", str(out), *FAST, "--set", "video.exposure_fraction=0.8"]) == 0
    summary = (out / "summary.json").read_text()
    assert '"status": "no_object"' in summary and '"status": "fitted"' in summary


def test_unwritable_output_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path / "static.mp4", _static(3))
    blocker = tmp_path / "file"
    blocker.write_text("a file where the output's parent folder should be")
    assert main(["process", str(path), "--out", str(blocker / "run"), *FAST]) == 2
    _one_line_error(capsys, "cannot write")


def test_output_folder_that_is_not_a_run_is_left_alone(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _write(tmp_path / "static.mp4", _static(3))
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("precious")
    assert main(["process", str(path), "--out", str(out), "--overwrite", *FAST]) == 2
    _one_line_error(capsys, "not an sfb-video output", "never replaced")
    assert (out / "thesis.tex").read_text() == "precious"


def test_ctrl_c_exits_130_and_keeps_finished_frames_for_resuming(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    config = demo_config(load_config("fast"))
    path = _write(tmp_path / "clip.mp4", list(demo_clip(config).frames))
    real_fit = sfb_video.stages.track.fit_detection
    calls: list[int] = []

    def fit_then_interrupt(*args: object, **kwargs: object) -> object:
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(sfb_video.stages.track, "fit_detection", fit_then_interrupt)
    out = tmp_path / "o"
    # One track at a time: a frame is written once the next is fitted (nothing looks back).
    args = [
        "process",
        str(path),
        "--out",
        str(out),
        *FAST,
        "--set",
        "video.exposure_fraction=0.8",
        "--max-objects",
        "1",
    ]
    assert main(args) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "resume" in err and "Traceback" not in err
    assert not (out / "summary.json").exists() and not (out / "tsr.mp4").exists()
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["frame_00000_track_00.pt", "frame_00001_track_00.pt"]


@pytest.mark.parametrize(("frames", "message"), [("5:2", "selects no frames"), ("-9:-8", "selects no frames")])
def test_bad_frame_range(tmp_path: Path, capsys: pytest.CaptureFixture[str], frames: str, message: str) -> None:
    path = _write(tmp_path / "static.mp4", _static(3))
    assert main(["process", str(path), "--out", str(tmp_path / "o"), "--frames", frames, *FAST]) == 2
    _one_line_error(capsys, message)
