"""Where the dB go: each frame's fit scored as it is, then with one component replaced by the truth.

    python -m benchmarks.oracle [--dataset synthetic|synthetic-hard] [--root runs/synthetic-set]
                                [--config default] [--max-frames N] [--refit]

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

``--refit`` measures the parts apart: a swap without a refit measures how a part fits the rest
(a fitted texture goes with the fitted rotation), not what the part costs. Each frame's fit is
fitted again from its own result for ``fit.iterations`` steps, once as it is (the control:
more steps alone), then with one part set to the truth and held: the path (position and
travel), the rotation (start and spin), the mesh (its texture learnt afresh on the true UVs),
the mesh and its texture (the motion alone learnt). Prints PSNR, TIoU and mesh error.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
from pathlib import Path

import numpy as np
import torch

from sfb_video import metrics
from sfb_video.config import Config, load_config
from sfb_video.evaluation.synthetic import fit_synthetic_frame, score_state, synthetic_crop
from sfb_video.evaluation.synthetic_set import SETS, SyntheticSequence, ensure_set, list_synthetic
from sfb_video.fitting.engine import deterministic, seed_texture, seeded
from sfb_video.fitting.frame import FitResult, FrameObjective, frame_optimisation
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model.motion import Motion, MotionParams
from sfb_video.model.scene import ObjectState
from sfb_video.model.shape import ShapeParams

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


def _true_texture(sequence: SyntheticSequence) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(sequence.clip.scene.mesh.texture)).permute(2, 0, 1).float() / 255


def _true_object(sequence: SyntheticSequence, motion: Motion) -> ObjectState:
    mesh = sequence.clip.scene.mesh
    return ObjectState(mesh.vertices, mesh.topology, _true_texture(sequence), motion)


REFITS = {
    "refit": (),
    "true path": ("path",),
    "true rotation": ("rotation",),
    "true mesh": ("mesh",),
    "true mesh + texture": ("mesh", "texture"),
}
"""The refits' columns: the parts each holds at the truth."""


def refit(
    sequence: SyntheticSequence, index: int, fit: FitResult, parts: tuple[str, ...], config: Config
) -> ObjectState:
    """Frame ``index`` fitted again from ``fit``'s result, ``parts`` set to the truth and held."""
    fc, clip = config.fit, sequence.clip
    crop = synthetic_crop(clip, index, config)
    true, fitted = _true_motion(sequence, index), fit.state.motion
    path = (true if "path" in parts else fitted).x0, (true if "path" in parts else fitted).dx
    turn = (true if "rotation" in parts else fitted).rot0, (true if "rotation" in parts else fitted).omega
    with seeded(fc.seed):
        if "mesh" in parts:
            mesh = clip.scene.mesh
            vertices = torch.as_tensor(mesh.vertices, dtype=torch.float32)
            held = "texture" in parts
            size = mesh.texture.shape[0] if held else fc.texture_size
            shape = ShapeParams(vertices, mesh.topology, size, False, not held)
            if held:
                seed_texture(shape, _true_texture(sequence))
        else:
            _, topology = load_prototype(fit.prototype)
            shape = ShapeParams(fit.state.vertices, topology, fit.state.texture.shape[-1], fc.deform)
            seed_texture(shape, fit.state.texture)
        motion = MotionParams(crop.camera, fc.size_range, fc.max_size_ratio, fc.max_rotation_deg, fc.init_size)
        motion.load_motion(Motion(*path, *turn))
        if "path" in parts:
            motion.ends.requires_grad_(False)
        if "rotation" in parts:
            motion.quat0.requires_grad_(False)
            motion.omega_raw.requires_grad_(False)
        optimisation = frame_optimisation(
            FrameObjective(crop, shape, motion, None, fc, config.render), fc.iterations, False
        )
        with deterministic(crop.image.device):
            optimisation.run(fc.iterations)
    optimisation.restore()
    with torch.no_grad():
        return ObjectState(shape.vertices(), shape.topology, shape.texture(), motion.motion())


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


def frame_refits(sequence: SyntheticSequence, index: int, config: Config) -> dict[str, tuple[float, float, float]]:
    """(PSNR, TIoU, mesh error) of frame ``index``: 'Im', the fit, its refits and the truth."""
    clip, truth = sequence.clip, sequence.clip.truth[index]
    x, y, w, h = truth.bbox
    expected = truth.subframes[:, y : y + h, x : x + w].astype(np.float64) / 255
    blurred = clip.frames[index][y : y + h, x : x + w].astype(np.float64) / 255
    fit, _ = fit_synthetic_frame(clip, index, config)
    states = {"fit": fit.state} | {name: refit(sequence, index, fit, parts, config) for name, parts in REFITS.items()}
    states["truth rendered"] = _true_object(sequence, _true_motion(sequence, index))
    out = {"Im": (metrics.psnr(np.broadcast_to(blurred, expected.shape), expected), math.nan, math.nan)}
    for name, state in states.items():
        score = score_state(state, clip, index, config)
        out[name] = (score.psnr, score.tiou, score.mesh_err)
    return out


def refit_table(root: Path, dataset: str, config: Config, max_frames: int | None) -> None:
    """Print the refits' table: per sequence, PSNR / TIoU / mesh error of each column."""
    columns = ("Im", "fit", *REFITS, "truth rendered")
    rows = []
    for sequence in list_synthetic(root, dataset):
        frames = [t.index for t in sequence.clip.truth if t.bbox is not None][:max_frames]
        scores = [frame_refits(sequence, i, config) for i in frames]
        rows.append((sequence.name, {c: np.mean([s[c] for s in scores], 0) for c in columns}))
    print(f"PSNR (dB) / TIoU / mesh error of per-frame fits, {dataset}; refitted with one part true and held\n")
    print("| sequence | " + " | ".join(columns) + " |")
    print("|---|" + "---|" * len(columns))
    rows.append(("**mean**", {c: np.mean([r[1][c] for r in rows], 0) for c in columns}))

    def cell(v: np.ndarray) -> str:
        return f"{v[0]:.2f}" if math.isnan(v[1]) else f"{v[0]:.2f} / {v[1]:.2f} / {v[2]:.3f}"

    for name, means in rows:
        print(f"| {name} | " + " | ".join(cell(means[c]) for c in columns) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="synthetic", choices=sorted(SETS))
    parser.add_argument("--root", default=None, help="the set's folder (default: runs/<dataset>-set)")
    parser.add_argument("--config", default="default")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--refit", action="store_true", help="refit with one part true and held")
    args = parser.parse_args()
    root = Path(args.root or f"runs/{args.dataset}-set")
    ensure_set(root, SETS[args.dataset](), quiet=True)
    config = load_config(args.config)
    if args.refit:
        refit_table(root, args.dataset, config, args.max_frames)
        return
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
