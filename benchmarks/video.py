"""Warm start against cold starts on a generated clip: time and accuracy per frame, peak memory.

    python -m benchmarks.video [--frames 8] [--config default] [--set KEY=VALUE ...] [--device cpu]

Generates a clip with ground truth (a textured ball, 320x240), processes it twice with the full
pipeline, once warm-starting every frame of the track from the previous one (the default) and
once cold-starting every frame, and prints one row per frame for each: the fit's time, TIoU,
PSNR (FMO benchmark definitions, scored in the pipeline's own time direction) and translation
error in object sizes, then the means of warm frames against cold ones. Each variant runs in a
child process, which reports its own peak resident memory.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

from sfb_video.config import load_config
from sfb_video.demo import demo_clip, demo_config, score_run, write_clip_video
from sfb_video.results import load_results
from sfb_video.stages.process import ProcessOptions, process_clip

# Single-frame fits only: this compares the two ways of starting them (the joint refit is
# measured by `sfb-video eval --mode joint`).
VARIANTS = {
    "warm": ["video.warm_start=true", "joint.enabled=false"],
    "cold": ["video.warm_start=false", "joint.enabled=false"],
}


def run_variant(preset: str, overrides: list[str], device: str = "cpu") -> dict:
    """Process the clip in a temporary folder; per-frame rows and this process's peak memory."""
    config = demo_config(load_config(preset, overrides))
    clip = demo_clip(config)
    with tempfile.TemporaryDirectory() as tmp:
        video, out = Path(tmp) / "clip.mp4", Path(tmp) / "run"
        write_clip_video(clip, video)
        # The difference image, as in the README's table, whatever DeFMO weights this machine has.
        options = ProcessOptions(video=video, out=out, masks="diff")
        process_clip(options, config, torch.device(device), quiet=True)
        results = {k.index: r for k, r in load_results(out).items()}  # one object
        scores = score_run(out, clip, config)
    rows = [
        {
            "frame": i,
            "start": results[i].start,
            "seconds": results[i].seconds,
            "iterations": len(results[i].curve),
            "tiou": s.tiou,
            "psnr": s.psnr,
            "translation_err": s.translation_err,
        }
        for i, s in sorted(scores.items())
    ]
    return {"rows": rows, "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _mean(rows: list[dict], key: str) -> float:
    return statistics.mean(r[key] for r in rows) if rows else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="default")
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--child", choices=list(VARIANTS), help=argparse.SUPPRESS)
    args = parser.parse_args()
    overrides = [*args.set, f"demo.frames={args.frames}"]
    if args.child:
        print(json.dumps(run_variant(args.config, [*overrides, *VARIANTS[args.child]], args.device)))
        return
    base = [sys.executable, "-m", "benchmarks.video", "--config", args.config, "--frames", str(args.frames)]
    base += ["--device", args.device]
    base += [a for s in args.set for a in ("--set", s)]
    outcome = {}
    for name in VARIANTS:
        done = subprocess.run([*base, "--child", name], capture_output=True, text=True, check=True)
        outcome[name] = json.loads(done.stdout.strip().splitlines()[-1])
    print(f"preset {args.config} {' '.join(overrides)} on {args.device}; one clip, each variant in its own process\n")
    print("| variant | frame | start | s | steps | TIoU | PSNR | transl. err |")
    print("|---|---:|---|---:|---:|---:|---:|---:|")
    for name, data in outcome.items():
        for r in data["rows"]:
            print(
                f"| {name} | {r['frame']} | {r['start']} | {r['seconds']:.2f} | {r['iterations']} | "
                f"{r['tiou']:.3f} | {r['psnr']:.2f} | {r['translation_err']:.2f} |"
            )
    print("\n| frames | n | median s | mean TIoU | mean PSNR | mean transl. err | peak memory (MB) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    warm_rows = [r for r in outcome["warm"]["rows"] if r["start"] == "warm"]
    cold_rows = outcome["cold"]["rows"]
    for label, rows, peak in (
        ("warm-started (warm variant)", warm_rows, outcome["warm"]["peak_mb"]),
        ("cold-started (cold variant)", cold_rows, outcome["cold"]["peak_mb"]),
    ):
        median = statistics.median(r["seconds"] for r in rows) if rows else float("nan")
        print(
            f"| {label} | {len(rows)} | {median:.2f} | {_mean(rows, 'tiou'):.3f} | {_mean(rows, 'psnr'):.2f} | "
            f"{_mean(rows, 'translation_err'):.2f} | {peak:.0f} |"
        )


if __name__ == "__main__":
    main()
