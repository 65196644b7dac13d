"""Many clips at once: one process one after another, against Ray with one and two workers.

    python -m benchmarks.batch [--clips 6] [--frames 8] [--repeats 3] [--config fast] [--set KEY=VALUE ...]

Six short generated clips (the demo's ball, 8 frames of 320x240, a different seed each) go through
``sfb-video batch``'s own code three times in one run, each into a fresh folder: one after
another in this process, then on a local Ray with one worker and with two (each clip one CPU,
one torch thread). Clips per minute, the speed-up over one worker, and Ray's overhead per clip
(one worker's wall time less the single process's, per clip); and the clips per minute once each
worker has finished its first clip, which is what a long batch runs at. Targets (issue 20): two workers
>= 1.6x one worker on a 2-core CPU, overhead < 2 s per clip. Run it on a quiet machine: two
torch processes on two cores slow each other down many times.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import tempfile
import time
from pathlib import Path

from sfb_video.batch import DONE, BatchPlan, plan_jobs, run_batch
from sfb_video.cluster import Resources, connected
from sfb_video.config import Config, load_config
from sfb_video.demo import demo_clip, demo_config, write_clip_video
from sfb_video.stages.process import ClipOptions


def write_clips(folder: Path, count: int, frames: int, config: Config, small: bool = False) -> list[Path]:
    """``count`` clips of the demo's object in ``folder``, ``frames`` frames each, a different
    path each: the demo's size (320x240), or 192x144 with a smaller object (``small``)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    size = {"width": 192, "height": 144, "size_px": (18.0, 20.0)} if small else {}
    for k in range(count):
        demo = dataclasses.replace(config.demo, frames=frames, seed=k, **size)
        path = folder / f"clip{k}.mp4"
        write_clip_video(demo_clip(dataclasses.replace(config, demo=demo)), path)
        paths.append(path)
    return paths


def timed_batch(clips: list[Path], out: Path, config: Config, use_ray: bool, workers: int) -> tuple[float, float]:
    """Seconds to run the clips into ``out`` (every clip must finish), and clips per minute
    once each worker has finished its first clip (what a long batch runs at: Ray's start, a
    worker's start and its first clip's imports are behind it)."""
    jobs = plan_jobs(clips, out)
    plan = BatchPlan(jobs, ClipOptions(masks="diff"), config, out, "cpu", Resources(1), 0, None, use_ray, workers)
    started = time.perf_counter()
    ends: list[float] = []
    rows = run_batch(plan, on_row=lambda _, __: ends.append(time.perf_counter()))
    seconds = time.perf_counter() - started
    failed = [r for r in rows if r.status != DONE]
    if failed:
        raise SystemExit(f"clip {failed[0].clip} did not finish: {failed[0].status} {failed[0].error}")
    steady = 60 * (len(ends) - workers) / (ends[-1] - ends[workers - 1]) if len(ends) > workers else math.nan
    return seconds, steady


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=6)
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--config", default="fast")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    config = demo_config(load_config(args.config, args.set))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        clips = write_clips(root / "clips", args.clips, args.frames, config)
        names = ("one process, one after another", "Ray, 1 worker", "Ray, 2 workers")
        runs: dict[str, list[tuple[float, float]]] = {name: [] for name in names}
        ray_starts = []
        for k in range(args.repeats):  # interleaved, so that a noisy minute hits every kind alike
            runs[names[0]].append(timed_batch(clips, root / f"sequential{k}", config, False, 1))
            started = time.perf_counter()
            with connected(None, 1):
                pass
            ray_starts.append(time.perf_counter() - started)
            runs[names[1]].append(timed_batch(clips, root / f"ray1-{k}", config, True, 1))
            runs[names[2]].append(timed_batch(clips, root / f"ray2-{k}", config, True, 2))
    n = len(clips)
    medians = {name: tuple(statistics.median(v[i] for v in values) for i in (0, 1)) for name, values in runs.items()}
    one = medians[names[1]]
    print(
        f"{n} clips of {args.frames} frames (320x240), preset {args.config}, one torch thread per clip; "
        f"medians of {args.repeats} runs\n"
    )
    print(
        "| run | wall time (s) | clips / min | vs Ray, 1 worker | clips / min after each worker's first "
        "| vs Ray, 1 worker |"
    )
    print("|---|---:|---:|---:|---:|---:|")
    for name, (seconds, steady) in medians.items():
        print(
            f"| {name} | {seconds:.1f} | {60 * n / seconds:.2f} | {one[0] / seconds:.2f}x | {steady:.2f} | "
            f"{steady / one[1]:.2f}x |"
        )
    sequential = medians[names[0]][0]
    print(
        f"\nRay's overhead per clip (1 worker against one process, Ray's start included): "
        f"{(one[0] - sequential) / n:.2f} s; starting and stopping a local Ray alone: "
        f"{statistics.median(ray_starts):.1f} s"
    )


if __name__ == "__main__":
    main()
