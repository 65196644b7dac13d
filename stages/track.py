"""Tracking: which blob of each frame is the object, which frames form one track, and which way
time runs through them. The parts live in :mod:`sfb_video.stages.tracking`; this is the stage.

Frames stream through with their difference masks. Each frame's object is looked for near
where the track's last fit predicts it (its motion continued across the gap between exposures,
:mod:`~sfb_video.stages.tracking.prediction`); nothing near starts a new track. Each detection
is fitted (warm from the track's last frame) and written into the run folder once no later frame
can change it (:class:`~sfb_video.stages.frame_buffer.FrameBuffer`), which is what a resumed run
reuses. One frame cannot tell which end of its streak came first (DeFMO's sub-frame masks order a
frame, but may run either way themselves): the directions that make consecutive frames meet end
to start win over DeFMO's.

Where several objects' streaks touch, their blob is shared out among their tracks by nearness
to their predicted streaks; an object whose streak lay inside another's blob before it had a
track of its own is found there when its track, fitted in enough frames to be kept, looks back.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

import torch

from sfb_video.config import Config, DetectConfig, TrackConfig, VideoConfig
from sfb_video.errors import NoObjectError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.results import FrameResult, load_followed
from sfb_video.run_folder import frame_path, saved_frames
from sfb_video.stages.detect import (
    FrameBlobs,
    Neighbour,
    difference_mask,
    frame_blobs,
    moving_mask,
    still_there,
)
from sfb_video.stages.fit import fit_detection
from sfb_video.stages.frame_buffer import FrameBuffer, Pending, StepReport
from sfb_video.stages.masks import MaskSource
from sfb_video.stages.register import mask_onto_next, segment_of, usable
from sfb_video.stages.tracking.assignment import Matched, match_tracks
from sfb_video.stages.tracking.look_back import Held, HeldFit, Refit, held_blobs, look_back_into, proven_length
from sfb_video.stages.tracking.splitting import Claim, on_its_streak
from sfb_video.stages.tracking.tracker import Tracker, TrackNumbers, new_objects, short_tracks_dropped
from sfb_video.stages.types import Detection, Frame, FrameStatus, FrameWithBackground, Status

T = TypeVar("T")


def _present(items: list[T | None]) -> list[T]:
    return [item for item in items if item is not None]


def with_neighbours(
    frames: Iterator[FrameWithBackground], detect: DetectConfig
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
        ahead.append((frame, difference_mask(frame.pixels, frame.background_pixels, detect, frame.known)))
        if len(ahead) == 4:
            yield emit()
    while ahead:
        yield emit()


class Tracking:
    """The tracks of one clip, frame after frame: the stage's step, which the evaluation takes too.

    Each :meth:`step` hands over a frame's blobs: the tracks take theirs
    (:func:`~sfb_video.stages.tracking.assignment.match_tracks`), the blobs left that are objects
    of their own start tracks (at most ``video.max_objects`` live at once; 0: all), a piece of a
    track's streak split off beside it goes back to it, each claim is fitted (``refit``; a fit
    the run folder holds, ``saved``, is loaded), and a track fitted in enough frames to be kept
    looks back for its object (:func:`~sfb_video.stages.tracking.look_back.look_back_into`). The
    frames go into ``buffer`` and out of it once no later frame can change them.
    """

    def __init__(
        self,
        camera: PinholeCamera,
        config: Config,
        buffer: FrameBuffer,
        refit: Refit,
        saved: set[tuple[int, int]] | None = None,
    ) -> None:
        self.camera, self.config, self.buffer, self.refit = camera, config, buffer, refit
        self.saved = saved or set()
        self.held: deque[list[Held]] = deque(maxlen=config.track.look_back + proven_length(config.video) + 1)
        self.numbers = TrackNumbers()
        self.live: list[Tracker] = []
        self.limit = config.video.max_objects or math.inf
        # One track at a time: none starts beside another to look back.
        self.looks_back = self.limit > 1 and config.track.look_back > 0

    def restart(self) -> None:
        """End every track: the next frames' positions are in other coordinates (a moving
        camera's new reference frame), or a frame between did not register."""
        self.live = []

    def failed(self, index: int, note: str) -> None:
        """Frame ``index`` could not be used (it did not register): every track ends there."""
        self.restart()
        self.buffer.add(index, [Pending(FrameStatus(index, Status.FAILED, note=note))])
        self.buffer.write_before(index + 1 - len(self.held))

    def step(self, frame: FrameWithBackground, found: FrameBlobs) -> None:
        """Take frame ``frame``'s blobs ``found``: match, start, fit, look back, and write what
        no later frame can change."""
        config, buffer = self.config, self.buffer
        matched = match_tracks(found, [(t, t.predictions(frame.index)) for t in self.live], config.detect, config.track)
        for first in matched.directed:
            buffer.directed(first)  # a track's first frame, found to run the other way
        self.live = [t for t in self.live if t.previous is not None]
        new_track = functools.partial(
            Tracker, self.camera, config.detect, config.track, config.video.exposure_fraction, self.numbers
        )
        objects, untracked = _with_new_tracks(
            found, matched, self.live, self.limit, new_track, config.detect, config.track
        )
        note = f"{untracked} other moving object(s) seen, not tracked (video.max_objects)" if untracked else ""
        merged = matched.merged
        results, fits, proven = _fit_claims(
            frame, found, objects, merged, note, self.saved, buffer, self.refit, config.video
        )
        self.live += [c.tracker for c in objects if c.tracker.previous is not None and c.tracker not in self.live]
        owner = {c.label: c.tracker for c in objects}
        for tracker, label in merged:
            if tracker.previous is not None:
                note = f"its streak merged into track {owner[label].number}'s"
                results.append(Pending(FrameStatus(frame.index, Status.MERGED, None, note, tracker.number)))
        buffer.add(frame.index, results or [Pending(FrameStatus(frame.index, Status.NO_OBJECT))])
        if self.looks_back:
            self.held.append(held_blobs(frame, found, fits, config.crop))
        for tracker in proven:
            look_back_into(
                tracker,
                list(self.held),
                buffer,
                self.saved,
                self.camera,
                config.detect,
                config.track,
                config.video,
                self.refit,
            )
        # A frame may change while a track's look back can reach it (the frames ``held``), and a
        # track's first frame until its second fixes its time direction.
        opened = any(t.length == 1 and t.previous is not None and t.previous.index == frame.index for t in self.live)
        buffer.write_before(frame.index + 1 - max(len(self.held), int(opened)))


def track_and_fit(
    frames: Iterator[FrameWithBackground],
    folder: Path,
    camera: PinholeCamera,
    config: Config,
    device: torch.device,
    masks: MaskSource | None = None,
    report: StepReport | None = None,
) -> list[FrameStatus]:
    """Detect and fit every object of every frame (:class:`Tracking`), writing each fit into the
    run ``folder`` once no later frame can change it; fits already written there are reused.
    ``masks`` gives each fit its sub-frame masks (None: the difference mask).

    Returns:
        the status of every object of every frame read (one ``no_object`` status for a frame
        without any), in frame order, then track order; tracks fitted in fewer than
        ``video.min_track_frames`` frames ``dropped``.
    """

    def refit(
        frame: FrameWithBackground, detection: Detection, start: FrameResult | None, earlier: FrameResult | None
    ) -> FrameResult:
        # Looked up at each call: a test stands a fit of its own in for the stage's.
        return fit_detection(frame, detection, camera, config, start, device, masks, earlier)

    tracking = Tracking(camera, config, FrameBuffer(folder, report), refit, saved_frames(folder))
    segment = 0
    for frame, mask, neighbours in with_neighbours(frames, config.detect):
        if segment_of(frame) != segment:
            tracking.restart()
            segment = segment_of(frame)
        if not usable(frame):
            tracking.failed(frame.index, frame.registered.note)
            continue
        moving = moving_mask(mask, neighbours, config.detect)
        tracking.step(frame, frame_blobs(moving, config.detect, (frame.pixels, frame.background_pixels), mask))
    return short_tracks_dropped(tracking.buffer.close(), config.video.min_track_frames)


def _fit_claims(
    frame: FrameWithBackground,
    found: FrameBlobs,
    claims: list[Claim],
    merged: list[tuple[Tracker, int]],
    note: str,
    saved: set[tuple[int, int]],
    buffer: FrameBuffer,
    refit: Refit,
    video: VideoConfig,
) -> tuple[list[Pending], list[tuple[Claim, HeldFit]], list[Tracker]]:
    """Fit each track's claim on a blob of ``frame`` (a written fit is loaded: a resumed run) and
    add it to its track. Returns the frame's objects, the fits the look back may refit, and the
    tracks that have just been fitted in enough frames to be kept."""
    results: list[Pending] = []
    fits: list[tuple[Claim, HeldFit]] = []
    proven: list[Tracker] = []
    for claim in claims:
        tracker, label = claim.tracker, claim.label
        detection = found.detection(frame.index, label, claim.others, claim.part)
        key = (frame.index, tracker.upcoming)
        loaded = load_followed(frame_path(buffer.folder, *key)) if key in saved else None
        text = note
        crossed = [t for t, lab in merged if lab == label and t.number is not None]
        if crossed:
            text = f"its streak merged with track(s) {', '.join(str(t.number) for t in crossed)}'s"
        if claim.shared_with:
            others = ", ".join(str(t.number) for t in claim.shared_with)
            text = f"its streak touched track(s) {others}'s: their pixels shared out by nearness"
        start = tracker.previous if video.warm_start else None
        before = tracker.earlier
        try:
            result = loaded or refit(frame, detection, start, before)
        except NoObjectError as exc:
            tracker.lose()
            results.append(Pending(FrameStatus(frame.index, Status.NO_OBJECT, detection.box, str(exc))))
            continue
        shared = bool(claim.shared_with)
        track, result, reversed_previous = tracker.add(result, detection.colour, shared)
        if reversed_previous is not None:
            buffer.reoriented(reversed_previous)
        status = FrameStatus(frame.index, Status.FITTED, detection.box, text, track, shared)
        results.append(Pending(status, result, saved=result is loaded))
        fits.append((claim, HeldFit(tracker, track, claim.prediction, claim.part, start, before)))
        if not shared and tracker.length == proven_length(video):
            proven.append(tracker)
    return results, fits, proven


def _with_new_tracks(
    found: FrameBlobs,
    matched: Matched,
    live: list[Tracker],
    limit: float,
    new_track: Callable[[], Tracker],
    detect: DetectConfig,
    track: TrackConfig,
) -> tuple[list[Claim], int]:
    """The tracks' claims and a new track's on each blob left that is an object of its own
    (largest first, while fewer than ``limit`` tracks are live), after giving back to its track a
    piece of a streak split off beside it that no track wants and is no object of its own; and
    how many objects of their own were left untracked (``video.max_objects``)."""
    fresh = new_objects(found, matched.taken, detect, track, alone=not live)
    claimed = matched.taken | matched.wanted | set(fresh)
    free = {k for k in range(1, found.count) if k not in claimed}
    for claim in matched.claims:
        if pieces := on_its_streak(found, claim, free):
            found.merge(claim.label, pieces)
            free -= set(pieces)
    room = max(0, int(min(limit, len(fresh) + len(live)) - len(live)))
    return matched.claims + [Claim(new_track(), label, 0, None) for label in fresh[:room]], len(fresh) - room
