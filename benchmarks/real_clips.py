"""Real footage, no truth: does the recovered motion explain the streaks, and do frames join?

    python -m benchmarks.real_clips [--frames 8] [--config default] [--set KEY=VALUE ...] [--out DIR]

Processes the first ``--frames`` frames of each clip in ``../shared/data/clips`` once, with the
joint fit on, and reads both results from the run folder: every frame's single-frame fit
("before", ``frames/``) and what the outputs show ("after", the joint fit where it covers the
frame). ``--out`` keeps the run folders there (one per clip) to look at. Per clip it prints, as
medians over fitted frames:

- travel / streak: the object's travel within the exposure in the image (|u(end) - u(start)|)
  over the streak's length, estimated from the detection box as its longer side minus its
  shorter side (a round object's streak is its length plus one diameter by one diameter);
  near 1 when the motion explains the streak, near 0 for "a long object that barely moves";
- join gap: for consecutive fitted frames of one track, the distance in pixels between where
  frame k+1's exposure starts and where frame k's motion, continued at constant velocity
  across the gap between exposures, puts it; small when the frames' trajectories join.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import torch

from sfb_video.config import load_config
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.motion import Motion, continue_motion
from sfb_video.results import FrameKey, FrameResult, load_results
from sfb_video.stages.process import ProcessOptions, clip_camera, process_clip
from sfb_video.stages.read import probe
from sfb_video.stages.run_results import RunResults, read_run

CLIPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "clips"


def _travel_px(motion: Motion, camera: PinholeCamera) -> float:
    uv = camera.project(torch.stack((motion.x0, motion.x0 + motion.dx)))[0]
    return float((uv[1] - uv[0]).norm())


def _join_px(a: Motion, b: Motion, frames: int, exposure: float, camera: PinholeCamera) -> float:
    predicted = continue_motion(a, frames, exposure).x0
    uv = camera.project(torch.stack((predicted, b.x0)))[0]
    return float((uv[1] - uv[0]).norm())


def measure(results: dict[FrameKey, FrameResult], boxes: dict, exposure: float, camera: PinholeCamera) -> dict:
    """Median travel / streak and join gap (px) of a run's results, by (frame, track)."""
    ratios, gaps = [], []
    for key, r in sorted(results.items()):
        i, t = key.index, key.track
        _, _, w, h = boxes[key]
        streak = max(w, h) - min(w, h)
        if streak > 0:
            ratios.append(_travel_px(r.state.motion, camera) / streak)
        if (later := FrameKey(i + 1, t)) in results:
            # The exposure fraction the result was fitted with: the joint fit's own where learnt.
            gaps.append(_join_px(r.state.motion, results[later].state.motion, 1, exposure, camera))
    return {
        "travel_ratio": statistics.median(ratios) if ratios else float("nan"),
        "join_px": statistics.median(gaps) if gaps else float("nan"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--config", default="default")
    parser.add_argument("--set", nargs="*", default=[])
    parser.add_argument("--out", type=Path, help="keep the run folders here")
    args = parser.parse_args()
    torch.set_num_threads(2)
    config = load_config(args.config, args.set)
    print("| clip | frames fitted | travel / streak before | after | join gap (px) before | after | joint e | s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for clip in sorted(CLIPS.glob("*.avi")):
        with tempfile.TemporaryDirectory() as tmp:
            out = (args.out or Path(tmp)) / clip.stem
            start = time.perf_counter()
            options = ProcessOptions(video=clip, out=out, frames=f"0:{args.frames}", masks="diff")
            summary = process_clip(options, config, torch.device("cpu"), quiet=True)
            seconds = time.perf_counter() - start
            _, statuses = read_run(out)
            camera = clip_camera(probe(clip, config.video), config.camera, None)
            boxes = {s.key: s.box for s in statuses}
            joint_e = summary["joint"]["exposure_fraction"] or config.video.exposure_fraction
            before = measure(load_results(out), boxes, config.video.exposure_fraction, camera)
            after = measure(RunResults.of_run(out, config.joint).final(), boxes, joint_e, camera)
        print(
            f"| {clip.name} | {summary['frames_fitted']} | {before['travel_ratio']:.2f} | {after['travel_ratio']:.2f} "
            f"| {before['join_px']:.1f} | {after['join_px']:.1f} | {joint_e:.2f} | {seconds:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
