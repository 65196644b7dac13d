"""The camera's registration: its error on generated moves, its cost, and the real clips still.

    python -m benchmarks.registration [--frames 24]

Generated: a 640x480 clip of a fast ball over a photo, shaken (up to 6 px and 1 degree a frame)
and panning (2-5 px a frame), registered to its first frame (:mod:`sfb_video.registration`):
the largest corner error against the true transform, median and worst over frames, and the
median seconds a frame. Real: every clip of ../shared/data/clips (a still camera): whether it
is found still, and its largest corner shift. Targets (issue 33): at most 1 px, at most about
0.05 s a frame at 640x480, the real clips still.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from sfb_video.config import CameraConfig
from sfb_video.registration import corner_shift, features, match, register_frames
from sfb_video.synth import ClipSpec, generate_clip
from sfb_video.synth.shake import shake_frames, shake_transforms, true_to_reference
from sfb_video.video import VideoReader

CLIPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "clips"
SIZE = (640, 480)


def _tensors(frames: np.ndarray) -> list[tuple[int, torch.Tensor]]:
    return [(k, torch.from_numpy(np.ascontiguousarray(f)).permute(2, 0, 1)) for k, f in enumerate(frames)]


def generated(frames: int, camera: str, config: CameraConfig) -> dict[str, float]:
    spec = ClipSpec(shape="ball", seed=4, num_frames=8, width=SIZE[0], height=SIZE[1], background="coffee")
    # The ball's 8 frames over again: a ball stays in view only so long.
    ball = generate_clip(spec).frames
    still = np.stack([ball[k % 8] for k in range(frames)])
    if camera == "shaken":
        moves = shake_transforms(frames, SIZE, 1, max_shift_px=6.0, max_turn_deg=1.0)
    else:
        moves = shake_transforms(frames, SIZE, 1, max_shift_px=1.0, max_turn_deg=0.2, pan_px=3.5)
    tensors = _tensors(shake_frames(still, moves))
    start = time.perf_counter()
    motion = register_frames(tensors, config)
    seconds = (time.perf_counter() - start) / frames
    truth = true_to_reference(moves)
    errors = [
        corner_shift(r.to_reference @ np.linalg.inv(truth[k]), SIZE)
        for k, r in motion.frames.items()
        if r.to_reference is not None and r.segment == 0
    ]
    return {
        "median": statistics.median(errors),
        "worst": max(errors),
        "failed": len(motion.failed),
        "references": len({r.segment for r in motion.frames.values()}),
        "seconds": seconds,
    }


def frame_seconds(frames: int, config: CameraConfig) -> float:
    """The median seconds of one frame's features and match at 640x480."""
    spec = ClipSpec(shape="ball", seed=4, num_frames=2, width=SIZE[0], height=SIZE[1], background="coffee")
    a, b = (t for _, t in _tensors(generate_clip(spec).frames))
    reference = features(a, config.features)
    times = []
    for _ in range(frames):
        start = time.perf_counter()
        match(features(b, config.features), reference, config.min_inliers)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def real(config: CameraConfig) -> list[tuple[str, bool, float, int]]:
    rows = []
    for path in sorted(CLIPS.glob("*")):
        with VideoReader(path) as reader:
            images = [(k, f) for k, f in enumerate(reader)]
        motion = register_frames(images, config)
        size = (images[0][1].shape[2], images[0][1].shape[1])
        shift = max(corner_shift(r.to_reference, size) for r in motion.frames.values() if r.to_reference is not None)
        rows.append((path.name, motion.moving, shift, len(images)))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=24)
    args = parser.parse_args()
    config = CameraConfig()
    print(f"one frame's features and match at 640x480: {frame_seconds(args.frames, config):.3f} s (median)\n")
    print("| generated 640x480 | frames | corner error median / worst (px) | failed | references | s / frame |")
    print("|---|---:|---:|---:|---:|---:|")
    for camera in ("shaken", "panning"):
        r = generated(args.frames, camera, config)
        print(
            f"| {camera} | {args.frames} | {r['median']:.2f} / {r['worst']:.2f} | {r['failed']} | "
            f"{r['references']} | {r['seconds']:.3f} |"
        )
    if CLIPS.is_dir():
        print("\n| real clip | frames | found still | largest corner shift (px) |\n|---|---:|---|---:|")
        for name, moving, shift, frames in real(config):
            print(f"| {name} | {frames} | {'yes' if not moving else 'NO'} | {shift:.2f} |")


if __name__ == "__main__":
    main()
