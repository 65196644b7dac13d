"""Ghosts in the TSR sub-frames: how much of the input's blurred streak a composite leaves.

    python -m benchmarks.composite [--frames 6] [--config fast] [--set KEY=VALUE ...]

Each scenario of :mod:`benchmarks.detect` that has one object (a generated 320x240 clip with
ground truth) is written as a video and processed by the pipeline (single-frame fits, the
difference mask); every fitted frame is then rendered into its sub-frames as ``tsr.mp4`` is
(:func:`sfb_video.stages.export.render_frame`) and compared with the true sub-frames. The ghost of a
sub-frame is the energy of |TSR sub-frame - true sub-frame| over the pixels the object's streak
covers in the input frame but where the true object is not at that sub-frame's time: the
input's streak left there shows as a ghost. Reported as a share of the same energy of the input
frame itself (1: the streak left whole; a misplaced rendered object counts too), and in grey
levels per pixel (mean |difference| over RGB, 0-255); and, leaving out the rendered object's
own pixels too, the share of the input's streak left in the composite (the ghost itself)
beside the share the background estimate alone leaves there (its noise against the noise-free
truth: the floor). A second table does the same for a fit of half of every streak (the true
object on the first half of its path), which is what a fit of a partial detection renders.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import statistics
import tempfile
from pathlib import Path

import cv2
import numpy as np
import torch

from benchmarks.detect import BASE, SCENARIOS
from sfb_video.config import Config, load_config
from sfb_video.demo import write_clip_video
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.results import FrameResult, load_result
from sfb_video.run_folder import FRAMES
from sfb_video.stages.background import with_backgrounds
from sfb_video.stages.export import render_frame
from sfb_video.stages.process import ProcessOptions, process_clip
from sfb_video.stages.types import FrameWithBackground
from sfb_video.synth import ClipSpec, FrameTruth, SyntheticClip, generate_clip


class _Sums:
    """Energies summed over a scenario's sub-frames (see the module docstring)."""

    def __init__(self) -> None:
        self.left = self.whole = self.left_own = self.whole_own = self.floor_own = 0.0
        self.pixels = self.fitted = 0

    def add(
        self,
        frame: FrameWithBackground,
        result: FrameResult,
        truth: FrameTruth,
        camera: PinholeCamera,
        n: int,
        config: Config,
    ) -> None:
        self.fitted += 1
        kernel = np.ones((5, 5), np.uint8)
        subframes = render_frame(frame, result, camera, n, config.detect, config.render).subframes
        background = frame.background_pixels.float() / 255
        own = result.state.render_subframes(camera, background, n, config.render)
        streak = cv2.dilate((truth.masks.max(0) > 0.02).astype(np.uint8), kernel).astype(bool)
        for j in range(n):
            objects = cv2.dilate((truth.masks[j] > 0).astype(np.uint8), kernel).astype(bool)
            where = torch.from_numpy(streak & ~objects)
            true = torch.from_numpy(truth.subframes[j]).permute(2, 0, 1).float()
            error = (subframes[j].float() - true).abs().sum(0)
            input_error = (frame.pixels.float() - true).abs().sum(0)
            self.left += float((error * where).sum())
            self.whole += float((input_error * where).sum())
            self.pixels += int(where.sum())
            # Without the rendered object's own pixels: what is left of the input's streak, and
            # what the background estimate alone leaves there (its noise: the floor).
            rendered = ((own[j] - background).abs().amax(0) > 2 / 255).numpy().astype(np.uint8)
            apart = where & ~torch.from_numpy(cv2.dilate(rendered, kernel).astype(bool))
            self.left_own += float((error * apart).sum())
            self.whole_own += float((input_error * apart).sum())
            self.floor_own += float(((frame.background_pixels.float() - true).abs().sum(0) * apart).sum())

    def row(self, frames: int) -> dict[str, float]:
        return {
            "frames": frames,
            "fitted": self.fitted,
            "share": self.left / max(self.whole, 1e-9),
            "grey": self.left / max(3 * self.pixels, 1),
            "input_grey": self.whole / max(3 * self.pixels, 1),
            "streak_left": self.left_own / max(self.whole_own, 1e-9),
            "floor": self.floor_own / max(self.whole_own, 1e-9),
        }


def partial_fit(clip: SyntheticClip, index: int, share: float) -> FrameResult:
    """A fit with the true mesh and texture whose path covers the first ``share`` of frame
    ``index``'s streak: what a fit of the fragment a partial detection saw renders."""
    truth, mesh = clip.truth[index], clip.scene.mesh
    motion = Motion(
        torch.tensor(truth.motion.x0, dtype=torch.float32),
        share * torch.tensor(truth.motion.dx, dtype=torch.float32),
        torch.tensor(truth.motion.rotation, dtype=torch.float32),
        share * torch.tensor(truth.motion.omega, dtype=torch.float32),
    )
    texture = torch.from_numpy(mesh.texture).permute(2, 0, 1).float() / 255
    state = ObjectState(mesh.vertices, mesh.topology, texture, motion)
    uv, _ = clip.camera.project(torch.stack((motion.x0, motion.x0 + motion.dx)))
    radius = float(truth.radius_px or 1.0)
    x0, y0 = (math.floor(float(uv[:, k].min()) - radius) for k in (0, 1))
    x1, y1 = (math.ceil(float(uv[:, k].max()) + radius) for k in (0, 1))
    box = (max(0, x0), max(0, y0), max(1, x1 - max(0, x0)), max(1, y1 - max(0, y0)))
    return FrameResult(index, box, box, clip.camera, state, "cold", "sphere", {"image": 0.0}, [], 0.0)


def ghost_scenario(spec: ClipSpec, config: Config) -> tuple[dict[str, float], dict[str, float]]:
    """Process the clip ``spec`` makes and measure the ghosts of its fitted frames' sub-frames,
    and of a fit of half of every streak (:func:`partial_fit`)."""
    clip = generate_clip(spec)
    config = dataclasses.replace(
        config,
        video=dataclasses.replace(config.video, exposure_fraction=spec.exposure_fraction, tsr=spec.num_subframes),
    )
    n = spec.num_subframes
    fits, halves = _Sums(), _Sums()
    with tempfile.TemporaryDirectory() as tmp:
        video, out = Path(tmp) / "clip.mp4", Path(tmp) / "run"
        write_clip_video(clip, video)
        process_clip(ProcessOptions(video=video, out=out, masks="diff"), config, torch.device("cpu"), quiet=True)
        for frame in with_backgrounds(video, config.video, len(clip.frames)):
            # One object: its tracks are the track it was lost and found again as.
            paths = sorted((out / FRAMES).glob(f"frame_{frame.index:05d}_track_*.pt"))
            path, truth = (paths[0] if paths else None), clip.truth[frame.index]
            if not truth.present:
                continue
            halves.add(frame, partial_fit(clip, frame.index, 0.5), truth, clip.camera, n, config)
            if path is not None:
                fits.add(frame, load_result(path), truth, clip.camera, n, config)
    return fits.row(len(clip.frames)), halves.row(len(clip.frames))


def _table(title: str, rows: list[tuple[str, dict[str, float]]]) -> None:
    print(f"\n{title}\n")
    print(
        "| scenario | frames | fitted | ghost (share of the input's) | ghost, grey levels | input, grey levels "
        "| input's streak left | background's floor |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    keys = ("share", "grey", "input_grey", "streak_left", "floor")
    for name, r in rows:
        print(
            f"| {name} | {r['frames']} | {r['fitted']} | {r['share']:.3f} | {r['grey']:.2f} | {r['input_grey']:.2f} "
            f"| {r['streak_left']:.3f} | {r['floor']:.3f} |"
        )
    mean = {k: statistics.fmean(r[k] for _, r in rows) for k in keys}
    print(
        f"| **mean** | | | {mean['share']:.3f} | {mean['grey']:.2f} | {mean['input_grey']:.2f} "
        f"| {mean['streak_left']:.3f} | {mean['floor']:.3f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--config", default="fast")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    config = load_config(args.config, ["joint.enabled=false", *args.set])
    rows, halves = [], []
    for name, fields in SCENARIOS.items():
        if "second" in fields:
            continue
        spec = dataclasses.replace(BASE, **({"num_frames": args.frames} | fields))
        fits, half = ghost_scenario(spec, config)
        rows.append((name, fits))
        halves.append((name, half))
    print(f"preset {args.config} joint.enabled=false {' '.join(args.set)}; 320x240 clips")
    _table("The pipeline's fits", rows)
    _table("A fit of the first half of each streak (the true object on half its path)", halves)


if __name__ == "__main__":
    main()
