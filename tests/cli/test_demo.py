from pathlib import Path

import pytest
import torch

from sfb_video.cli import main
from sfb_video.config import load_config
from sfb_video.demo import run_demo
from sfb_video.imageio import read_image

FAST = ["--config", "fast", "--device", "cpu", "--quiet"]


def test_demo_writes_a_blurred_frame_whose_subframes_average_to_it(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), *FAST]) == 0
    assert {p.name for p in out.iterdir()} == {"blurred.png", "background.png", "subframes.png", "config.yaml"}
    blurred, background = read_image(out / "blurred.png"), read_image(out / "background.png")
    strip = read_image(out / "subframes.png")
    n = strip.shape[2] // blurred.shape[2]
    subframes = torch.stack(strip.chunk(n, dim=2))
    assert n == load_config("fast").demo.subframes
    # The object is there, and the blurred frame is the mean of its sharp sub-frames.
    assert (blurred - background).abs().amax(0).gt(0.1).sum() > 50
    assert (subframes.mean(0) - blurred).abs().max() < 3 / 255


def test_demo_is_deterministic() -> None:
    config = load_config("fast")
    a = run_demo(config, torch.device("cpu"))
    b = run_demo(config, torch.device("cpu"))
    assert torch.equal(a.blurred, b.blurred)


def test_existing_output_is_not_overwritten_silently(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), *FAST]) == 0
    stamp = (out / "blurred.png").stat().st_mtime_ns
    assert main(["demo", "--out", str(out), *FAST]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--overwrite" in err
    assert (out / "blurred.png").stat().st_mtime_ns == stamp
    assert main(["demo", "--out", str(out), "--overwrite", *FAST]) == 0
    assert not list(tmp_path.glob(".demo*"))


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--set", "render.bogus=1"], "unknown config key"),
        (["--config", "nope"], "not found"),
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
    assert "cannot write to output folder" in capsys.readouterr().err
