"""The labelled shape benchmark: which shape each sequence comes out as, and what it costs.

    python -m benchmarks.shapes [--root runs/shapes-set] [--config default] [--runs 2]
                                [--class ball ...] [--sequence NAME ...] [--set KEY=VALUE ...]

Runs the pipeline's joint mode (:mod:`sfb_video.evaluation.runner`, difference masks) on the
generated ``shapes`` set (:func:`sfb_video.evaluation.synthetic_set.shape_specs`: eight
sequences per class of ball, box, elongated, disc and ring), ``--runs`` times, each run with
``fit.w_texture`` scaled by a millionth more (1, 1 + 1e-6, 1 - 1e-6, ...): a change that small
should change no choice. A sequence's shape is the prototype most of its frames show. Prints
per sequence its class, the shape of each run and the first run's scores, then per class: the
confusion matrix of the chosen class, PSNR over 'Im' (the blurred frame as every sub-frame),
TIoU, mesh error, the share of sequences whose choice held over every run, and seconds per
frame.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import torch

from sfb_video.config import Config, load_config
from sfb_video.evaluation.runner import FrameRow, baseline_rows, run_sequence
from sfb_video.evaluation.synthetic_set import (
    PROTOTYPE_CLASSES,
    SHAPE_CLASSES,
    ensure_set,
    list_synthetic,
    shape_class,
    shape_specs,
)


@dataclass(frozen=True)
class SequenceRun:
    """One sequence in one run: the prototype its frames show most, its class, and its scores
    (means over its frames, as the benchmark scores a sequence)."""

    name: str
    truth: str
    prototype: str
    psnr: float
    im: float
    tiou: float
    mesh_err: float
    seconds_per_frame: float

    @property
    def chosen(self) -> str:
        return PROTOTYPE_CLASSES.get(self.prototype, self.prototype)


def shown_prototype(rows: list[FrameRow]) -> str:
    """The prototype most of ``rows`` (a sequence's joint-mode frames) show; on a tie, the one
    an earlier frame shows; "" where no frame was fitted."""
    shown = [r.prototype for r in rows if r.prototype]
    if not shown:
        return ""
    counts = Counter(shown)
    return max(shown, key=lambda p: (counts[p], -shown.index(p)))


def _mean(values: list[float]) -> float:
    kept = [v for v in values if not math.isnan(v)]
    return statistics.fmean(kept) if kept else math.nan


def score_sequence(sequence, config: Config, device: torch.device) -> SequenceRun:
    """Run ``sequence`` in the joint mode and score it."""
    started = time.perf_counter()
    rows = [r for r in run_sequence(sequence, config, "joint", device) if r.mode == "joint"]
    seconds = time.perf_counter() - started
    im = _mean([r.psnr for r in baseline_rows(sequence) if r.mode == "Im"])
    return SequenceRun(
        name=sequence.name,
        truth=shape_class(sequence.name),
        prototype=shown_prototype(rows),
        psnr=_mean([r.psnr for r in rows]),
        im=im,
        tiou=_mean([r.tiou for r in rows]),
        mesh_err=_mean([r.mesh_err for r in rows]),
        seconds_per_frame=seconds / max(1, len(rows)),
    )


def perturbations(runs: int) -> list[float]:
    """The ``fit.w_texture`` scales of ``runs`` runs: 1, 1 + 1e-6, 1 - 1e-6, 1 + 2e-6, ..."""
    return [1.0 + (-1) ** (k + 1) * 1e-6 * ((k + 1) // 2) for k in range(runs)]


def print_tables(runs: list[list[SequenceRun]]) -> None:
    """Per sequence, then per class: the confusion matrix, scores, stability and time."""
    classes = list(SHAPE_CLASSES)
    first = runs[0]
    print("| sequence | class | shape, per run | PSNR | Im | over Im | TIoU | mesh err | s / frame |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for each in zip(*runs, strict=True):
        r = each[0]
        shapes = " ".join(s.prototype or "-" for s in each)
        print(
            f"| {r.name} | {r.truth} | {shapes} | {r.psnr:.2f} | {r.im:.2f} | {r.psnr - r.im:+.2f} | "
            f"{r.tiou:.3f} | {r.mesh_err:.3f} | {r.seconds_per_frame:.1f} |"
        )
    labels = classes + sorted({s.chosen for run in runs for s in run} - set(classes))
    print(f"\nconfusion of the chosen class, {len(runs)} run(s) pooled (rows: truth)\n")
    print("| truth \\ chosen | " + " | ".join(labels) + " | right |")
    print("|---|" + "---:|" * (len(labels) + 1))
    for truth in classes:
        chosen = Counter(s.chosen for run in runs for s in run if s.truth == truth)
        total = sum(chosen.values())
        cells = " | ".join(str(chosen[label]) for label in labels)
        print(f"| {truth} | {cells} | {chosen[truth] / max(1, total):.2f} |")
    print("\n| class | sequences | right | held | PSNR | Im | over Im | worst over Im | TIoU | mesh err | s / frame |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    groups = {c: [k for k, r in enumerate(first) if r.truth == c] for c in classes}
    groups["all"] = list(range(len(first)))
    for name, members in groups.items():
        if not members:
            continue
        right = _mean([float(run[k].chosen == run[k].truth) for run in runs for k in members])
        held = _mean([float(len({run[k].prototype for run in runs}) == 1) for k in members])
        psnr = _mean([_mean([run[k].psnr for run in runs]) for k in members])
        im = _mean([first[k].im for k in members])
        worst = min(_mean([run[k].psnr for run in runs]) - first[k].im for k in members)
        tiou = _mean([_mean([run[k].tiou for run in runs]) for k in members])
        mesh = _mean([_mean([run[k].mesh_err for run in runs]) for k in members])
        seconds = _mean([run[k].seconds_per_frame for run in runs for k in members])
        print(
            f"| {name} | {len(members)} | {right:.2f} | {held:.2f} | {psnr:.2f} | {im:.2f} | {psnr - im:+.2f} | "
            f"{worst:+.2f} | {tiou:.3f} | {mesh:.3f} | {seconds:.1f} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path("runs/shapes-set"), help="the set's folder (made if new)")
    parser.add_argument("--config", default="default")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--runs", type=int, default=2, help="runs, each with fit.w_texture perturbed (default 2)")
    parser.add_argument("--class", dest="classes", action="append", choices=list(SHAPE_CLASSES), help="default: all")
    parser.add_argument("--sequence", action="append", help="default: all")
    args = parser.parse_args()
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    config = load_config(args.config, args.set)
    ensure_set(args.root, shape_specs())
    sequences = [
        s
        for s in list_synthetic(args.root, "shapes")
        if (not args.classes or shape_class(s.name) in args.classes) and (not args.sequence or s.name in args.sequence)
    ]
    device = torch.device("cpu")
    runs: list[list[SequenceRun]] = []
    started = time.perf_counter()
    for scale in perturbations(args.runs):
        perturbed = dataclasses.replace(
            config, fit=dataclasses.replace(config.fit, w_texture=config.fit.w_texture * scale)
        )
        run = []
        for sequence in sequences:
            run.append(score_sequence(sequence, perturbed, device))
            r = run[-1]
            over = f"{r.psnr - r.im:+.2f} dB over Im"
            print(f"{r.name}: {r.prototype or '-'} ({over}, {r.seconds_per_frame:.1f} s a frame)", flush=True)
        runs.append(run)
    minutes = (time.perf_counter() - started) / 60
    told = f"preset {args.config} {' '.join(args.set)}"
    print(f"\n{told}; {len(sequences)} sequences, {args.runs} run(s), {minutes:.1f} min\n")
    print_tables(runs)


if __name__ == "__main__":
    main()
