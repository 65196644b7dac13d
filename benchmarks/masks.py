"""What sub-frame masks buy: the difference image (L_D) against true sub-frame masks (L_S).

    python -m benchmarks.masks [--root runs/synthetic-set] [--config default] [--max-frames N]

DeFMO's weights cannot be downloaded everywhere (not on our CI machine), so the synthetic set's
true sub-frame masks stand in for DeFMO's: the rows with them bound what DeFMO's masks can give.
They are handed over in DeFMO's manner, with the time order reversed in every other frame (one
blurred image cannot tell which way time runs), so the video rows also show that the track's
order between frames wins. Runs the synthetic benchmark set (``sfb-video eval --dataset
synthetic``) per frame and as videos with both, and prints the totals and their ratios.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from sfb_video.config import load_config
from sfb_video.crop import Box, Crop
from sfb_video.evaluation.runner import MODES, FrameRow, run_sequence
from sfb_video.evaluation.synthetic import crop_masks
from sfb_video.evaluation.synthetic_set import SyntheticSequence, ensure_set, list_synthetic
from sfb_video.evaluation.tables import markdown, summarise
from sfb_video.stages.masks import MaskSource
from sfb_video.stages.types import FrameWithBackground


def true_masks(sequence: SyntheticSequence) -> MaskSource:
    """The sequence's true sub-frame masks, reversed in odd frames, averaged to the fit's count."""

    def make(frame: FrameWithBackground, box: Box, crop: Crop, n: int) -> torch.Tensor:
        masks = crop_masks(sequence.clip, frame.index, crop)
        masks = masks.reshape(n, -1, *masks.shape[1:]).mean(1)
        return masks.flip(0) if frame.index % 2 else masks

    return MaskSource("truth", "the generator's sub-frame masks, reversed in odd frames", make)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", default="runs/synthetic-set", type=Path)
    parser.add_argument("--config", default="default")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--max-frames", type=int)
    args = parser.parse_args()
    config = load_config(args.config, args.set)
    ensure_set(args.root)
    sequences = list_synthetic(args.root)
    totals: dict[str, dict[str, dict]] = {}
    for masks in ("diff", "truth"):
        rows: list[FrameRow] = []
        for sequence in sequences:
            source = None if masks == "diff" else true_masks(sequence)
            for mode in MODES:
                rows += run_sequence(sequence, config, mode, torch.device("cpu"), args.max_frames, masks=source)
        records = summarise(rows)
        print(f"\n## masks: {masks}\n\n{markdown(records)}")
        totals[masks] = {r["mode"]: r for r in records if r["sequence"] == "total"}
    print("| mode | TIoU diff | TIoU truth | ratio | PSNR diff | PSNR truth | transl. err diff | transl. err truth |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for mode in MODES:
        d, t = totals["diff"][mode], totals["truth"][mode]
        print(
            f"| {mode} | {d['tiou']:.3f} | {t['tiou']:.3f} | {t['tiou'] / d['tiou']:.2f} | {d['psnr']:.2f} | "
            f"{t['psnr']:.2f} | {d['translation_err']:.2f} | {t['translation_err']:.2f} |"
        )


if __name__ == "__main__":
    main()
