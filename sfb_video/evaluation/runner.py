"""Run the method on benchmark sequences, per frame and as a warm-started video, and score it.

Each frame gets what the FMO deblurring benchmark hands a method: the frame, its background,
the tight box and the number of sub-frames. ``per-frame`` fits every frame from a cold start,
as the benchmark (and the paper) does; ``video`` fits the sequence in order as the pipeline
does, each frame warm-started from the previous one. Both are scored with the benchmark's own
rules (``sfb_video.metrics``), so their numbers compare with the published ones and with each
other. A frame the method cannot fit scores 0 on every measure, as in the benchmark, where an
unscored frame keeps its initial 0.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from sfb_video.config import Config
from sfb_video.evaluation.datasets import BenchmarkFrame
from sfb_video.evaluation.scoring import render_estimate, score_estimate
from sfb_video.fitter import NoObjectError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.results import FrameResult
from sfb_video.synth import SyntheticClip
from stages.background import FrameWithBackground
from stages.detect import Detection
from stages.fit import fit_detection
from stages.masks import MaskSource
from stages.track import join

MODES = ("per-frame", "video")


class Sequence(Protocol):
    """What the runner needs of a sequence (a benchmark one, or one of our synthetic set)."""

    dataset: str
    name: str
    num_subframes: int
    num_frames: int

    def frames(self) -> Iterator[BenchmarkFrame]: ...


@dataclass(frozen=True)
class FrameRow:
    """The scores of one frame in one mode; 3D errors only where the truth has them (else NaN)."""

    dataset: str
    sequence: str
    frame: int
    mode: str
    status: str
    tiou: float
    psnr: float
    ssim: float
    seconds: float
    translation_err: float = math.nan
    rotation_err_deg: float = math.nan
    mesh_err: float = math.nan


def _tensor(image: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float()


def fit_benchmark_frame(
    frame: BenchmarkFrame,
    camera: PinholeCamera,
    config: Config,
    previous: FrameResult | None,
    device: torch.device,
    masks: MaskSource | None = None,
) -> FrameResult:
    """Fit one frame from the benchmark's inputs, warm from ``previous`` when given.

    ``masks`` gives the fit its sub-frame masks (None: the difference mask).

    Raises:
        NoObjectError: when the box shows no difference from the background.
    """
    height, width = frame.image.shape[:2]
    x, y, w, h = frame.box
    blob = torch.zeros(height, width, dtype=torch.bool)
    blob[y : y + h, x : x + w] = True
    inputs = FrameWithBackground(frame.index, _tensor(frame.image), _tensor(frame.background))
    return fit_detection(inputs, Detection(frame.index, frame.box, blob), camera, config, previous, device, masks)


def estimate_subframes(result: FrameResult, frame: BenchmarkFrame, camera: PinholeCamera, config: Config) -> np.ndarray:
    """The (N, h, w, 3) sub-frames the fit renders on the frame's tight box, over its background."""
    return render_estimate(result.state, camera, frame.box, frame.background, len(frame.centres), config.render)


def score_frame(
    frame: BenchmarkFrame,
    result: FrameResult,
    estimate: np.ndarray,
    camera: PinholeCamera,
    clip: SyntheticClip | None,
) -> dict[str, float]:
    """The benchmark's measures of one fitted frame, and 3D errors when ``clip`` holds the truth."""
    x, y, w, h = frame.box
    truth = frame.subframes[:, y : y + h, x : x + w]
    truth_3d = None if clip is None else (clip.truth[frame.index].motion, clip.scene.mesh)
    return score_estimate(result.state, estimate, truth, camera, frame.centres, frame.radius, truth_3d)[0]


def mode_config(config: Config, mode: str) -> Config:
    """Per-frame fits use the fitter's prototypes; a video track's first frame tries the track's."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; choose one of {MODES}")
    if mode == "video":
        return config
    return dataclasses.replace(config, video=dataclasses.replace(config.video, track_prototypes=config.fit.prototypes))


def run_sequence(
    sequence: Sequence,
    config: Config,
    mode: str,
    device: torch.device,
    max_frames: int | None = None,
    on_frame: Callable[[FrameRow], None] | None = None,
    masks: MaskSource | None = None,
) -> list[FrameRow]:
    """Fit and score the frames of ``sequence`` in ``mode`` (one of ``MODES``).

    Args:
        masks: where the fits' sub-frame masks come from (None: the difference mask).
        max_frames: stop after this many frames (the first ones), for quick looks.
        on_frame: called with each frame's row as soon as it is scored (progress).
    """
    config = mode_config(config, mode)
    clip: SyntheticClip | None = getattr(sequence, "clip", None)
    if clip is not None:
        # The generator's camera and shutter are known: the method is told them, as a user would be.
        video = dataclasses.replace(config.video, exposure_fraction=clip.spec.exposure_fraction)
        config = dataclasses.replace(config, video=video)
    rows: list[FrameRow] = []
    previous: FrameResult | None = None
    track_length = 0
    for frame in sequence.frames():
        if max_frames is not None and len(rows) >= max_frames:
            break
        height, width = frame.image.shape[:2]
        camera = clip.camera if clip is not None else PinholeCamera.from_fov(width, height, config.camera.fov_y_deg)
        start = time.perf_counter()
        try:
            warm = previous if mode == "video" else None
            result = fit_benchmark_frame(frame, camera, config, warm, device, masks)
            estimate = estimate_subframes(result, frame, camera, config)
        except NoObjectError:
            row = FrameRow(sequence.dataset, sequence.name, frame.index, mode, "no_object", 0.0, 0.0, 0.0, 0.0)
            previous, track_length = None, 0
        else:
            seconds = time.perf_counter() - start
            scores = score_frame(frame, result, estimate, camera, clip)
            row = FrameRow(sequence.dataset, sequence.name, frame.index, mode, result.start, seconds=seconds, **scores)
            if mode == "video":
                if previous is not None:
                    _, result = join(previous, result, camera, config.video.exposure_fraction, track_length == 1)
                previous, track_length = result, track_length + 1
        rows.append(row)
        if on_frame is not None:
            on_frame(row)
    return rows
