"""Run the method on benchmark sequences, per frame, as a warm-started video and jointly, and
score it.

Each frame gets what the FMO deblurring benchmark hands a method: the frame, its background,
the tight box and the number of sub-frames. ``per-frame`` fits every frame from a cold start,
as the benchmark (and the paper) does; ``video`` fits the sequence in order, each frame
warm-started from the previous one; ``joint`` then refits windows of those frames with one
shape and one trajectory (:mod:`sfb_video.stages.windows`), as the pipeline does by default. All are scored
with the benchmark's own rules (``sfb_video.metrics``), so their numbers compare with the published ones and with each
other. A frame the method cannot fit scores 0 on every measure, as in the benchmark, where an
unscored frame keeps its initial 0.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from sfb_video import metrics
from sfb_video.config import Config
from sfb_video.crop import Box, box_mask
from sfb_video.errors import DivergenceError, NoObjectError
from sfb_video.evaluation.datasets import BenchmarkFrame
from sfb_video.evaluation.scoring import render_estimate, score_estimate
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.results import FrameKey, FrameResult
from sfb_video.stages.detect import box_blobs
from sfb_video.stages.fit import fit_detection
from sfb_video.stages.frame_buffer import FrameBuffer
from sfb_video.stages.masks import MaskSource
from sfb_video.stages.run_results import MemorySource, RunResults
from sfb_video.stages.track import Tracking
from sfb_video.stages.types import Detection, FrameStatus, FrameWithBackground
from sfb_video.stages.windows import fit_track_window, window_frame
from sfb_video.synth import SyntheticClip

MODES = ("per-frame", "video", "joint")
BASELINES = ("Im", "Bg")
"""The benchmark's baselines: the blurred frame ('Im') or the background ('Bg') as every
sub-frame. A method that does not beat 'Im' on a sequence has not deblurred it."""


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
    prototype: str = ""
    track: int | None = None
    """The frame's track (the pipeline's tracker: :class:`~sfb_video.stages.tracking.tracker.Tracker`), in
    the video and joint modes."""

    @property
    def windowed(self) -> float:
        """In the joint mode, 1 where an accepted window stands for the frame, 0 where the frame
        kept its single-frame fit (a rejected window, or one that explains the frame far worse,
        :func:`~sfb_video.stages.run_results.trusted_frames`); NaN in the other modes."""
        return float(self.status == "joint") if self.mode == "joint" else math.nan


ImageSink = Callable[["FrameRow", BenchmarkFrame, np.ndarray], None]
"""Row, frame, our (N, h, w, 3) sub-frames on its tight box."""


def _inputs(frame: BenchmarkFrame) -> FrameWithBackground:
    """The frame and its background as the pipeline's stages take them, (3, H, W) each."""

    def tensor(image: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float()

    return FrameWithBackground(frame.index, tensor(frame.image), tensor(frame.background))


def fit_benchmark_frame(
    inputs: FrameWithBackground,
    box: Box,
    camera: PinholeCamera,
    config: Config,
    previous: FrameResult | None,
    device: torch.device,
    masks: MaskSource | None = None,
    earlier: FrameResult | None = None,
) -> FrameResult:
    """Fit one frame from the benchmark's inputs (the frame and its background, the object's
    tight ``box``), warm from ``previous`` when given (with
    ``earlier``, the frame before it on the track, its motion continues turning).

    ``masks`` gives the fit its sub-frame masks (None: the difference mask).

    Raises:
        NoObjectError: when the box shows no difference from the background.
    """
    blob = box_mask(box, inputs.pixels.shape[1:])
    detection = Detection(inputs.index, box, blob)
    return fit_detection(inputs, detection, camera, config, previous, device, masks, earlier)


def estimate_subframes(result: FrameResult, frame: BenchmarkFrame, camera: PinholeCamera, config: Config) -> np.ndarray:
    """The (N, h, w, 3) sub-frames the fit renders on the frame's tight box, over its background."""
    return render_estimate(result.state, camera, frame.box, frame.background, len(frame.centres), config.render)


def true_subframes(frame: BenchmarkFrame) -> np.ndarray:
    """The (N, h, w, 3) true sub-frames on the frame's tight box."""
    x, y, w, h = frame.box
    return frame.subframes[:, y : y + h, x : x + w]


def score_frame(
    frame: BenchmarkFrame,
    result: FrameResult,
    estimate: np.ndarray,
    camera: PinholeCamera,
    clip: SyntheticClip | None,
) -> dict[str, float]:
    """The benchmark's measures of one fitted frame, and 3D errors when ``clip`` holds the truth."""
    truth = true_subframes(frame)
    truth_3d = None if clip is None else (clip.truth[frame.index].motion, clip.scene.mesh)
    return score_estimate(result.state, estimate, truth, camera, frame.centres, frame.radius, truth_3d)[0]


def baseline_rows(sequence: Sequence, max_frames: int | None = None) -> list[FrameRow]:
    """The rows of the benchmark's baselines (:data:`BASELINES`) on every frame of ``sequence``
    (the first ``max_frames``): the frame's tight box of the blurred image, or of the background,
    as each of its sub-frames. They estimate no position: their TIoU is unknown."""
    rows = []
    for position, frame in enumerate(sequence.frames()):
        if max_frames is not None and position >= max_frames:
            break
        x, y, w, h = frame.box
        truth = true_subframes(frame)
        for mode, still in zip(BASELINES, (frame.image, frame.background), strict=True):
            estimate = np.broadcast_to(still[y : y + h, x : x + w], truth.shape)
            psnr, ssim = metrics.psnr(estimate, truth), metrics.ssim(estimate, truth)
            rows.append(
                FrameRow(sequence.dataset, sequence.name, frame.index, mode, "baseline", math.nan, psnr, ssim, 0.0)
            )
    return rows


def mode_config(config: Config, mode: str) -> Config:
    """Per-frame fits use the fitter's prototypes; a video track's first frame tries the track's."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; choose one of {MODES}")
    if mode != "per-frame":
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
    with_video: bool = False,
    first: int = 0,
    on_images: ImageSink | None = None,
) -> list[FrameRow]:
    """Fit and score the frames of ``sequence`` in ``mode`` (one of ``MODES``).

    Args:
        first: skip the frames before this one (``per-frame`` mode only, whose frames are fitted
            each on its own: how a distributed evaluation splits a sequence).
        masks: where the fits' sub-frame masks come from (None: the difference mask).
        with_video: in ``joint`` mode, also score its warm-started fits as the ``video`` mode's
            rows (the same fits: one run gives both modes).
        max_frames: stop after this many frames (the first ones), for quick looks.
        on_frame: called with each frame's row as soon as it is scored (progress).
        on_images: called with each scored frame's row, the frame and our (N, h, w, 3)
            sub-frames on its tight box (for montages).
    """
    if first and mode != "per-frame":
        raise ValueError("only the per-frame mode can start in the middle of a sequence")
    config = mode_config(config, mode)
    clip: SyntheticClip | None = getattr(sequence, "clip", None)
    if clip is not None and getattr(sequence, "told_exposure", True):
        # The generator's camera and shutter are known: the method is told them, as a user would be.
        video = dataclasses.replace(config.video, exposure_fraction=clip.spec.exposure_fraction)
        config = dataclasses.replace(config, video=video)
    rows: list[FrameRow] = []
    fitted: dict[int, tuple[BenchmarkFrame, FrameResult, float]] = {}  # joint mode: scored at the end
    scored = functools.partial(_scored_row, sequence, config=config, clip=clip, on_images=on_images)

    def emit(row: FrameRow) -> None:
        rows.append(row)
        if on_frame is not None:
            on_frame(row)

    frames = itertools.islice(sequence.frames(), max_frames)
    if mode == "per-frame":
        for frame in itertools.islice(frames, first, None):
            camera = _camera(frame, clip, config)
            start = time.perf_counter()
            try:
                result = fit_benchmark_frame(_inputs(frame), frame.box, camera, config, None, device, masks)
            except NoObjectError:
                result = None
            emit(scored(frame, mode, result, time.perf_counter() - start, camera))
        return rows
    statuses, camera = _tracked(frames, clip, mode, config, device, masks, with_video, scored, emit, fitted)
    if mode != "joint" or camera is None:
        return rows
    video_rows = [r for r in rows if r.mode == "video"]
    unfitted = [r for r in rows if r.mode == "joint"]
    if with_video:  # a frame with no object scores 0 in both modes
        for row in unfitted:
            video_rows.append(dataclasses.replace(row, mode="video"))
            if on_frame is not None:
                on_frame(video_rows[-1])
    joint_rows = _joint_rows(sequence, statuses, fitted, unfitted, camera, config, device, clip, on_frame, on_images)
    return sorted(video_rows, key=lambda r: r.frame) + joint_rows


def _tracked(
    frames: Iterator[BenchmarkFrame],
    clip: SyntheticClip | None,
    mode: str,
    config: Config,
    device: torch.device,
    masks: MaskSource | None,
    with_video: bool,
    scored: Callable[..., FrameRow],
    emit: Callable[[FrameRow], None],
    fitted: dict[int, tuple[BenchmarkFrame, FrameResult, float]],
) -> tuple[list[FrameStatus], PinholeCamera | None]:
    """Fit ``frames`` through the pipeline's tracking step (:class:`Tracking`), which decides the
    tracks and warm starts, on the box the benchmark hands over as each frame's one blob: each
    frame is scored (``scored``, then ``emit``) once no later frame can change it, in the
    ``video`` mode (``joint`` with ``with_video``), or its fit kept in ``fitted`` (``joint``).
    Returns every frame's status and the clip's camera (None: no frame)."""
    held: dict[int, BenchmarkFrame] = {}
    seconds: dict[int, float] = {}
    statuses: list[FrameStatus] = []
    camera: PinholeCamera | None = None

    def refit(
        inputs: FrameWithBackground, detection: Detection, start: FrameResult | None, earlier: FrameResult | None
    ) -> FrameResult:
        assert camera is not None
        began = time.perf_counter()
        try:
            return fit_benchmark_frame(inputs, detection.box, camera, config, start, device, masks, earlier)
        finally:
            seconds[inputs.index] = time.perf_counter() - began

    def report(status: FrameStatus, result: FrameResult | None) -> None:
        statuses.append(status)
        frame = held.pop(status.index)
        assert camera is not None
        if result is None:  # no object: scored 0 in the mode asked
            emit(scored(frame, mode, None, 0.0, camera))
            return
        if mode == "joint":
            fitted[status.index] = (frame, result, seconds[status.index])
        if mode == "video" or with_video:
            emit(scored(frame, "video", result, seconds[status.index], camera))

    # The box is the object, however few of its pixels changed: it is the frame's one blob.
    video, detect = dataclasses.replace(config.video, max_objects=1), dataclasses.replace(config.detect, min_area_px=1)
    one_at_a_time = dataclasses.replace(config, video=video, detect=detect)
    tracking: Tracking | None = None
    for frame in frames:
        camera = _camera(frame, clip, config)
        tracking = tracking or Tracking(camera, one_at_a_time, FrameBuffer(None, report), refit)
        held[frame.index] = frame
        inputs = _inputs(frame)
        found = box_blobs(inputs, frame.box, config.detect)
        if found.count == 1:
            # Nothing changed there by the detector's threshold: no track goes on into the box,
            # but the fit's own threshold may still find the object in it, fitted cold.
            tracking.restart()
            found = box_blobs(inputs, frame.box, config.detect, whole=True)
        tracking.step(inputs, found)
    if tracking is not None:
        tracking.buffer.close()
    return statuses, camera


def _camera(frame: BenchmarkFrame, clip: SyntheticClip | None, config: Config) -> PinholeCamera:
    """The generator's camera where it is known, else one of the configured field of view."""
    if clip is not None:
        return clip.camera
    height, width = frame.image.shape[:2]
    return PinholeCamera.from_fov(width, height, config.camera.fov_y_deg)


def _scored_row(
    sequence: Sequence,
    frame: BenchmarkFrame,
    mode: str,
    result: FrameResult | None,
    seconds: float,
    camera: PinholeCamera,
    *,
    config: Config,
    clip: SyntheticClip | None,
    on_images: ImageSink | None,
) -> FrameRow:
    """Frame ``frame``'s fit ``result`` scored as a row of ``mode`` (None: no object, all 0)."""
    if result is None:
        return FrameRow(sequence.dataset, sequence.name, frame.index, mode, "no_object", 0.0, 0.0, 0.0, 0.0)
    estimate = estimate_subframes(result, frame, camera, config)
    row = FrameRow(
        sequence.dataset,
        sequence.name,
        frame.index,
        mode,
        result.start,
        seconds=seconds,
        prototype=result.prototype,
        track=None if mode == "per-frame" else result.track,
        **score_frame(frame, result, estimate, camera, clip),
    )
    if on_images is not None:
        on_images(row, frame, estimate)
    return row


def _joint_rows(
    sequence: Sequence,
    statuses: list[FrameStatus],
    fitted: dict[int, tuple[BenchmarkFrame, FrameResult, float]],
    unfitted: list[FrameRow],
    camera: PinholeCamera,
    config: Config,
    device: torch.device,
    clip: SyntheticClip | None,
    on_frame: Callable[[FrameRow], None] | None,
    on_images: ImageSink | None = None,
) -> list[FrameRow]:
    """Fit the windows of the warm-started fits jointly and score every frame as the joint fit
    shows it; a frame's time is its single-frame fit's plus its share of each window's."""
    tracks = {s.index: s.track for s in statuses}
    keys = {i: FrameKey(i, track) for i, track in tracks.items() if track is not None and i in fitted}
    source = MemorySource({key: fitted[i][1] for i, key in keys.items()})
    # Joint mode fits its windows whatever the config's joint.enabled says.
    results = RunResults(statuses, source, dataclasses.replace(config.joint, enabled=True))
    seconds = {i: s for i, (_, _, s) in fitted.items()}
    for window in results.windows:
        members = list(window.frames)
        crops = {}
        for i in members:
            frame, result, _ = fitted[i]
            crops[i] = window_frame(_inputs(frame), frame.box, result, camera, config.crop, device)
        started = time.perf_counter()
        try:
            saved = fit_track_window(
                window.track,
                members,
                crops,
                lambda i: fitted[i][1],
                results.previous(window),
                camera,
                config,
                results.stands_for(window),
            )
        except DivergenceError as exc:
            # Left out, as the pipeline leaves it out: its frames keep their single-frame fits.
            print(f"{sequence.name}: joint fit of frames {members[0]}-{members[-1]} skipped: {exc}", file=sys.stderr)
        else:
            source.add_window(window.key, saved)
        for i in members:
            seconds[i] += (time.perf_counter() - started) / len(members)
    rows = list(unfitted)
    for index, (frame, result, _) in sorted(fitted.items()):
        result, window = results.showing(keys[index], result)
        estimate = estimate_subframes(result, frame, camera, config)
        scores = score_frame(frame, result, estimate, camera, clip)
        start = "joint" if window is not None else result.start
        row = FrameRow(
            sequence.dataset,
            sequence.name,
            index,
            "joint",
            start,
            seconds=seconds[index],
            prototype=result.prototype,
            track=tracks.get(index),
            **scores,
        )
        rows.append(row)
        if on_frame is not None:
            on_frame(row)
        if on_images is not None:
            on_images(row, frame, estimate)
    return sorted(rows, key=lambda r: r.frame)
