"""A newly proven track looks back into the frames before its first for its object inside blobs
other tracks took, and refits the blob's parts."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from sfb_video.config import CropConfig, DetectConfig, TrackConfig, VideoConfig
from sfb_video.crop import Box, crop_box, mask_box
from sfb_video.defmo import INPUT_SIZE
from sfb_video.errors import NoObjectError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.results import FrameKey, FrameResult, load_result
from sfb_video.stages.detect import (
    FrameBlobs,
    share_out,
)
from sfb_video.stages.frame_buffer import FrameBuffer
from sfb_video.stages.tracking.prediction import glide, join, join_gap
from sfb_video.stages.tracking.splitting import Claim
from sfb_video.stages.tracking.tracker import Tracker
from sfb_video.stages.types import Detection, FrameStatus, FrameWithBackground, Prediction, Status

Refit = Callable[[FrameWithBackground, Detection, FrameResult | None, FrameResult | None], FrameResult]
"""Fits a frame's detection warm from a start (and the frame before it), as the stage fits."""


@dataclass
class HeldFit:
    """One track's fit of a blob of a recent frame: its track, the prediction that found it, its
    part of the blob where tracks shared it (in the blob's region), and the fit's warm start and
    the frame before that (:func:`~sfb_video.stages.fit.fit_detection`), to refit it from."""

    tracker: Tracker
    number: int
    prediction: Prediction | None
    part: np.ndarray | None
    start: FrameResult | None
    earlier: FrameResult | None


@dataclass
class Held:
    """A blob that tracks took in a recent frame, kept for a track that starts later to look back
    into (:func:`look_back_into`): its ``region`` of the frame (:func:`held_region`), the frame's
    and background's pixels there, (3, h, w) each, the blob there, (h, w) bool, and its fits."""

    index: int
    shape: tuple[int, int]
    region: Box
    pixels: torch.Tensor
    background: torch.Tensor
    blob: np.ndarray
    fits: list[HeldFit]

    def frame(self) -> FrameWithBackground:
        """The frame as a fit of a part of the blob sees it: its region's pixels in place, the
        rest black (no crop of a part reaches it)."""
        x, y, w, h = self.region
        pixels = self.pixels.new_zeros((3, *self.shape))
        background = self.background.new_zeros((3, *self.shape))
        pixels[:, y : y + h, x : x + w] = self.pixels
        background[:, y : y + h, x : x + w] = self.background
        return FrameWithBackground(self.index, pixels, background)

    def detection(self, part: np.ndarray) -> Detection:
        """The ``part`` (h, w) of the blob as the frame's detection."""
        box = mask_box(part)
        assert box is not None  # share_out gives no empty part
        x, y, w, h = self.region
        mask = torch.zeros(self.shape, dtype=torch.bool)
        mask[y : y + h, x : x + w] = torch.from_numpy(part)
        return Detection(self.index, (box[0] + x, box[1] + y, box[2], box[3]), mask)


def held_region(box: Box, frame_size: tuple[int, int], config: CropConfig) -> Box:
    """The part of a (W, H) frame that holds the crop (:func:`~sfb_video.crop.crop_box`) and the
    DeFMO window (4:3 whatever the crop's aspect) of every box inside ``box``: a box inside is no
    larger, and its centre lies in ``box``, so its crop is no larger than ``box``'s (unclipped by
    the frame) and reaches at most half that past ``box``; at the frame's edge both shift
    inwards alike."""
    x, y, w, h = box
    width, height = frame_size
    defmo = dataclasses.replace(config, margin=config.defmo_margin, aspect=INPUT_SIZE[1] / INPUT_SIZE[0])
    unclipped = [crop_box(box, (1 << 30, 1 << 30), c)[2:] for c in (config, defmo)]
    cw, ch = (max(sizes) for sizes in zip(*unclipped, strict=True))
    rw, rh = min(w + cw + 2, width), min(h + ch + 2, height)  # 2: the crop's rounding
    x0 = math.floor(min(max(x + w / 2 - rw / 2, 0), width - rw))
    y0 = math.floor(min(max(y + h / 2 - rh / 2, 0), height - rh))
    return x0, y0, rw, rh


def held_blobs(
    frame: FrameWithBackground, found: FrameBlobs, fits: list[tuple[Claim, HeldFit]], crop: CropConfig
) -> list[Held]:
    """The blobs that tracks took in ``frame``, with what :func:`look_back_into` needs of them."""
    shape = (int(frame.pixels.shape[1]), int(frame.pixels.shape[2]))
    held: list[Held] = []
    for label in dict.fromkeys(claim.label for claim, _ in fits):
        x, y, w, h = (int(v) for v in found.stats[label, :4])
        rx, ry, rw, rh = region = held_region((x, y, w, h), (shape[1], shape[0]), crop)
        window = (slice(ry, ry + rh), slice(rx, rx + rw))
        blob = found.labels[window] == label
        kept = [
            dataclasses.replace(fit, part=None if claim.part is None else claim.part[window])
            for claim, fit in fits
            if claim.label == label
        ]
        pixels = frame.pixels[(slice(None), *window)].clone()
        background = frame.background_pixels[(slice(None), *window)].clone()
        held.append(Held(frame.index, shape, region, pixels, background, blob, kept))
    return held


def look_back_into(
    tracker: Tracker,
    held: list[list[Held]],
    buffer: FrameBuffer,
    saved: set[tuple[int, int]],
    camera: PinholeCamera,
    detect: DetectConfig,
    track: TrackConfig,
    video: VideoConfig,
    refit: Refit,
) -> None:
    """A track just fitted in enough frames to be kept (:func:`proven_length`) looks back for its object
    in the ``track.look_back`` frames before its first, inside blobs that other tracks, still going,
    took whole (its object had no track yet to share them with): where its streak, moved back at
    its pace in the image, takes enough of such a blob, and the blob is larger by as much than its
    tracks' own of the next frame (``track.look_back_share``), the blob is shared out, each track's
    part refitted in the ``buffer`` (the fit each track went on from kept with it, for a resumed
    run to follow the tracks as this one did), and the track's fit there joins it (warm from its
    next frame, the time run backwards).
    """
    last = tracker.previous
    assert last is not None and tracker.number is not None
    by_index = {blobs[0].index: blobs for blobs in held if blobs}
    mine = sorted((h.index, _area(h, f)) for hs in held for h in hs for f in h.fits if f.tracker is tracker)
    if not mine or mine[0][0] == last.index:
        return
    first = buffer.followed(FrameKey(mine[0][0], tracker.number))
    assert first is not None  # the track's first frame is held
    own_area = mine[0][1]
    later = first
    for index in range(first.index - 1, first.index - 1 - track.look_back, -1):
        prediction = glide(first, last, index, camera)
        best: tuple[float, Held, list[np.ndarray]] | None = None
        for blob in by_index.get(index, []):
            if not any(_goes_on(f, first.index) for f in blob.fits):
                continue
            # A track's first frame was found with no prediction: where its next two put it.
            predicted = [f.prediction or _first_prediction(index, f, buffer, camera) for f in blob.fits]
            ahead = [p for p in predicted if p is not None]
            if len(ahead) < len(predicted):
                continue
            parts = share_out(blob.blob, [*ahead, prediction], detect.min_area_px, blob.region[:2])
            share = 0.0 if parts is None else float(parts[-1].sum())
            # The blob is larger than its tracks' own blobs of the next frame by about this
            # object: not one object's blob that another track's path happens to pass.
            grown = float(blob.blob.sum()) - _areas_after(blob, by_index.get(index + 1, []))
            enough = track.look_back_share * own_area
            if parts is not None and min(share, grown) >= enough and (best is None or share > best[0]):
                best = (share, blob, parts)
        if best is None:
            break
        _, blob, parts = best
        frame = blob.frame()
        fits = [*blob.fits, HeldFit(tracker, tracker.number, prediction, parts[-1], None, None)]
        # A resumed run: every part refitted and written before (a frame stopped midway is refitted).
        found_late = all((index, fit.number) in saved for fit in fits)
        # This track's fit starts warm from its next frame, its time run backwards.
        mirrored = dataclasses.replace(later.reversed(), index=2 * index - later.index)
        starts = [f.start for f in blob.fits] + [mirrored]
        detections = [blob.detection(part) for part in parts]
        try:
            results = [
                _refitted(frame, detection, fit, start, buffer, camera, video, refit, found_late)
                for fit, detection, start in zip(fits, detections, starts, strict=True)
            ]
        except NoObjectError:
            break
        for fit, part, detection, result in zip(fits, parts, detections, results, strict=True):
            fit.part = part
            others = ", ".join(str(f.number) for f in fits if f is not fit)
            note = f"its streak touched track(s) {others}'s: their pixels shared out by nearness, looking back"
            status = FrameStatus(index, Status.FITTED, detection.box, note, fit.number, True)
            buffer.refitted(status, result, found_late)
        blob.fits.append(fits[-1])
        tracker.length += 1
        later = results[-1]


def proven_length(video: VideoConfig) -> int:
    """The frames a track is fitted in before it looks back (:func:`look_back_into`): as many as a
    track needs to be kept (``video.min_track_frames``), at least two (its time direction
    known). A shred that would be dropped does not look back and split another's blob."""
    return max(2, video.min_track_frames)


def _area(blob: Held, fit: HeldFit) -> float:
    """The pixels of ``blob`` that are ``fit``'s (its part, where the blob was shared)."""
    return float((blob.blob if fit.part is None else fit.part).sum())


def _areas_after(blob: Held, following: list[Held]) -> float:
    """The pixels of the blobs of the next frame that ``blob``'s tracks took there; infinite
    where one of them has none (nothing tells how large its object is)."""
    total = 0.0
    for fit in blob.fits:
        areas = [_area(h, f) for h in following for f in h.fits if f.tracker is fit.tracker and f.number == fit.number]
        if not areas:
            return math.inf
        total += areas[0]
    return total


def _refitted(
    frame: FrameWithBackground,
    detection: Detection,
    fit: HeldFit,
    start: FrameResult | None,
    buffer: FrameBuffer,
    camera: PinholeCamera,
    video: VideoConfig,
    refit: Refit,
    found_late: bool,
) -> FrameResult:
    """A track's fit of its part of a blob, found looking back (:func:`look_back_into`), warm from
    ``start``, in the track's time direction (:func:`_joined`); ``found_late``: saved already
    (a resumed run)."""
    if found_late:
        return load_result(FrameKey(frame.index, fit.number).path(buffer.folder))
    result = refit(frame, detection, start, fit.earlier)
    return _joined(dataclasses.replace(result, track=fit.number), fit.start, buffer, camera, video)


def _first_prediction(index: int, fit: HeldFit, buffer: FrameBuffer, camera: PinholeCamera) -> Prediction | None:
    """Where a track's first frame ``index`` (``fit``, found with no prediction) should be by the
    track's next two frames, or None without them."""
    nearer, further = (buffer.followed(FrameKey(index + k, fit.number)) for k in (1, 2))
    if nearer is None or further is None:
        return None
    return glide(nearer, further, index, camera)


def _goes_on(fit: HeldFit, index: int) -> bool:
    """Whether ``fit``'s track still goes on in frame ``index`` or later."""
    return fit.tracker.number == fit.number and fit.tracker.previous is not None and fit.tracker.previous.index >= index


def _joined(
    result: FrameResult, start: FrameResult | None, buffer: FrameBuffer, camera: PinholeCamera, video: VideoConfig
) -> FrameResult:
    """A refitted frame of a track in the track's time direction: joined to the frame it started
    from, or where it started cold (the track's first frame), to the track's next frame."""
    e = video.exposure_fraction
    if start is not None:
        return join(start, result, camera, e, may_flip_previous=False)[1]
    following = buffer.followed(FrameKey(result.index + 1, result.track))
    if following is None:
        return result
    return min((result, result.reversed()), key=lambda r: join_gap(r, following, camera, e))
