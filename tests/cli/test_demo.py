"""``sfb-video demo``: a generated clip processed end to end, and its argument errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from sfb_video.cli import main
from sfb_video.config import load_config

FAST = ["--config", "fast", "--device", "cpu", "--quiet"]


def test_demo_processes_a_generated_clip_and_scores_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--config", "fast", "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "accuracy against the generated ground truth" in printed and "| mean |" in printed
    assert (tmp_path / "demo-clip.mp4").is_file()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames_fitted"] == load_config("fast").demo.frames
    for name in ("tsr.mp4", "trajectory.csv", "recording.rrd", "config.yaml"):
        assert (out / name).is_file()
    # A second run does not replace the finished one without --overwrite.
    stamp = (out / "summary.json").stat().st_mtime_ns
    assert main(["demo", "--out", str(out), *FAST]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--overwrite" in err
    assert (out / "summary.json").stat().st_mtime_ns == stamp


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--set", "render.bogus=1"], "unknown config key"),
        (["--config", "nope"], "no config preset 'nope'"),
        (["--device", "cuda:7"] if not torch.cuda.is_available() else ["--device", "tpu"], "device"),
    ],
)
def test_bad_arguments_give_one_line_errors(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    args = ["demo", "--out", str(tmp_path / "d"), "--quiet", *extra]
    if "--config" not in extra:
        args += ["--config", "fast"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err
    assert not (tmp_path / "d").exists()


def test_unwritable_output_folder_is_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["demo", "--out", str(blocker / "demo"), *FAST]) == 2
    assert "cannot write" in capsys.readouterr().err
