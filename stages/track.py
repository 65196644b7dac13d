"""Tracking: which blob of each frame is the object, which frames form one track, and which way
time runs through them.

Frames stream through with their difference masks. Each frame's object is looked for near
where the track's last fit predicts it (its motion continued across the gap between exposures,
:func:`predict`); nothing near starts a new track. Each detection is fitted (warm from the
track's last frame) and written into the run folder once no later frame can change it
(:class:`~sfb_video.stages.frame_buffer.FrameBuffer`), which is what a resumed run reuses.
One frame cannot tell which end of its streak came first (DeFMO's sub-frame masks order a frame,
but may run either way themselves): :func:`join` picks the directions that make consecutive
frames meet end to start, and that order between frames wins over DeFMO's.

Where several objects' streaks touch, their blob is shared out among their tracks by nearness
to their predicted streaks; an object whose streak lay inside another's blob before it had a
track of its own is found there when its track, fitted in enough frames to be kept, looks back.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
import torch

from sfb_video.config import Config, CropConfig
from sfb_video.crop import Box, box_mask, crop_box, mask_box
from sfb_video.defmo import INPUT_SIZE
from sfb_video.errors import NoObjectError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.motion import Motion, continue_motion
from sfb_video.results import FrameKey, FrameResult, load_followed, load_result
from sfb_video.run_folder import frame_path, saved_frames
from sfb_video.stages.detect import (
    FrameBlobs,
    Neighbour,
    blob_colour,
    difference_mask,
    frame_blobs,
    gate_distance,
    moving_mask,
    parallel,
    pick_blob,
    share_out,
    still_there,
)
from sfb_video.stages.fit import continued, fit_detection
from sfb_video.stages.frame_buffer import FrameBuffer, Pending, StepReport
from sfb_video.stages.masks import MaskSource
from sfb_video.stages.register import mask_onto_next, segment_of, usable
from sfb_video.stages.types import Detection, Frame, FrameStatus, FrameWithBackground, Prediction, Status

T = TypeVar("T")


def predict(motion: Motion, camera: PinholeCamera) -> Prediction:
    """Where ``motion``'s streak appears in ``camera``: the centre of its middle, its diameter
    and its ends."""
    uv, depth = camera.project(torch.stack((motion.x0 + 0.5 * motion.dx, motion.x0, motion.x0 + motion.dx)))
    ends = ((float(uv[1, 0]), float(uv[1, 1])), (float(uv[2, 0]), float(uv[2, 1])))
    return Prediction((float(uv[0, 0]), float(uv[0, 1])), float(camera.fy / depth[0]), ends=ends)


def join_gap(previous: FrameResult, current: FrameResult, camera: PinholeCamera, exposure_fraction: float) -> float:
    """Pixels between where ``current``'s exposure starts and where ``previous``'s motion,
    continued at constant velocity across the gap, puts that start."""
    predicted = continue_motion(previous.state.motion, current.index - previous.index, exposure_fraction)
    uv = camera.project(torch.stack((predicted.x0, current.state.motion.x0)))[0]
    return float((uv[0] - uv[1]).norm())


def ray_gap(
    previous: FrameResult, current: FrameResult, camera: PinholeCamera, min_exposure_fraction: float = 0.2
) -> float:
    """Pixels between where ``current``'s exposure starts and the segment on which
    ``previous``'s streak goes on past its end for any exposure fraction down to
    ``min_exposure_fraction``: the join gap where the shutter is not known (a short one leaves a
    long gap between streaks; e leaves 1 / e - 1 streak lengths)."""
    motion = previous.state.motion
    uv = camera.project(torch.stack((motion.x0, motion.x0 + motion.dx, current.state.motion.x0)))[0]
    direction = uv[1] - uv[0]
    along = float(((uv[2] - uv[1]) @ direction) / direction.square().sum().clamp_min(1e-12))
    gaps = (current.index - previous.index) / min_exposure_fraction - 1
    return float((uv[2] - uv[1] - min(max(along, 0.0), gaps) * direction).norm())


def join(
    previous: FrameResult,
    current: FrameResult,
    camera: PinholeCamera,
    exposure_fraction: float,
    may_flip_previous: bool,
) -> tuple[FrameResult, FrameResult]:
    """Choose the time directions of two frames of one track so that they join end to start.

    The current frame's start should be where the previous frame's motion, continued across the
    gap, puts it (in image pixels, where the fit is surest). The previous frame may be reversed
    too when nothing before it fixed its direction (the first frame of a track).

    Returns:
        previous and current, each possibly reversed.
    """
    options = [(p, c) for p in (previous, previous.reversed()) for c in (current, current.reversed())]
    if not may_flip_previous:
        options = options[:2]
    return min(options, key=lambda pc: join_gap(pc[0], pc[1], camera, exposure_fraction))


def with_neighbours(
    frames: Iterator[FrameWithBackground], config: Config
) -> Iterator[tuple[FrameWithBackground, torch.Tensor, list[Neighbour]]]:
    """Each frame with its difference mask and its neighbours (:class:`~sfb_video.stages.detect.Neighbour`): the
    frames two before and two after (at a clip's ends, two and three away on its one side).

    Two frames apart, not one: an FMO's streaks in consecutive frames can overlap (it moves
    little more than its size while the shutter is open), but never two frames apart, while a
    slow mover still covers much the same pixels. At a clip's ends only one side has a frame two
    away (the adjacent frame's streak would cut off this one's end), and the frame three away on
    that side joins it: one frame alone drops whatever passes there two frames later, as an
    object following another along its path does, while a slow mover covers both (and a change
    of the scene still shows in both later frames). Only a clip of three frames or fewer falls
    back on the adjacent frames.
    """
    # Frames t - 3 .. t - 1: their registrations and masks only (not their pixels).
    history: deque[tuple[Frame, torch.Tensor]] = deque(maxlen=3)
    ahead: deque[tuple[FrameWithBackground, torch.Tensor]] = deque()  # frame t and up to three after

    def emit() -> tuple[FrameWithBackground, torch.Tensor, list[Neighbour]]:
        frame, mask = ahead.popleft()

        # A moving camera's frames of another reference, or that did not register, are not
        # this frame's neighbours: as at a clip's ends.
        def kin(other: tuple[Frame | FrameWithBackground, torch.Tensor]) -> bool:
            return segment_of(other[0]) == segment_of(frame) and usable(other[0])

        def earlier_mask(other: tuple[Frame, torch.Tensor]) -> torch.Tensor | None:
            if kin(other):
                return other[1]
            # The camera panned on to this frame's reference: the frames before it still show
            # where the object was, their masks drawn here, so that a reference's first frame
            # is not cut short by a later frame's streak alone, as a clip's first frame is.
            if segment_of(other[0]) + 1 == segment_of(frame) and usable(other[0]):
                return mask_onto_next(other[0], other[1])
            return None

        # By distance from this frame; None where a frame is of another reference or did not
        # register (as at a clip's ends).
        earlier = [earlier_mask(h) for h in reversed(history)]  # frames t - 1 .. t - 3
        after = [f if kin(f) else None for f in ahead]  # frames t + 1 .. t + 3
        before, later = _present(earlier[1:2]), _present(after[1:2])
        if not before and not later:  # the frames two away did not register
            before, later = _present(earlier[2:3]), _present(after[2:3])
        if not before and not later:  # a clip of three frames or fewer
            before, later = _present(earlier[:1]), _present(after[:1])
        elif not later:
            before = _present(earlier[1:3])
        elif not before:
            later = _present(after[1:3])
        history.append((Frame(frame.index, torch.empty(0), frame.registered), mask))
        # Only what still shows in a later frame is a scene change: a track that passes the same
        # place twice (a circular swing) shows the object where an earlier frame had it. A
        # change stays: with two later frames, it still shows in both.
        stills = [still_there(frame.pixels, frame.background_pixels, f.pixels) for f, _ in later]
        if len(stills) == 2:
            stills = [stills[0] & stills[1]] * 2
        return (
            frame,
            mask,
            [
                *(Neighbour(m, torch.zeros_like(m)) for m in before),
                *(Neighbour(m, still) for (_, m), still in zip(later, stills, strict=True)),
            ],
        )

    for frame in frames:
        ahead.append((frame, difference_mask(frame.pixels, frame.background_pixels, config.detect, frame.known)))
        if len(ahead) == 4:
            yield emit()
    while ahead:
        yield emit()


def _present(items: list[T | None]) -> list[T]:
    return [item for item in items if item is not None]


def follow(
    found: FrameBlobs,
    predictions: list[tuple[Prediction, FrameResult]],
    config: Config,
    taken: frozenset[int] = frozenset(),
    fallback: bool = True,
) -> tuple[tuple[int, int], FrameResult, Prediction] | None:
    """Find a track's object among a frame's blobs but the ``taken`` ones (other tracks'), near
    where the track predicts it (:meth:`Tracker.predictions`).

    Of several predictions (the two directions of a track's first frame, or its 3D and image-pace
    guesses), the one whose prediction lands nearer its blob is kept; a ``fallback`` prediction
    only where the others find no blob (and not at all with ``fallback`` False: a second look,
    past the blob the first found, keeps to the guesses that found it). Blobs of the track's
    colour are preferred.

    Returns:
        the blob (its label and how many others could have been it, :func:`pick_blob`), the
        track's last frame in the direction that predicted it and that prediction; None when no
        blob is near.
    """
    best: tuple[float, tuple[int, int], FrameResult, Prediction] | None = None
    for tier in (False, True) if fallback else (False,):
        for prediction, option in predictions:
            picked = None if prediction.fallback != tier else pick_blob(found, prediction, config.detect, taken)
            if picked is not None:
                distance = _miss(found, picked[0], prediction)
                if best is None or distance < best[0]:
                    best = (distance, picked, option, prediction)
        if best is not None:
            break
    return None if best is None else (best[1], best[2], best[3])


def _miss(found: FrameBlobs, label: int, prediction: Prediction) -> float:
    """How far blob ``label``'s box centre lies from ``prediction``'s, in pixels."""
    x, y, w, h = (float(v) for v in found.stats[label, :4])
    return math.hypot(x + w / 2 - prediction.centre[0], y + h / 2 - prediction.centre[1])


def _miss_diameters(found: FrameBlobs, followed: tuple[tuple[int, int], FrameResult, Prediction] | None) -> float:
    """:func:`_miss` of a :func:`follow` result in its object's diameters (inf: no blob)."""
    if followed is None:
        return math.inf
    return _miss(found, followed[0][0], followed[2]) / max(followed[2].diameter, 1.0)


def _second_miss(
    found: FrameBlobs,
    predictions: list[tuple[Prediction, FrameResult]],
    wanted: tuple[tuple[int, int], FrameResult, Prediction] | None,
    config: Config,
) -> float:
    """How far, in its object's diameters, the blob a track would take were the one it wants
    (``wanted``, :func:`follow`) taken lies from the prediction that finds it (inf: none would)."""
    if wanted is None:
        return math.inf
    return _miss_diameters(found, follow(found, predictions, config, frozenset({wanted[0][0]}), wanted[2].fallback))


def _choosing_order(
    found: FrameBlobs,
    wants: list[tuple[Tracker, tuple[tuple[int, int], FrameResult, Prediction] | None]],
    elsewhere: list[float] | None = None,
    *,
    gate: float,
) -> list[int]:
    """The order in which tracks choose their blobs (indices into ``wants``: each track and the
    blob it would take, :func:`follow`): longer tracks first, their predictions being the
    surest, but of tracks that would take the same blob, the one first whose taking it lands
    them all nearest their blobs, at the place of the longest of them: its prediction's miss
    plus the others' misses of the blobs they would take instead (``elsewhere``, for each track,
    in its object's diameters, :func:`_second_miss`; None: none would take another), one that
    would take none counting as a miss at the ``gate``'s edge, and the nearer prediction first
    of equals. A track of one frame does not go first beside a longer one that would find no
    other blob. The others of them keep their own places (the cases behind each rule:
    ``benchmarks/RESULTS.md``, several objects)."""

    miss = [_miss_diameters(found, w) for _, w in wants]
    # A track that would take no blob is a group of its own.
    group = [(-1 - k) if w is None else w[0][0] for k, (_, w) in enumerate(wants)]
    others = elsewhere or [math.inf] * len(wants)
    longest: dict[int, int] = {}
    members: dict[int, list[int]] = {}
    for k, (tracker, _) in enumerate(wants):
        longest[group[k]] = max(longest.get(group[k], 0), tracker.length)
        members.setdefault(group[k], []).append(k)
    nearest: dict[int, int] = {}
    for g, ks in members.items():
        # A track of one frame guesses its direction: it comes after a longer one that would
        # lose its object.
        held = any(wants[k][0].length >= 2 and others[k] == math.inf for k in ks)
        sure = [k for k in ks if not (held and wants[k][0].length < 2)]
        nearest[g] = min(sure, key=lambda k: (miss[k] + sum(min(others[j], gate) for j in ks if j != k), miss[k], k))

    def place(k: int) -> int:
        return longest[group[k]] if nearest[group[k]] == k else wants[k][0].length

    return sorted(range(len(wants)), key=lambda k: (-place(k), nearest[group[k]] != k, miss[k], -wants[k][0].length, k))


def _goes_elsewhere(
    found: FrameBlobs,
    wanted: tuple[tuple[int, int], FrameResult, Prediction],
    rest: tuple[tuple[int, int], FrameResult, Prediction] | None,
    first_choices: set[int],
) -> bool:
    """Whether a track whose ``wanted`` blob another track took first takes the best blob left
    (``rest``, :func:`follow`) rather than share the taken one: where ``rest`` lands nearer its
    prediction (the other only passed near: the lead's shred, the trail's blob where the lead
    was), or no track wants it first (``first_choices``) and a guess that is no fallback found it."""
    if rest is None:
        return False
    nearer = _miss(found, rest[0][0], rest[2]) < _miss(found, wanted[0][0], wanted[2])
    return nearer or (rest[0][0] not in first_choices and not rest[2].fallback)


def follow_box(
    frame: FrameWithBackground, box: Box, predictions: list[tuple[Prediction, FrameResult]], config: Config
) -> tuple[Detection, FrameResult | None]:
    """:func:`follow` for an object whose box is given (a benchmark hands it over): the box's
    changed pixels are its blob, and the track goes on where that blob passes the same gate
    (:func:`~sfb_video.stages.detect.gate_distance`) as a detected one would.

    Returns:
        the box's detection (its mask the whole box, as a fit of a handed-over box uses it) and
        the track's last frame in the direction that predicted it, or None.
    """
    x, y, w, h = box
    changed = difference_mask(frame.pixels, frame.background_pixels, config.detect, frame.known)[y : y + h, x : x + w]
    blob = box_mask(box, frame.pixels.shape[1:])
    ys, xs = torch.nonzero(changed, as_tuple=True)
    if xs.numel() == 0:
        return Detection(frame.index, box, blob), None
    inside = torch.zeros_like(blob)
    inside[y : y + h, x : x + w] = changed
    colour = blob_colour(frame.pixels.cpu().numpy(), frame.background_pixels.cpu().numpy(), inside.numpy())
    detection = Detection(frame.index, box, blob, 0, colour)
    centre = (x + float(xs.double().mean()), y + float(ys.double().mean()))
    best: tuple[float, FrameResult] | None = None
    for prediction, option in predictions:
        if gate_distance(prediction, centre, (w, h), float(xs.numel()), config.detect) is None:
            continue
        distance = math.hypot(x + w / 2 - prediction.centre[0], y + h / 2 - prediction.centre[1])
        if best is None or distance < best[0]:
            best = (distance, option)
    return detection, None if best is None else best[1]


def lags(three_d: Prediction, paced: Prediction, last: tuple[float, float], config: Config) -> bool:
    """Whether the 3D guess falls short of the image-pace guess along the pace's line: more than
    ``track.lag_diameters`` of the object's diameters from it, and either hardly on from the
    ``last`` streak's centre (under one diameter), or on from it the pace's way, less far, and
    parallel to its line (``detect.parallel_deg``: a ball swung on a circle, where the 3D guess
    turns as the object turned, and the pace does not)."""
    gap = math.hypot(three_d.centre[0] - paced.centre[0], three_d.centre[1] - paced.centre[1])
    if gap <= config.track.lag_diameters * max(paced.diameter, 1.0):
        return False
    step = np.subtract(three_d.centre, last)
    pace = np.subtract(paced.centre, last)
    if np.linalg.norm(step) < max(paced.diameter, 1.0):
        return True  # hardly on from the last streak: its direction says nothing
    on = float(step @ pace) > 0 and np.linalg.norm(step) < np.linalg.norm(pace)
    return on and parallel(step / np.linalg.norm(step), pace / np.linalg.norm(pace), config.detect.parallel_deg)


def _at_edge(box: Box, camera: PinholeCamera) -> bool:
    """Whether ``box`` (x, y, w, h) touches the edge of ``camera``'s image."""
    x, y, w, h = box
    return x <= 0 or y <= 0 or x + w >= camera.width or y + h >= camera.height


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
    motion continued across the gap (turning as it turned), predicts it (:func:`follow`, or
    :func:`follow_box` for a given box); the frames then join end to start (:func:`join`),
    which fixes the time direction of a track's first frame. A frame that is not the next one,
    or has no object, ends the track, but for up to ``track.max_coast`` frames in which the
    object's streak merged with another track's (:meth:`coast`) or was shared out with it.

    Attributes:
        previous: the track's last fitted frame (the warm start of the next); earlier: the one
            before it; colour: the chromaticity of the track's blobs; length: its fitted frames;
            number: the track's number (None before its first frame); numbers: where the
            numbers of new tracks come from (shared by the trackers of one clip).
    """

    def __init__(self, camera: PinholeCamera, config: Config, numbers: TrackNumbers | None = None) -> None:
        self.camera, self.config = camera, config
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
        e = self.config.video.exposure_fraction
        predicted = [
            (dataclasses.replace(predict(continued(o, self.earlier, index, e), self.camera), colour=self.colour), o)
            for o in options
        ]
        if self.earlier is not None:
            # A second guess from the image: the last streak moved on at the pace of the last
            # two. One frame's fit is unsure of its speed (a longer object moving less blurs
            # alike) and a falling object gathers speed; follow keeps the guess whose blob lands
            # nearer.
            glided = self._glided(index)
            last = predict(self.previous.state.motion, self.camera).centre
            if self._clean_pace() and lags(predicted[0][0], glided, last, self.config):
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
            _at_edge(self.previous.detection_box, self.camera) or _at_edge(self.earlier.detection_box, self.camera)
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
        if self.coasting > self.config.track.max_coast:
            self.lose()

    def found(self, followed: FrameResult | None) -> FrameResult | None:
        """Take what :func:`follow` found: the track's last frame in the direction that predicted
        the object, or None (a new track starts). Returns that frame where it was reversed (to be
        kept so), else None."""
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
            e = self.config.video.exposure_fraction
            before, result = join(self.previous, result, self.camera, e, self.length == 1 and not shared)
            if before is not self.previous:
                reversed_previous = before
        if shared and self.previous is not None:
            self.coast()
            return self.number, result, reversed_previous
        self.colour = _blend(self.colour if self.length else None, colour, self.config.track.colour_memory)
        self.earlier, self.previous, self.length, self.coasting = self.previous, result, self.length + 1, 0
        return self.number, result, reversed_previous

    def lose(self) -> None:
        """End the track: the next object found starts a new one."""
        self.previous, self.length, self.coasting = None, 0, 0


def _new_objects(found: FrameBlobs, taken: set[int], config: Config, alone: bool) -> list[int]:
    """The labels of the blobs no track took that are objects of their own, largest first.

    Beside another track (when ``alone``, no track live, every blob but the largest; otherwise
    every one), a blob must also be an object of its own by :meth:`FrameBlobs.own_object` (not
    an arm's shred, not a shadow)."""
    areas = [found.area(k) for k in range(1, found.count)]
    floor = max(config.detect.min_area_px, config.track.other_share * max(areas, default=0.0))
    fresh = [k for k in range(1, found.count) if k not in taken and found.area(k) >= floor]
    fresh.sort(key=lambda k: (-found.area(k), k))
    return [k for n, k in enumerate(fresh) if (alone and n == 0) or found.own_object(k)]


def track_and_fit(
    frames: Iterator[FrameWithBackground],
    folder: Path,
    camera: PinholeCamera,
    config: Config,
    device: torch.device,
    masks: MaskSource | None = None,
    report: StepReport | None = None,
) -> list[FrameStatus]:
    """Detect and fit every object of every frame, writing each fit into the run ``folder`` once
    no later frame can change it; fits already written there are reused.

    Every fast mover has its own track (at most ``video.max_objects`` at once; 0: all). In each
    frame the tracks look for their objects first, each among the blobs that no other has
    taken, in :func:`_choosing_order` (longest first, but of those that would take one blob the
    one whose taking it lands them all nearest, a track of one frame after longer ones); one
    whose blob was taken goes to a blob left (:func:`_goes_elsewhere`) or shares it; the blobs left that
    are objects of their own (``track.other_share``,
    :meth:`~sfb_video.stages.detect.FrameBlobs.own_object`) start new tracks, largest first;
    the other pieces left of a track's streak, split off as objects beside it, go back to it
    (:func:`_on_its_streak`).
    A track fitted in enough frames to be kept looks back for its object inside other tracks'
    blobs of the frames before its first (:func:`_look_back`). ``masks`` gives each fit its sub-frame
    masks (None: the difference mask).

    Returns:
        the status of every object of every frame read (one ``no_object`` status for a frame
        without any), in frame order, then track order.
    """
    saved = saved_frames(folder)
    held: deque[list[_Held]] = deque(maxlen=config.track.look_back + _proven(config) + 1)
    numbers = TrackNumbers()
    live: list[Tracker] = []
    limit = config.video.max_objects or math.inf
    # One track at a time: none starts beside another to look back.
    looks_back = limit > 1 and config.track.look_back > 0
    buffer = FrameBuffer(folder, report)
    segment = 0
    for frame, mask, neighbours in with_neighbours(frames, config):
        if segment_of(frame) != segment:
            # A new reference frame: the tracks' positions were in the last one's coordinates.
            live, segment = [], segment_of(frame)
        if not usable(frame):
            live = []
            buffer.add(frame.index, [Pending(FrameStatus(frame.index, Status.FAILED, note=frame.registered.note))])
            buffer.write_before(frame.index + 1 - len(held))
            continue
        moving = moving_mask(mask, neighbours, config.detect)
        found = frame_blobs(moving, config.detect, (frame.pixels, frame.background_pixels), mask)
        taken: set[int] = set()
        objects: list[_Claim] = []
        merged: list[tuple[Tracker, int]] = []
        asked = [(t, t.predictions(frame.index)) for t in live]
        wants = [(t, follow(found, p, config)) for t, p in asked]
        elsewhere = [_second_miss(found, p, w, config) for (_, p), (_, w) in zip(asked, wants, strict=True)]
        wanted = {w[0][0] for _, w in wants if w is not None}
        for k in _choosing_order(found, wants, elsewhere, gate=config.detect.gate):
            (tracker, predictions), followed = asked[k], wants[k][1]
            claim = None
            if followed is not None and followed[0][0] in taken:
                # Its best blob is another track's too: their streaks touch or cross. The best
                # blob left where it is this track's object; else shared out if it can be; else
                # the best blob left all the same, or none (the track coasts).
                rest = follow(found, predictions, config, frozenset(taken), followed[2].fallback)
                if _goes_elsewhere(found, followed, rest, wanted):
                    followed = rest
                elif (claim := _shared(found, followed, objects, tracker, config)) is None:
                    crossing, followed = followed, rest
                    # A track of one frame, its direction unknown, ends here: coasting, it went
                    # on through other tracks' blobs (a slow box's shred took the pen's blob).
                    if followed is None and tracker.length >= 2:
                        tracker.coast()
                        merged.append((tracker, crossing[0][0]))
                        continue
            if followed is None:
                tracker.found(None)
                continue
            (label, others), option, prediction = followed
            reversed_first = tracker.found(option)
            if reversed_first is not None:
                buffer.directed(reversed_first)  # the track's first frame, found to run the other way
            taken.add(label)
            objects.append(claim or _Claim(tracker, label, others, prediction))
        live = [t for t in live if t.previous is not None]
        fresh = _new_objects(found, taken, config, alone=not live)
        # A piece that no track wants and that is no object of its own may be a track's.
        free = {k for k in range(1, found.count) if k not in taken and k not in wanted and k not in fresh}
        for claim in objects:
            if pieces := _on_its_streak(found, claim, free):
                found.merge(claim.label, pieces)
                free -= set(pieces)
        room = max(0, int(min(limit, len(fresh) + len(live)) - len(live)))
        objects += [_Claim(Tracker(camera, config, numbers), label, 0, None) for label in fresh[:room]]
        untracked = len(fresh) - room
        owner = {c.label: c.tracker for c in objects}
        results: list[Pending] = []
        fits: list[tuple[_Claim, _HeldFit]] = []
        proven: list[Tracker] = []
        for claim in objects:
            tracker, label = claim.tracker, claim.label
            detection = found.detection(frame.index, label, claim.others, claim.part)
            key = (frame.index, tracker.upcoming)
            loaded = load_followed(frame_path(folder, *key)) if key in saved else None
            note = f"{untracked} other moving object(s) seen, not tracked (video.max_objects)" if untracked else ""
            crossed = [t for t, lab in merged if lab == label and t.number is not None]
            if crossed:
                note = f"its streak merged with track(s) {', '.join(str(t.number) for t in crossed)}'s"
            if claim.shared_with:
                others = ", ".join(str(t.number) for t in claim.shared_with)
                note = f"its streak touched track(s) {others}'s: their pixels shared out by nearness"
            start = tracker.previous if config.video.warm_start else None
            before = tracker.earlier
            try:
                result = loaded or fit_detection(frame, detection, camera, config, start, device, masks, before)
            except NoObjectError as exc:
                tracker.lose()
                results.append(Pending(FrameStatus(frame.index, Status.NO_OBJECT, detection.box, str(exc))))
            else:
                shared = bool(claim.shared_with)
                track, result, reversed_previous = tracker.add(result, detection.colour, shared)
                if reversed_previous is not None:
                    buffer.reoriented(reversed_previous)
                if tracker not in live:
                    live.append(tracker)
                status = FrameStatus(frame.index, Status.FITTED, detection.box, note, track, shared)
                results.append(Pending(status, result, saved=result is loaded))
                fits.append((claim, _HeldFit(tracker, track, claim.prediction, claim.part, start, before)))
                if not shared and tracker.length == _proven(config):
                    proven.append(tracker)
        for tracker, label in merged:
            if tracker.previous is not None:
                into = owner[label].number
                note = f"its streak merged into track {into}'s"
                results.append(Pending(FrameStatus(frame.index, Status.MERGED, None, note, tracker.number)))
        buffer.add(frame.index, results or [Pending(FrameStatus(frame.index, Status.NO_OBJECT))])
        if looks_back:
            held.append(_held_blobs(frame, found, fits, config))
        for tracker in proven:
            _look_back(tracker, list(held), buffer, saved, camera, config, device, masks)
        # A frame may change while a track's look back can reach it (the frames ``held``), and a
        # track's first frame until its second fixes its time direction.
        opened = any(t.length == 1 and t.previous is not None and t.previous.index == frame.index for t in live)
        buffer.write_before(frame.index + 1 - max(len(held), int(opened)))
    return short_tracks_dropped(buffer.close(), config.video.min_track_frames)


@dataclass
class _Claim:
    """A track's claim on a blob of one frame: the blob, how many others could have been its
    object, the prediction that found it, and where tracks' streaks touch in it, the part of it
    that is this track's (:meth:`FrameBlobs.split`) and the tracks it was shared with."""

    tracker: Tracker
    label: int
    others: int
    prediction: Prediction | None
    part: np.ndarray | None = None
    shared_with: list[Tracker] = dataclasses.field(default_factory=list)


def _on_its_streak(found: FrameBlobs, claim: _Claim, free: set[int]) -> list[int]:
    """The other pieces of the blob that ``claim``'s was split from as objects beside each other
    (:func:`~sfb_video.stages.detect.side_by_side`), among the ``free`` blobs (no track took them
    or wants them first, and no object of its own, :func:`_new_objects`), that lie on its track's
    predicted streak rather than beside it: their centres within half its object's diameter of
    the line along the predicted motion through its blob's (a thin streak split in two cores end
    to end). An object beside another still starts its own track where it lies in the other's
    predicted streak: young tracks' predicted diameters run large."""
    prediction = claim.prediction
    if found.joined is None or claim.part is not None or prediction is None or prediction.ends is None:
        return []
    (ax, ay), (bx, by) = prediction.ends
    length = math.hypot(bx - ax, by - ay)
    if length < 1.0:
        return []
    across = np.array((ay - by, bx - ax)) / length
    siblings = np.flatnonzero(found.joined == found.joined[claim.label])
    # The claim's own blob is taken, so not free.
    apart = np.abs((found.centroids[siblings] - found.centroids[claim.label]) @ across)
    return [int(k) for k, d in zip(siblings, apart, strict=True) if k in free and d <= prediction.diameter / 2]


def _shared(
    found: FrameBlobs,
    crossing: tuple[tuple[int, int], FrameResult, Prediction],
    claims: list[_Claim],
    tracker: Tracker,
    config: Config,
) -> _Claim | None:
    """Where ``tracker``'s object is in a blob other tracks took first (their streaks touch or
    cross), the blob shared out among them all by nearness to their predicted streaks: this
    track's claim, the others' narrowed to their own parts. None where it cannot be shared (one
    of them has no prediction, or a part would be too small), or where ``tracker`` or one of
    them is a track of one frame, which only guesses its direction: then the track takes the
    best blob left, or coasts through the frame (a track of one frame ends). Three or more tracks
    may share one blob."""
    (label, _), _, prediction = crossing
    first = [c for c in claims if c.label == label]
    if tracker.length < 2 or any(c.tracker.length < 2 for c in first):
        return None
    predicted = [c.prediction for c in first if c.prediction is not None]
    if len(predicted) < len(first):
        return None
    parts = found.split(label, [*predicted, prediction], config.detect.min_area_px)
    if parts is None:
        return None
    for claim, part in zip(first, parts, strict=False):
        claim.part = part
        claim.shared_with = [*claim.shared_with, tracker]
    return _Claim(tracker, label, 0, prediction, parts[-1], [c.tracker for c in first])


@dataclass
class _HeldFit:
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
class _Held:
    """A blob that tracks took in a recent frame, kept for a track that starts later to look back
    into (:func:`_look_back`): its ``region`` of the frame (:func:`held_region`), the frame's
    and background's pixels there, (3, h, w) each, the blob there, (h, w) bool, and its fits."""

    index: int
    shape: tuple[int, int]
    region: Box
    pixels: torch.Tensor
    background: torch.Tensor
    blob: np.ndarray
    fits: list[_HeldFit]

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


def _held_blobs(
    frame: FrameWithBackground, found: FrameBlobs, fits: list[tuple[_Claim, _HeldFit]], config: Config
) -> list[_Held]:
    """The blobs that tracks took in ``frame``, with what :func:`_look_back` needs of them."""
    shape = (int(frame.pixels.shape[1]), int(frame.pixels.shape[2]))
    held: list[_Held] = []
    for label in dict.fromkeys(claim.label for claim, _ in fits):
        x, y, w, h = (int(v) for v in found.stats[label, :4])
        rx, ry, rw, rh = region = held_region((x, y, w, h), (shape[1], shape[0]), config.crop)
        window = (slice(ry, ry + rh), slice(rx, rx + rw))
        blob = found.labels[window] == label
        kept = [
            dataclasses.replace(fit, part=None if claim.part is None else claim.part[window])
            for claim, fit in fits
            if claim.label == label
        ]
        pixels = frame.pixels[(slice(None), *window)].clone()
        background = frame.background_pixels[(slice(None), *window)].clone()
        held.append(_Held(frame.index, shape, region, pixels, background, blob, kept))
    return held


def _look_back(
    tracker: Tracker,
    held: list[list[_Held]],
    buffer: FrameBuffer,
    saved: set[tuple[int, int]],
    camera: PinholeCamera,
    config: Config,
    device: torch.device,
    masks: MaskSource | None,
) -> None:
    """A track just fitted in enough frames to be kept (:func:`_proven`) looks back for its object
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
    for index in range(first.index - 1, first.index - 1 - config.track.look_back, -1):
        prediction = glide(first, last, index, camera)
        best: tuple[float, _Held, list[np.ndarray]] | None = None
        for blob in by_index.get(index, []):
            if not any(_goes_on(f, first.index) for f in blob.fits):
                continue
            # A track's first frame was found with no prediction: where its next two put it.
            predicted = [f.prediction or _first_prediction(index, f, buffer, camera) for f in blob.fits]
            ahead = [p for p in predicted if p is not None]
            if len(ahead) < len(predicted):
                continue
            parts = share_out(blob.blob, [*ahead, prediction], config.detect.min_area_px, blob.region[:2])
            share = 0.0 if parts is None else float(parts[-1].sum())
            # The blob is larger than its tracks' own blobs of the next frame by about this
            # object: not one object's blob that another track's path happens to pass.
            grown = float(blob.blob.sum()) - _areas_after(blob, by_index.get(index + 1, []))
            enough = config.track.look_back_share * own_area
            if parts is not None and min(share, grown) >= enough and (best is None or share > best[0]):
                best = (share, blob, parts)
        if best is None:
            break
        _, blob, parts = best
        frame = blob.frame()
        fits = [*blob.fits, _HeldFit(tracker, tracker.number, prediction, parts[-1], None, None)]
        # A resumed run: every part refitted and written before (a frame stopped midway is refitted).
        found_late = all((index, fit.number) in saved for fit in fits)
        # This track's fit starts warm from its next frame, its time run backwards.
        mirrored = dataclasses.replace(later.reversed(), index=2 * index - later.index)
        starts = [f.start for f in blob.fits] + [mirrored]
        detections = [blob.detection(part) for part in parts]
        try:
            results = [
                _refitted(frame, detection, fit, start, buffer, camera, config, device, masks, found_late)
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


def _proven(config: Config) -> int:
    """The frames a track is fitted in before it looks back (:func:`_look_back`): as many as a
    track needs to be kept (``video.min_track_frames``), at least two (its time direction
    known). A shred that would be dropped does not look back and split another's blob."""
    return max(2, config.video.min_track_frames)


def _area(blob: _Held, fit: _HeldFit) -> float:
    """The pixels of ``blob`` that are ``fit``'s (its part, where the blob was shared)."""
    return float((blob.blob if fit.part is None else fit.part).sum())


def _areas_after(blob: _Held, following: list[_Held]) -> float:
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
    fit: _HeldFit,
    start: FrameResult | None,
    buffer: FrameBuffer,
    camera: PinholeCamera,
    config: Config,
    device: torch.device,
    masks: MaskSource | None,
    found_late: bool,
) -> FrameResult:
    """A track's fit of its part of a blob, found looking back (:func:`_look_back`), warm from
    ``start``, in the track's time direction (:func:`_joined`); ``found_late``: saved already
    (a resumed run)."""
    if found_late:
        return load_result(FrameKey(frame.index, fit.number).path(buffer.folder))
    result = fit_detection(frame, detection, camera, config, start, device, masks, fit.earlier)
    return _joined(dataclasses.replace(result, track=fit.number), fit.start, buffer, camera, config)


def glide(at: FrameResult, other: FrameResult, index: int, camera: PinholeCamera) -> Prediction:
    """Frame ``index``'s prediction from frame ``at``'s streak, moved in the image at the pace
    between ``other`` and ``at`` (frames of one track): on past a track's last clean frame, or
    back before its first."""
    moved, seen = predict(at.state.motion, camera), predict(other.state.motion, camera)
    pace = [(a - b) / (at.index - other.index) for a, b in zip(moved.centre, seen.centre, strict=True)]
    steps = index - at.index

    def on(point: tuple[float, float]) -> tuple[float, float]:
        return point[0] + steps * pace[0], point[1] + steps * pace[1]

    ends = None if moved.ends is None else (on(moved.ends[0]), on(moved.ends[1]))
    return Prediction(on(moved.centre), moved.diameter, None, ends)


def _first_prediction(index: int, fit: _HeldFit, buffer: FrameBuffer, camera: PinholeCamera) -> Prediction | None:
    """Where a track's first frame ``index`` (``fit``, found with no prediction) should be by the
    track's next two frames, or None without them."""
    nearer, further = (buffer.followed(FrameKey(index + k, fit.number)) for k in (1, 2))
    if nearer is None or further is None:
        return None
    return glide(nearer, further, index, camera)


def _goes_on(fit: _HeldFit, index: int) -> bool:
    """Whether ``fit``'s track still goes on in frame ``index`` or later."""
    return fit.tracker.number == fit.number and fit.tracker.previous is not None and fit.tracker.previous.index >= index


def _joined(
    result: FrameResult, start: FrameResult | None, buffer: FrameBuffer, camera: PinholeCamera, config: Config
) -> FrameResult:
    """A refitted frame of a track in the track's time direction: joined to the frame it started
    from, or where it started cold (the track's first frame), to the track's next frame."""
    e = config.video.exposure_fraction
    if start is not None:
        return join(start, result, camera, e, may_flip_previous=False)[1]
    following = buffer.followed(FrameKey(result.index + 1, result.track))
    if following is None:
        return result
    return min((result, result.reversed()), key=lambda r: join_gap(r, following, camera, e))


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
