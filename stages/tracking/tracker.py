"""A track's life: its predictions, the frames it takes, coasting through merged frames, its end;
the blobs that start new tracks, and the tracks too short to keep."""

from __future__ import annotations

import dataclasses
from collections import Counter
from dataclasses import dataclass

from sfb_video.config import DetectConfig, TrackConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.results import FrameResult
from sfb_video.stages.detect import (
    FrameBlobs,
)
from sfb_video.stages.fit import continued
from sfb_video.stages.tracking.prediction import at_edge, glide, join, lags, predict
from sfb_video.stages.types import FrameStatus, Prediction, Status


def _blend(
    track: tuple[float, float, float] | None, blob: tuple[float, float, float] | None, memory: float
) -> tuple[float, float, float] | None:
    """A track's colour: ``memory`` its own, the rest its newest blob's (one blob that took in a
    piece of the arm holding the ball does not make the track look for skin)."""
    if track is None or blob is None:
        return blob
    r, g, b = (memory * t + (1 - memory) * c for t, c in zip(track, blob, strict=True))
    return r, g, b


@dataclass
class TrackNumbers:
    """The number the next track to start takes (tracks are numbered 0, 1, ... as they start,
    whichever object they follow)."""

    next: int = 0


class Tracker:
    """Which frames form one track, frame after frame: the pipeline's one rule, which the
    evaluation runs too.

    A frame continues the track when its object is found where the track's last frame, its
    motion continued across the gap (turning as it turned), predicts it
    (:func:`~sfb_video.stages.tracking.assignment.match_tracks`, also for a given box:
    :func:`~sfb_video.stages.detect.box_blobs`); the frames then join end to start (:func:`join`),
    which fixes the time direction of a track's first frame. A frame that is not the next one,
    or has no object, ends the track, but for up to ``track.max_coast`` frames in which the
    object's streak merged with another track's (:meth:`coast`) or was shared out with it.

    Attributes:
        previous: the track's last fitted frame (the warm start of the next); earlier: the one
            before it; colour: the chromaticity of the track's blobs; length: its fitted frames;
            number: the track's number (None before its first frame); numbers: where the
            numbers of new tracks come from (shared by the trackers of one clip); detect,
            track: the sections its guesses and its life follow; exposure_fraction: the
            video's (``video.exposure_fraction``).
    """

    def __init__(
        self,
        camera: PinholeCamera,
        detect: DetectConfig,
        track: TrackConfig,
        exposure_fraction: float,
        numbers: TrackNumbers | None = None,
    ) -> None:
        self.camera, self.detect, self.track, self.exposure_fraction = camera, detect, track, exposure_fraction
        self.numbers = TrackNumbers() if numbers is None else numbers
        self.previous: FrameResult | None = None
        self.earlier: FrameResult | None = None
        self.colour: tuple[float, float, float] | None = None
        self.length = 0
        self.number: int | None = None
        self.coasting = 0  # frames since ``previous`` its streak shared or merged with another's

    @property
    def upcoming(self) -> int:
        """The number of the track the next fitted frame joins: this one's, or a new one's."""
        return self.numbers.next if self.previous is None or self.number is None else self.number

    def predictions(self, index: int) -> list[tuple[Prediction, FrameResult]]:
        """Where frame ``index``'s object should be, with the last frame in the direction that
        predicts it: its two directions' guesses while the track's direction is open; from its
        second frame on, its 3D guess and its image-pace guess (the 3D guess a fallback where it
        :func:`lags`), or the image-pace guess alone while it coasts; none without a track that
        goes on into this frame."""
        if self.previous is not None:
            gap = index - self.previous.index
            if gap != 1 + self.coasting:
                self.lose()
        self.earlier = self.earlier if self.length >= 2 else None
        if self.previous is None:
            return []
        if self.coasting and self.earlier is not None:
            return [(self._glided(index), self.previous)]
        options = [self.previous, self.previous.reversed()] if self.length == 1 else [self.previous]
        e = self.exposure_fraction
        predicted = [
            (dataclasses.replace(predict(continued(o, self.earlier, index, e), self.camera), colour=self.colour), o)
            for o in options
        ]
        if self.earlier is not None:
            # A second guess from the image: the last streak moved on at the pace of the last
            # two. One frame's fit is unsure of its speed (a longer object moving less blurs
            # alike) and a falling object gathers speed; each blob is taken by the guess that lands
            # nearer it (:mod:`~sfb_video.stages.tracking.cost`).
            glided = self._glided(index)
            last = predict(self.previous.state.motion, self.camera).centre
            if self._clean_pace() and lags(predicted[0][0], glided, last, self.detect, self.track):
                # The two guesses part: the image pace from two whole streaks is the surer, and
                # the lagging 3D guess would land on whatever lies behind. It is still followed
                # where the pace finds nothing: an object that landed stops.
                three_d, option = predicted[0]
                return [(glided, self.previous), (dataclasses.replace(three_d, fallback=True), option)]
            predicted.append((glided, self.previous))
        return predicted

    def _clean_pace(self) -> bool:
        """Whether the image pace (:meth:`_glided`) comes from two whole streaks: neither box
        touches the frame's edge (a streak cut off there paces the cut, not the object)."""
        assert self.previous is not None and self.earlier is not None
        return not (
            at_edge(self.previous.detection_box, self.camera) or at_edge(self.earlier.detection_box, self.camera)
        )

    def _glided(self, index: int) -> Prediction:
        """Frame ``index``'s prediction past frames without a clean fit: the last clean streak
        moved on in the image at the pace of the last two (:func:`glide`). Over several frames
        this is surer than the 3D motion continued, whose depth speed and turn, a little off,
        carry it far away."""
        assert self.previous is not None and self.earlier is not None
        return dataclasses.replace(glide(self.previous, self.earlier, index, self.camera), colour=self.colour)

    def coast(self) -> None:
        """Keep the track through this frame, where its object's streak merged into another
        track's blob: the next frame is predicted from the track's last clean one, for at most
        ``track.max_coast`` frames of streaks merged or shared."""
        self.coasting += 1
        if self.coasting > self.track.max_coast:
            self.lose()

    def found(self, followed: FrameResult | None) -> FrameResult | None:
        """Take what the assignment found (``match_tracks``): the track's last frame in the
        direction that predicted the object, or None (a new track starts). Returns that frame where
        it was reversed (to be kept so), else None."""
        if followed is None:
            self.lose()
            self.earlier = None
            return None
        if followed is not self.previous:
            self.previous = followed
            return followed
        return None

    def add(
        self, result: FrameResult, colour: tuple[float, float, float] | None, shared: bool = False
    ) -> tuple[int, FrameResult, FrameResult | None]:
        """Add a fitted frame to the track (a new one when none goes on). A ``shared`` frame, whose
        blob was shared out with another track's (:meth:`FrameBlobs.split`), is joined in the
        track's direction but predicts nothing: its fit saw the other object too, and the next
        frame is predicted from the last clean one (as :meth:`coast` does).

        Returns:
            the track's number, ``result`` in the track's time direction (and numbered so), and
            the track's previous frame where joining reversed it (to be kept so), else None.
        """
        if self.previous is None:
            self.number = self.numbers.next
            self.numbers.next += 1
        assert self.number is not None
        if result.track != self.number:
            result = dataclasses.replace(result, track=self.number)
        reversed_previous = None
        if self.previous is not None:
            e = self.exposure_fraction
            before, result = join(self.previous, result, self.camera, e, self.length == 1 and not shared)
            if before is not self.previous:
                reversed_previous = before
        if shared and self.previous is not None:
            self.coast()
            return self.number, result, reversed_previous
        self.colour = _blend(self.colour if self.length else None, colour, self.track.colour_memory)
        self.earlier, self.previous, self.length, self.coasting = self.previous, result, self.length + 1, 0
        return self.number, result, reversed_previous

    def lose(self) -> None:
        """End the track: the next object found starts a new one."""
        self.previous, self.length, self.coasting = None, 0, 0


def new_objects(found: FrameBlobs, taken: set[int], detect: DetectConfig, track: TrackConfig, alone: bool) -> list[int]:
    """The labels of the blobs no track took that are objects of their own, largest first.

    Beside another track (when ``alone``, no track live, every blob but the largest; otherwise
    every one), a blob must also be an object of its own by :meth:`FrameBlobs.own_object` (not
    an arm's shred, not a shadow)."""
    areas = [found.area(k) for k in range(1, found.count)]
    floor = max(detect.min_area_px, track.other_share * max(areas, default=0.0))
    fresh = [k for k in range(1, found.count) if k not in taken and found.area(k) >= floor]
    fresh.sort(key=lambda k: (-found.area(k), k))
    return [k for n, k in enumerate(fresh) if (alone and n == 0) or found.own_object(k)]


def short_tracks_dropped(statuses: list[FrameStatus], least: int) -> list[FrameStatus]:
    """``statuses`` with every track fitted in fewer than ``least`` frames ``dropped`` (its fits
    stay saved, for a resumed run to reuse), unless no track is longer: then the longest is kept."""
    lengths = Counter(s.track for s in statuses if s.status == Status.FITTED)
    kept = {t for t, n in lengths.items() if n >= least}
    if lengths and not kept:
        kept = {min(lengths, key=lambda t: (-lengths[t], t))}
    out = []
    for s in statuses:
        if s.track is not None and s.track not in kept and s.status in (Status.FITTED, Status.MERGED):
            note = f"track {s.track} was fitted in {lengths[s.track]} frame(s), fewer than video.min_track_frames"
            s = dataclasses.replace(s, status=Status.DROPPED, note=note)
        out.append(s)
    return out
