"""The pipeline end to end on the real clips in ../shared/data/clips (fast preset).

These clips have no ground truth; the tests check that every clip runs through, that the object
found in circle_fast.avi is the swung ball and not the moving arm beside it, and that the fits
explain the frames they were made for.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from sfb_video.config import load_config
from stages.background import with_backgrounds
from stages.process import ProcessOptions, process_clip

CLIPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "clips"
pytestmark = pytest.mark.skipif(not CLIPS.is_dir(), reason="needs ../shared/data/clips beside the checkout")


def _run(name: str, root: Path) -> dict:
    out = root / name
    return process_clip(
        ProcessOptions(video=CLIPS / f"{name}.avi", out=out), load_config("fast"), torch.device("cpu"), quiet=True
    )


@pytest.mark.parametrize("name", ["falling_pen", "floorball_res"])
def test_pipeline_runs_end_to_end(name: str, tmp_path: Path) -> None:
    summary = _run(name, tmp_path)
    assert summary["frames_read"] == {"falling_pen": 8, "floorball_res": 76}[name]
    assert summary["frames_fitted"] >= {"falling_pen": 4, "floorball_res": 8}[name]
    for name_ in ("tsr.mp4", "trajectory.csv", "recording.rrd", "summary.json"):
        assert (tmp_path / name / name_).is_file()
    losses = sorted(f["losses"]["image"] for f in summary["frames"] if f["status"] == "fitted")
    # Median L_I measured 0.081-0.107 on the pen over rounding-level changes to the step (the
    # tracking then picks other fragments of the thin pen: issue 19), floorball 0.075-0.101.
    assert losses[len(losses) // 2] < 0.12


def test_circle_fast_finds_the_ball_not_the_arm(tmp_path: Path) -> None:
    summary = _run("circle_fast", tmp_path)
    frames = {f["index"]: f for f in summary["frames"]}
    assert summary["frames_read"] == 96
    # The ball flies through the whole clip (measured: all 96 frames fitted).
    assert summary["frames_fitted"] >= 90
    config = load_config("fast")
    arm_like = []
    for frame in with_backgrounds(CLIPS / "circle_fast.avi", config.video, 96):
        record = frames[frame.index]
        if record["status"] != "fitted":
            continue
        x, y, w, h = record["box"]
        image, background = frame.image[:, y : y + h, x : x + w], frame.background[:, y : y + h, x : x + w]
        changed = (image - background).norm(dim=0) > config.detect.threshold
        # The ball is yellow-green, the arm skin: where the box differs from the background,
        # green exceeds red for the ball and falls below it for the arm.
        if float(image[1][changed].mean() - image[0][changed].mean()) <= 0:
            arm_like.append(frame.index)
    # Measured: 5 of 96. In frames 4, 36, 60 and 73 the ball is faint or crosses the fist, and a
    # shred of the arm left by the slow-mover test lay nearer the prediction; frame 67 is
    # borderline (green - red = -0.01).
    assert len(arm_like) <= 6
    fitted = [f for f in frames.values() if f["status"] == "fitted"]
    single = sorted(f.get("losses_before", f["losses"])["image"] for f in fitted)
    assert single[len(single) // 2] < 0.06  # measured median L_I 0.052
    # The joint fit explains each frame with a shared shape and one path: measured median 0.071.
    joint = sorted(f["losses"]["image"] for f in fitted)
    assert joint[len(joint) // 2] < 0.08
