"""The pipeline end to end on the real clips in ../shared/data/clips (fast preset).

These clips have no ground truth; the tests check that every clip runs through, that the object
found in circle_fast.avi is the swung ball and not the moving arm beside it or its shadow, and that the fits
explain the frames they were made for.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from benchmarks.detect import aerobie_clip
from sfb_video.config import load_config
from sfb_video.evaluation.objects import box_iou
from sfb_video.stages.background import running_median, with_backgrounds
from sfb_video.stages.detect import choose_blob, frame_blobs, moving_mask
from sfb_video.stages.process import ProcessOptions, process_clip
from sfb_video.stages.track import with_neighbours
from sfb_video.stages.types import Frame

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
    # How much of each frame's difference from its background the fit explains around the object
    # (1: all, 0: no better than the background alone); unlike L_I it does not grow with the crop.
    # Measured medians: pen 0.26 (its streak is found only in part: long and slow for its size),
    # floorball 0.18 (an overlay drawn over the clip crosses the ball's streaks).
    explained = sorted(f["explained"] for f in summary["frames"] if f["status"] == "fitted")
    assert explained[len(explained) // 2] > 0.1


def test_circle_fast_finds_the_ball_not_the_arm(tmp_path: Path) -> None:
    # Every fast mover is tracked (the default): the arm's fast fringes and the ball's shadow on
    # the wall start no track beside the ball's.
    summary = _run("circle_fast", tmp_path)
    assert summary["frames_read"] == 96
    fitted = [f for f in summary["frames"] if f["status"] == "fitted"]
    lengths = {t["track"]: len(t["frames"]) for t in summary["tracks"]}
    # The ball flies through the whole clip. Measured: one track, all 96 frames, none dropped as
    # too short; before the arm's fringes and the shadow were told from objects, 27 tracks kept
    # (the ball's cut into 13 of them) and more dropped.
    seen = {f["track"] for f in summary["frames"] if f["status"] in ("fitted", "dropped")}
    assert max(lengths.values()) >= 90 and len(lengths) <= 2 and len(seen) <= 3, (lengths, seen)
    config = load_config("fast")
    arm_like = []
    records = {}
    for f in fitted:
        records.setdefault(f["index"], []).append(f)
    for frame in with_backgrounds(CLIPS / "circle_fast.avi", config.video, 96):
        for record in records.get(frame.index, []):
            x, y, w, h = record["box"]
            image, background = frame.image[:, y : y + h, x : x + w], frame.background[:, y : y + h, x : x + w]
            changed = (image - background).norm(dim=0) > config.detect.threshold
            # The ball is yellow-green, the arm skin: where the box differs from the background,
            # green exceeds red for the ball and falls below it for the arm.
            if float(image[1][changed].mean() - image[0][changed].mean()) <= 0:
                arm_like.append((frame.index, record["track"]))
    # Measured: 4 of 96 (49, 60, 73, 83), where the blob is the ball's streak (its own pixels
    # green: g - r 0.00 to +0.04) passing the fist, which lies inside its box. Was 5 (and 50, a
    # shadow on the wall nearer a poor prediction) before shades weighed less, 6 (and 39, a shred
    # of the arm) before blobs were scored by the track's colour, 9 with a prediction that went
    # straight on.
    assert len(arm_like) <= 5, arm_like
    explained = sorted(f["explained"] for f in fitted)
    assert explained[len(explained) // 2] > 0.35  # measured 0.45: the straight path of one
    # exposure cannot follow the curved streak of the swing
    # Cold retries where the warm fit missed: measured 29 with the detector that cut streaks at
    # a neighbour's difference, 20 with the whole streak found, 19 with the turning prediction (19 with
    # colour scoring too, 18 with shades weighing less).
    assert summary["cold_starts"] <= 25


def test_a_large_faint_disc_is_detected_whole_in_every_frame() -> None:
    # The real aerobie (a flying ring, grey on grey behind a fence) pasted along a path, 45 px a
    # frame: its ~80 px streaks overlap from frame to frame, large and slow for its size.
    pixels, boxes = aerobie_clip(8)
    config = load_config("fast")
    frames = (Frame(k, torch.from_numpy(np.ascontiguousarray(f.transpose(2, 0, 1)))) for k, f in enumerate(pixels))
    backgrounds = running_median(frames, config.video.background_window)
    for frame, mask, neighbours in with_neighbours(backgrounds, config.detect):
        found = choose_blob(frame.index, moving_mask(mask, neighbours, config.detect), None, config.detect)
        # The true box holds every pixel 0.02 away from the background; measured IoU 0.73-0.82.
        assert found is not None and box_iou(found.box, boxes[frame.index]) > 0.65, frame.index


@pytest.mark.parametrize("name", ["circle_fast.avi", "falling_pen.avi", "floorball_res.avi", "falling_two.mp4"])
def test_a_real_still_camera_is_found_still(name: str) -> None:
    # With camera.motion auto, a still clip is not warped: its outputs stay as they were.
    from sfb_video.config import CameraConfig
    from sfb_video.registration import register_frames
    from sfb_video.stages.read import read_frames
    from sfb_video.stages.register import camera_motion

    assert camera_motion(CLIPS / name, range(0, 40), CameraConfig()) is None
    motion = register_frames(((f.index, f.image) for f in read_frames(CLIPS / name, range(0, 40))), CameraConfig())
    assert not motion.failed


def test_objects_falling_side_by_side_are_found_apart() -> None:
    # falling_three.mp4, frames 10 and 11: a red end, a pale end and a grey object fall 7-12 px
    # apart, and their faint fringes join them into one region of the difference mask. Each is
    # a blob of its own (the boxes of their strong pixels, measured).
    config = load_config("fast")
    cores = {
        10: [(374, 18, 14, 39), (334, 43, 16, 34), (359, 65, 14, 40)],
        11: [(369, 68, 18, 49), (330, 101, 16, 43), (356, 134, 15, 50)],
    }
    frames = with_backgrounds(CLIPS / "falling_three.mp4", config.video, 12)
    for frame, mask, neighbours in with_neighbours(frames, config.detect):
        if frame.index not in cores:
            continue
        moving = moving_mask(mask, neighbours, config.detect)
        found = frame_blobs(moving, config.detect, (frame.pixels, frame.background_pixels), mask)
        owners = []
        for x, y, w, h in cores[frame.index]:
            labels, counts = np.unique(found.labels[y : y + h, x : x + w], return_counts=True)
            owners.append(int(labels[labels > 0][np.argmax(counts[labels > 0])]))
            assert found.own_object(owners[-1])
        assert len(set(owners)) == 3, (frame.index, owners)
