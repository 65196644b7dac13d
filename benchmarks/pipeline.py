"""The whole pipeline on one fixed clip: frames per second, seconds per stage, peak memory, the recording's size.

    python -m benchmarks.pipeline [--size 640x480] [--config default] [--set KEY=VALUE ...] [--device cpu]

The clip (generated on each run, bit-identical every time): 30 frames, a ball flying through
frames 0-13 and gone after, then a box through frames 16-29, over one photo: two tracks. A
``--size`` wider than 640 px (1920x1080, 3840x2160) is generated 640 px wide at its aspect and
scaled up, so that the objects cover the same share of the frame as at 640 px.
It is written as H.264 and processed by ``sfb-video process``'s own code with the difference
masks, in a fresh child process, which reports its wall time, the seconds of each stage
(:mod:`sfb_video.timing`: each stage's own time, those nested in it taken out) and its peak
resident memory (the whole process: Python, torch, numba, rerun, the encoder).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from benchmarks.memory import peak_mb
from sfb_video import timing
from sfb_video.config import load_config
from sfb_video.stages.process import ProcessOptions, process_clip
from sfb_video.synth import ClipSpec, generate_clip
from sfb_video.video import VideoWriter

FRAMES = 30
STAGES = ("read", "register", "background", "detect", "fit", "joint", "export", "recording")
JOINT = ("path", "shape trial", "spin search", "steps", "refine")
"""The joint fit's parts (:mod:`sfb_video.fitting.window`), shown under it; "joint" alone is the
rest of it (crops, scoring the windows, saving)."""
GENERATED_WIDTH = 640
_COMMON = {"num_frames": FRAMES, "exposure_fraction": 0.8, "speed_range": (1.2, 1.5)}


def clip_specs(width: int = 640, height: int = 480) -> tuple[ClipSpec, ClipSpec]:
    """The ball (frames 0-13) and the box (16-29) at ``width`` x ``height``. One seed: the same
    photo and the same noise in both, so each frame is taken whole from the clip whose object it
    shows."""
    size = {"width": width, "height": height, **_COMMON}
    ball = ClipSpec(shape="ball", absent_frames=tuple(range(14, FRAMES)), size_px_range=(20.0, 24.0), **size)
    box = ClipSpec(shape="box", absent_frames=tuple(range(16)), size_px_range=(22.0, 26.0), **size)
    return ball, box


def write_clip(path: Path, size: tuple[int, int] = (640, 480)) -> None:
    """The benchmark's clip as H.264 at 30 fps, ``size`` (width, height); a size wider than
    :data:`GENERATED_WIDTH` is generated that wide at its aspect and scaled up."""
    width, height = size
    small = (min(width, GENERATED_WIDTH), round(min(width, GENERATED_WIDTH) * height / width))
    ball, box = (generate_clip(spec) for spec in clip_specs(*small))
    with VideoWriter(path, 30.0, width, height) as video:
        for k in range(FRAMES):
            frame = box.frames[k] if k in box.spec.present_frames else ball.frames[k]
            if small != size:
                frame = cv2.resize(frame, size, interpolation=cv2.INTER_LINEAR)
            video.write(np.ascontiguousarray(frame))


def frame_size(text: str) -> tuple[int, int]:
    """``WIDTHxHEIGHT`` -> (width, height): even (H.264's 4:2:0), and at least 64 px each way
    where it is generated (:func:`write_clip`)."""
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT (e.g. 1920x1080)") from None
    if width % 2 or height % 2:
        raise argparse.ArgumentTypeError(f"{text}: H.264 takes even sizes")
    if min(width, GENERATED_WIDTH) < 64 or round(min(width, GENERATED_WIDTH) * height / width) < 64:
        raise argparse.ArgumentTypeError(f"{text}: too small or too wide to generate (at least 64 px each way)")
    return width, height


def measure(video: Path, preset: str, overrides: list[str], device: str) -> dict:
    """Process ``video`` in this process: wall time, stage seconds, peak memory, tracks found."""
    config = load_config(preset, overrides)
    timing.reset()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        options = ProcessOptions(video=video, out=Path(tmp) / "run", masks="diff")
        summary = process_clip(options, config, torch.device(device), quiet=True)
        seconds = time.perf_counter() - start
        recording_mb = (options.out / "recording.rrd").stat().st_size / 2**20
    tracks: dict[int, list[int]] = {}
    for frame in summary["frames"]:
        if frame.get("track") is not None:
            tracks.setdefault(frame["track"], []).append(frame["index"])
    return {
        "seconds": seconds,
        "stages": timing.stage_seconds(),
        "peak_mb": peak_mb(),
        "recording_mb": recording_mb,
        "fitted": summary["frames_fitted"],
        "tracks": [f"{frames[0]}-{frames[-1]}" for frames in tracks.values()],
        "windows": len(summary["joint"]["windows"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=frame_size, default=(640, 480), help="WIDTHxHEIGHT (default 640x480)")
    parser.add_argument("--config", default="default")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.device == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: no CUDA GPU is available to torch here")
    if args.child:
        print(json.dumps(measure(Path(args.child), args.config, args.set, args.device)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        video = Path(tmp) / "two_tracks.mp4"
        write_clip(video, args.size)
        command = [sys.executable, "-m", "benchmarks.pipeline", "--child", str(video), "--config", args.config]
        command += ["--device", args.device, *(a for s in args.set for a in ("--set", s))]
        done = subprocess.run(command, check=True, capture_output=True, text=True)
    row = json.loads(done.stdout.splitlines()[-1])
    total, stages = row["seconds"], row["stages"]
    width, height = args.size
    print(
        f"{args.config} preset {' '.join(args.set)} on {args.device}; "
        f"{FRAMES} frames of {width}x{height}, a ball then a box"
    )
    print(
        f"fitted {row['fitted']} frames in {len(row['tracks'])} tracks (frames {', '.join(row['tracks'])}), "
        f"{row['windows']} joint windows; "
        f"peak memory {row['peak_mb']:.0f} MB; recording.rrd {row['recording_mb']:.1f} MB, "
        f"{row['recording_mb'] / FRAMES:.2f} MB a frame\n"
    )
    print("| stage | seconds | share | s / frame |")
    print("|---|---:|---:|---:|")
    other = total - sum(stages.values())
    rows = [(s, stages.get(s, 0.0)) for s in STAGES]
    at = STAGES.index("joint") + 1
    rows[at:at] = [(f"joint: {p}", stages.get(f"joint: {p}", 0.0)) for p in JOINT]
    for name, seconds in [*rows, ("other (probe, run folder, saving)", other)]:
        print(f"| {name} | {seconds:.1f} | {seconds / total:.0%} | {seconds / FRAMES:.2f} |")
    print(f"| **all** | {total:.1f} | 100% | {total / FRAMES:.2f} |")
    print(f"\n{FRAMES / total:.2f} frames per second overall")


if __name__ == "__main__":
    main()
