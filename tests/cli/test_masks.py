"""``--masks`` and ``--defmo-weights`` from the command line: what is used, what is reported."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest
from rerun.chunk import RrdReader

from sfb_video import defmo
from sfb_video.cli import main
from sfb_video.config import load_config
from sfb_video.demo import demo_clip, demo_config
from sfb_video.video import VideoWriter

QUICK = ["--config", "fast", "--device", "cpu", "--set", "fit.iterations=20", "--set", "fit.warm_iterations=10"]
# Three frames of the six: enough to show warm starts; the others make their backgrounds.
THREE = ["--frames", "0:3", *QUICK]


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    config = demo_config(load_config("fast"))
    path = tmp_path_factory.mktemp("clip") / "clip.mp4"
    with VideoWriter(path, 30.0, config.demo.width, config.demo.height) as video:
        for frame in demo_clip(config).frames:
            video.write(frame)
    return path


def _mask_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("masks:")]


def test_process_with_defmo_weights_uses_and_reports_them_per_frame(
    clip: Path, defmo_weights: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    assert main(["process", str(clip), "--out", str(out), "--defmo-weights", str(defmo_weights), *THREE]) == 0
    assert _mask_lines(capsys.readouterr().err) == [
        f"masks: DeFMO's sub-frame masks (L_S): weights from {defmo_weights}"
    ]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["masks"] == {"source": "defmo", "reason": f"weights from {defmo_weights}"}
    fitted = [f for f in summary["frames"] if f["status"] == "fitted"]
    assert len(fitted) == 3
    for frame in fitted:
        assert frame["masks"] == "defmo" and frame["masks_order"] in ("as given", "reversed")
        assert "silhouette" in frame["losses"] and "difference" not in frame["losses"]
    entities = {c.entity_path for c in RrdReader(out / "recording.rrd").stream().to_chunks()}
    assert {"/world/camera/image/subframe_mask/track_00", "/run/masks"} <= entities


def test_process_without_weights_says_once_that_it_falls_back(
    clip: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    assert main(["process", str(clip), "--out", str(out), *THREE]) == 0
    (line,) = _mask_lines(capsys.readouterr().err)
    assert "difference image (L_D)" in line and "no DeFMO weights in" in line
    summary = json.loads((out / "summary.json").read_text())
    assert summary["masks"]["source"] == "diff"
    assert {f["masks"] for f in summary["frames"] if f["status"] == "fitted"} == {"diff"}
    entities = {c.entity_path for c in RrdReader(out / "recording.rrd").stream().to_chunks()}
    assert "/world/camera/image/subframe_mask/track_00" not in entities


def test_a_run_does_not_resume_with_other_masks(
    clip: Path, defmo_weights: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    assert main(["process", str(clip), "--out", str(out), "--masks", "diff", *THREE]) == 0
    marker = json.loads((out / "run.json").read_text())
    (out / "run.json").write_text(json.dumps(marker | {"finished": False}))  # as if it had stopped before the end
    (out / "summary.json").unlink()
    assert main(["process", str(clip), "--out", str(out), "--defmo-weights", str(defmo_weights), *THREE]) == 2
    assert "mask source" in capsys.readouterr().err


def test_fit_with_defmo_weights_writes_the_masks_it_used(clip: Path, defmo_weights: Path, tmp_path: Path) -> None:
    config = demo_config(load_config("fast"))
    frames = demo_clip(config)
    image, background = tmp_path / "im.png", tmp_path / "bgr.png"
    cv2.imwrite(str(image), frames.frames[0][..., ::-1])
    cv2.imwrite(str(background), frames.scene.background[..., ::-1])
    out = tmp_path / "fit"
    args = ["fit", "--image", str(image), "--background", str(background), "--out", str(out), "--quiet"]
    assert main([*args, "--defmo-weights", str(defmo_weights), *QUICK]) == 0
    record = json.loads((out / "fit.json").read_text())
    assert record["masks"] == "defmo" and "silhouette" in record["losses"]
    width, height = record["crop_size"]
    steps = config.render.time_steps
    assert cv2.imread(str(out / "masks.png")).shape[:2] == (height, steps * width)  # a strip, as tsr.png


@pytest.mark.filterwarnings("ignore:Transient failure")
def test_mask_errors_are_one_line_and_leave_no_output(
    clip: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "run"
    assert main(["process", str(clip), "--out", str(out), "--defmo-weights", str(tmp_path), *QUICK]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sfb-video: error: --defmo-weights") and "\n" not in err
    for part, name in defmo.WEIGHT_FILES.items():
        monkeypatch.setitem(defmo.urls, f"defmo_{part}", f"http://127.0.0.1:9/{name}")
    assert main(["process", str(clip), "--out", str(out), "--masks", "defmo", *QUICK]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("sfb-video: error: cannot download the DeFMO weights")
    assert not out.exists()
