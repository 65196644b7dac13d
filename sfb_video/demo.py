"""The built-in demo: generate a short clip with ground truth and process it like a user's clip.

The clip (``sfb_video.synth``: a textured object flying past a photo, rendered by a forward model
independent of ours) is written as H.264 beside the run folder, processed by the full pipeline,
and the recovered sub-frames are scored against the truth, so the demo also shows how far the
results can be trusted.
"""

from __future__ import annotations

import dataclasses
import statistics
from pathlib import Path

from sfb_video.config import Config
from sfb_video.evaluation.synthetic import FrameScore, score_state
from sfb_video.stages.run_results import RunResults
from sfb_video.synth import ClipSpec, SyntheticClip, generate_clip
from sfb_video.video import VideoWriter


def demo_clip(config: Config) -> SyntheticClip:
    """The clip ``config.demo`` describes, generated in memory."""
    demo = config.demo
    spec = ClipSpec(
        shape=demo.shape,
        num_frames=demo.frames,
        width=demo.width,
        height=demo.height,
        fov_y_deg=config.camera.fov_y_deg,
        size_px_range=demo.size_px,
        speed_range=demo.speed,
        exposure_fraction=demo.exposure_fraction,
        num_subframes=config.video.tsr,
        seed=demo.seed,
    )
    return generate_clip(spec)


def write_clip_video(clip: SyntheticClip, path: Path, fps: float = 30.0, crf: int = 18) -> None:
    """Write the clip's blurred frames as an H.264 video (``crf`` 0: lossless)."""
    with VideoWriter(path, fps, clip.spec.width, clip.spec.height, crf) as video:
        for frame in clip.frames:
            video.write(frame)


def demo_config(config: Config) -> Config:
    """``config`` with the pipeline told the generated camera's shutter."""
    video = dataclasses.replace(config.video, exposure_fraction=config.demo.exposure_fraction)
    return dataclasses.replace(config, video=video)


def score_run(folder: Path, clip: SyntheticClip, config: Config) -> dict[int, FrameScore]:
    """Score every fitted frame of a run, as its outputs show it, against the clip's truth, in
    the run's time direction."""
    results = RunResults.of_run(folder, config.joint).final()
    return {k.index: score_state(r.state, clip, k.index, config, may_flip=False) for k, r in sorted(results.items())}


def score_table(scores: dict[int, FrameScore]) -> str:
    """A Markdown table of per-frame scores and their means."""
    lines = ["| frame | TIoU | PSNR | transl. err |", "|---:|---:|---:|---:|"]
    lines += [f"| {i} | {s.tiou:.3f} | {s.psnr:.2f} | {s.translation_err:.2f} |" for i, s in sorted(scores.items())]
    if scores:
        mean = {k: statistics.mean(getattr(s, k) for s in scores.values()) for k in ("tiou", "psnr", "translation_err")}
        lines.append(f"| mean | {mean['tiou']:.3f} | {mean['psnr']:.2f} | {mean['translation_err']:.2f} |")
    return "\n".join(lines)
