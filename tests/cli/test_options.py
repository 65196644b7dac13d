"""Option errors: one line naming the option and what is wrong (no usage block), checked before
anything runs; ``--frames`` counts from the clip's end like a Python slice."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sfb_video.cli import main
from sfb_video.errors import SfbError
from sfb_video.stages.read import select_frames
from sfb_video.video import VideoWriter

FAST = ["--config", "fast", "--device", "cpu", "--quiet"]


@pytest.fixture(scope="module")
def six_frames(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("clip") / "six.mp4"
    scene = np.random.default_rng(0).integers(40, 200, (48, 64, 3), dtype=np.uint8)
    with VideoWriter(path, 30.0, 64, 48) as video:
        for _ in range(6):
            video.write(scene)
    return path


def _one_line(capsys: pytest.CaptureFixture[str], *words: str) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err and "usage:" not in err, err
    for word in words:
        assert word in err, err
    return err


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (
            ["process", "x.mp4", "--tsr", "abc"],
            ["sfb-video process: error:", "--tsr", "'abc'", "see sfb-video process --help"],
        ),
        (["process"], ["the following arguments are required: video"]),
        (["process", "x.mp4", "--tsr", "0"], ["argument --tsr: must be at least 1, got 0"]),
        (["fit", "--image", "a", "--background", "b", "--tsr", "0"], ["argument --tsr: must be at least 1, got 0"]),
        (["export", "run", "--views", "1"], ["argument --views: must be at least 2, got 1"]),
        (["batch", "x.mp4", "--gpus-per-clip", "-1"], ["argument --gpus-per-clip: must be at least 0, got -1"]),
        (["process", "x.mp4", "--frames", "a:b"], ["argument --frames", "START:STOP"]),
        (["fit", "--image", "a.png"], ["--background"]),
        (["eval", "--dataset", "nope", "--root", "."], ["--dataset", "invalid choice"]),
        (["bogus"], ["invalid choice", "see sfb-video --help"]),
        (["replay", "run", "--web-port", "x"], ["--web-port"]),
    ],
)
def test_parse_errors_are_one_line(capsys: pytest.CaptureFixture[str], args: list[str], words: list[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    _one_line(capsys, *words)


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--set", "fit.iterations=-5"], ["fit.iterations must be >= 1, got -5"]),
        (["--set", "video.exposure_fraction=0"], ["video.exposure_fraction must be > 0"]),
        (["--frames", "100:200"], ["--frames 100:200 selects no frames of the 6-frame clip"]),
        (["--frames", "-2:3"], ["--frames -2:3 selects no frames of the 6-frame clip"]),
    ],
)
def test_bad_values_are_refused_before_anything_runs(
    six_frames: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], words: list[str]
) -> None:
    out = tmp_path / "o"
    assert main(["process", str(six_frames), "--out", str(out), *FAST, *extra]) == 2
    _one_line(capsys, *words)
    assert not out.exists()


def test_a_folder_given_as_the_clip_is_named_as_such(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["process", str(tmp_path), "--out", str(tmp_path / "o"), *FAST]) == 2
    _one_line(capsys, "is a folder, not a video file")


def test_frames_count_from_the_end_like_a_slice() -> None:
    def frames(text: str) -> list[int]:
        chosen = select_frames(text, 6)
        assert chosen is not None
        return list(chosen)

    assert frames("1:3") == [1, 2]
    assert frames("-2:") == [4, 5]
    assert frames(":-4") == [0, 1]
    assert frames("-1") == [5]
    assert frames("4") == [4]
    assert frames("3:100") == [3, 4, 5]
    with pytest.raises(SfbError, match="selects no frames"):
        frames("-2:3")
    assert select_frames(None, 6) is None
    assert list(select_frames("2:4", None) or []) == [2, 3]
    with pytest.raises(SfbError, match="does not record its length"):
        select_frames("-2:", None)


def test_a_negative_range_on_the_command_line_reaches_the_run(
    six_frames: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # "--frames -2:" would be two options to argparse; it is one range here.
    out = tmp_path / "o"
    assert main(["process", str(six_frames), "--out", str(out), "--frames", "-2:", *FAST]) == 3  # static: nothing moves
    assert '"frames": [\n    4,\n    6\n  ]' in (out / "run.json").read_text()
