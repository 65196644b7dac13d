"""Where the dB go: each frame's fit scored as it is, then with one component replaced by the truth.

    python -m benchmarks.oracle [--dataset synthetic|synthetic-hard] [--root runs/synthetic-set]
                                [--config default] [--max-frames N]

Per-frame (cold) fits of a generated set, each frame's box handed over as the benchmark hands
it, then scored again with parts of the recovered object swapped for the generator's truth, at
the same time (no refit): the streak's path (position and travel within the exposure), the
rotation (start and spin), both, the object (mesh and texture together: a fitted texture does
not map onto the true mesh's UVs), and the object with its true motion, which is what our
renderer makes of the truth (its distance from the generator's own renderer); then the truth
with the fit's path, or the fit's rotation, in place of its own. The eval already
hands every method the true background and, on the first set, the exposure fraction; those two
terms are measured by the pipeline's runs, not here. 'Im' (the blurred frame as every
sub-frame) is the benchmark's baseline. Prints PSNR per sequence and the set's mean.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
from pathlib import Path

import numpy as np
import torch

from sfb_video import metrics
from sfb_video.config import Config, load_config
from sfb_video.evaluation.synthetic import fit_synthetic_frame, score_state
from sfb_video.evaluation.synthetic_set import SETS, SyntheticSequence, ensure_set, list_synthetic
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState

COLUMNS = (
    "Im",
    "fit",
    "true path",
    "true rotation",
    "true motion",
    "true object",
    "truth rendered",
    "truth, fit's path",
    "truth, fit's rotation",
)
"""The fit with one part true, then the truth with one part the fit's (the parts are coupled:
a fitted texture goes with the fitted rotation, so both directions are shown)."""


def _true_motion(sequence: SyntheticSequence, index: int) -> Motion:
    m = sequence.clip.truth[index].motion
    return Motion(*(torch.tensor(v, dtype=torch.float32) for v in (m.x0, m.dx, m.rotation, m.omega)))


def _true_object(sequence: SyntheticSequence, motion: Motion) -> ObjectState:
    mesh = sequence.clip.scene.mesh
    texture = torch.from_numpy(np.ascontiguousarray(mesh.texture)).permute(2, 0, 1).float() / 255
    return ObjectState(mesh.vertices, mesh.topology, texture, motion)


def frame_psnrs(sequence: SyntheticSequence, index: int, config: Config) -> dict[str, float]:
    """PSNR of frame ``index``: the baseline, the fit, and the fit with parts of it true."""
    clip, truth = sequence.clip, sequence.clip.truth[index]
    x, y, w, h = truth.bbox
    expected = truth.subframes[:, y : y + h, x : x + w].astype(np.float64) / 255
    blurred = clip.frames[index][y : y + h, x : x + w].astype(np.float64) / 255
    fit, _ = fit_synthetic_frame(clip, index, config)
    state, true = fit.state, _true_motion(sequence, index)
    fitted = state.motion
    variants = {
        "fit": state,
        "true path": dataclasses.replace(state, motion=dataclasses.replace(fitted, x0=true.x0, dx=true.dx)),
        "true rotation": dataclasses.replace(
            state, motion=dataclasses.replace(fitted, rot0=true.rot0, omega=true.omega)
        ),
        "true motion": dataclasses.replace(state, motion=true),
        "true object": _true_object(sequence, fitted),
        "truth rendered": _true_object(sequence, true),
        "truth, fit's path": _true_object(sequence, dataclasses.replace(true, x0=fitted.x0, dx=fitted.dx)),
        "truth, fit's rotation": _true_object(
            sequence, dataclasses.replace(true, rot0=fitted.rot0, omega=fitted.omega)
        ),
    }
    out = {"Im": metrics.psnr(np.broadcast_to(blurred, expected.shape), expected)}
    # The fit's own time direction is scored as the benchmark scores it (flipped where it would).
    out |= {name: score_state(s, clip, index, config).psnr for name, s in variants.items()}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="synthetic", choices=sorted(SETS))
    parser.add_argument("--root", default=None, help="the set's folder (default: runs/<dataset>-set)")
    parser.add_argument("--config", default="default")
    parser.add_argument("--max-frames", type=int, default=None)
    args = parser.parse_args()
    root = Path(args.root or f"runs/{args.dataset}-set")
    ensure_set(root, SETS[args.dataset](), quiet=True)
    config = load_config(args.config)
    rows = []
    for sequence in list_synthetic(root, args.dataset):
        frames = [t.index for t in sequence.clip.truth if t.bbox is not None][: args.max_frames]
        scores = [frame_psnrs(sequence, i, config) for i in frames]
        rows.append((sequence.name, len(frames), {c: statistics.fmean(s[c] for s in scores) for c in COLUMNS}))
    print(f"PSNR (dB) of per-frame fits, {args.dataset}, config {args.config}; no refit, one part true at a time\n")
    print("| sequence | frames | " + " | ".join(COLUMNS) + " |")
    print("|---|---:|" + "---:|" * len(COLUMNS))
    for name, n, means in rows:
        print(f"| {name} | {n} | " + " | ".join(f"{means[c]:.2f}" for c in COLUMNS) + " |")
    mean = {c: statistics.fmean(r[2][c] for r in rows) for c in COLUMNS}
    print(f"| **mean** | {sum(r[1] for r in rows)} | " + " | ".join(f"{mean[c]:.2f}" for c in COLUMNS) + " |")


if __name__ == "__main__":
    main()
