"""Ghosts in the TSR sub-frames: how much of the input's blurred streak a composite leaves.

    python -m benchmarks.composite [--frames 6] [--config fast] [--set KEY=VALUE ...]

Each scenario of :mod:`benchmarks.detect` that has one object (a generated 320x240 clip with
ground truth) is written as a video and processed by the pipeline (single-frame fits, the
difference mask); every fitted frame is then rendered into its sub-frames as ``tsr.mp4`` is
(:func:`stages.export.render_frame`) and compared with the true sub-frames. The ghost of a
sub-frame is the energy of |TSR sub-frame - true sub-frame| over the pixels the object's streak
covers in the input frame but where the true object is not at that sub-frame's time: the
input's streak left there shows as a ghost. Reported as a share of the same energy of the input
frame itself (1: the streak left whole; a misplaced rendered object counts too), and in grey
levels per pixel (mean |difference| over RGB, 0-255).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import tempfile
from pathlib import Path

import cv2
import numpy as np
import torch

from benchmarks.detect import BASE, SCENARIOS
from sfb_video.config import Config, load_config
from sfb_video.demo import write_clip_video
from sfb_video.results import load_result
from sfb_video.run_folder import frame_path
from sfb_video.synth import ClipSpec, generate_clip
from stages.background import with_backgrounds
from stages.export import render_frame
from stages.process import ProcessOptions, process_clip


def ghost_scenario(spec: ClipSpec, config: Config) -> dict[str, float]:
    """Process the clip ``spec`` makes and measure the ghosts of its fitted frames' sub-frames."""
    clip = generate_clip(spec)
    config = dataclasses.replace(
        config,
        video=dataclasses.replace(config.video, exposure_fraction=spec.exposure_fraction, tsr=spec.num_subframes),
    )
    n = spec.num_subframes
    left = whole = 0.0
    pixels = fitted = 0
    kernel = np.ones((5, 5), np.uint8)
    with tempfile.TemporaryDirectory() as tmp:
        video, out = Path(tmp) / "clip.mp4", Path(tmp) / "run"
        write_clip_video(clip, video)
        process_clip(ProcessOptions(video=video, out=out, masks="diff"), config, torch.device("cpu"), quiet=True)
        for frame in with_backgrounds(video, config.video, len(clip.frames)):
            path, truth = frame_path(out, frame.index), clip.truth[frame.index]
            if not path.is_file() or not truth.present:
                continue
            fitted += 1
            subframes = render_frame(frame, load_result(path), clip.camera, n, config).subframes
            streak = cv2.dilate((truth.masks.max(0) > 0.02).astype(np.uint8), kernel).astype(bool)
            for j in range(n):
                objects = cv2.dilate((truth.masks[j] > 0).astype(np.uint8), kernel).astype(bool)
                where = torch.from_numpy(streak & ~objects)
                true = torch.from_numpy(truth.subframes[j]).permute(2, 0, 1).float()
                left += float(((subframes[j].float() - true).abs().sum(0) * where).sum())
                whole += float(((frame.pixels.float() - true).abs().sum(0) * where).sum())
                pixels += int(where.sum())
    return {
        "frames": len(clip.frames),
        "fitted": fitted,
        "share": left / max(whole, 1e-9),
        "grey": left / max(3 * pixels, 1),
        "input_grey": whole / max(3 * pixels, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--config", default="fast")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    config = load_config(args.config, ["joint.enabled=false", *args.set])
    rows = []
    for name, fields in SCENARIOS.items():
        if "second" in fields:
            continue
        spec = dataclasses.replace(BASE, **({"num_frames": args.frames} | fields))
        rows.append((name, ghost_scenario(spec, config)))
    print(f"preset {args.config} joint.enabled=false {' '.join(args.set)}; 320x240 clips\n")
    print("| scenario | frames | fitted | ghost (share of the input's) | ghost, grey levels | input, grey levels |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, r in rows:
        print(
            f"| {name} | {r['frames']} | {r['fitted']} | {r['share']:.3f} | {r['grey']:.2f} | {r['input_grey']:.2f} |"
        )
    mean = {k: statistics.fmean(r[k] for _, r in rows) for k in ("share", "grey", "input_grey")}
    print(f"| **mean** | | | {mean['share']:.3f} | {mean['grey']:.2f} | {mean['input_grey']:.2f} |")


if __name__ == "__main__":
    main()
