"""Single-frame fitting accuracy and time on generated frames with ground truth.

    python -m benchmarks.fit [--seeds 2] [--variants full,no_LD,...] [--config default]

Each variant fits the same frames (every shape in ``SHAPES`` x ``--seeds`` seeds, frame size
320x240) from a cold start and prints one row per frame and a total row: TIoU, PSNR and SSIM on
the tight box (FMO benchmark definitions), translation error in object sizes, rotation error
of the exposure's rotation in degrees, the image loss L_I and seconds per frame. The ablation
variants switch one loss term off, or try all prototypes, as in the paper's Table 2; the last
fits no rotation at all, whose rotation error (the true angle) is the bar a recovered rotation
must clear.
"""

from __future__ import annotations

import argparse
import statistics

from sfb_video.config import Config, load_config
from sfb_video.evaluation.synthetic import FrameScore, fit_synthetic_frame
from sfb_video.synth import ClipSpec, generate_clip

SHAPES = ("ball", "box", "pen", "ring", "key")
VARIANTS: dict[str, list[str]] = {
    "full": [],
    "no_LD": ["fit.w_difference=0"],
    "no_LL": ["fit.w_laplacian=0"],
    "no_LT": ["fit.w_texture=0"],
    "all_prototypes": ["fit.prototypes=[sphere, sphere_large, torus]"],
    "no_rotation": ["fit.max_rotation_deg=0"],
}
COLUMNS = ("tiou", "psnr", "ssim", "translation_err", "rotation_err_deg", "image_loss", "seconds")


def _row(label: str, values: dict[str, float]) -> str:
    cells = [f"{values[c]:.3f}" if c in ("tiou", "ssim", "image_loss") else f"{values[c]:.2f}" for c in COLUMNS]
    return f"| {label} | " + " | ".join(cells) + " |"


def run_variant(config: Config, seeds: int, show_frames: bool) -> dict[str, float]:
    scores: list[FrameScore] = []
    for shape in SHAPES:
        for seed in range(seeds):
            clip = generate_clip(ClipSpec(shape=shape, seed=seed))
            fit, score = fit_synthetic_frame(clip, 0, config)
            scores.append(score)
            if show_frames:
                print(_row(f"{shape} s{seed} ({fit.prototype})", score.__dict__), flush=True)
    return {c: statistics.mean(getattr(s, c) for s in scores) for c in COLUMNS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--config", default="default")
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    header = "| frame | TIoU | PSNR | SSIM | transl. err | rot. err (deg) | L_I | s/frame |"
    print(f"preset {args.config} {' '.join(args.set)}, {len(SHAPES)} shapes x {args.seeds} seeds, cold starts\n")
    totals = {}
    for name in args.variants.split(","):
        config = load_config(args.config, [*args.set, *VARIANTS[name]])
        print(f"\n{name}\n\n{header}\n|---|---:|---:|---:|---:|---:|---:|---:|", flush=True)
        totals[name] = run_variant(config, args.seeds, show_frames=True)
        print(_row("**mean**", totals[name]), flush=True)
    print(f"\nsummary (means over all frames)\n\n{header.replace('| frame |', '| variant |')}")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name, values in totals.items():
        print(_row(name, values))


if __name__ == "__main__":
    main()
