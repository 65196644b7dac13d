"""Which blob each track takes in a frame: its predictions' best blob, the order in which tracks
choose, a blob shared out among the tracks whose streaks touch in it, and the pieces of a
streak given back to its track."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from sfb_video.config import Config
from sfb_video.results import FrameResult
from sfb_video.stages.detect import (
    FrameBlobs,
    pick_blob,
)
from sfb_video.stages.tracking.tracker import Tracker
from sfb_video.stages.types import Prediction


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


def second_miss(
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


def choosing_order(
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
    in its object's diameters, :func:`second_miss`; None: none would take another), one that
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


def goes_elsewhere(
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


@dataclass
class Claim:
    """A track's claim on a blob of one frame: the blob, how many others could have been its
    object, the prediction that found it, and where tracks' streaks touch in it, the part of it
    that is this track's (:meth:`FrameBlobs.split`) and the tracks it was shared with."""

    tracker: Tracker
    label: int
    others: int
    prediction: Prediction | None
    part: np.ndarray | None = None
    shared_with: list[Tracker] = dataclasses.field(default_factory=list)


def on_its_streak(found: FrameBlobs, claim: Claim, free: set[int]) -> list[int]:
    """The other pieces of the blob that ``claim``'s was split from as objects beside each other
    (:func:`~sfb_video.stages.detect.side_by_side`), among the ``free`` blobs (no track took them
    or wants them first, and no object of its own, :func:`new_objects`), that lie on its track's
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


def share_claim(
    found: FrameBlobs,
    crossing: tuple[tuple[int, int], FrameResult, Prediction],
    claims: list[Claim],
    tracker: Tracker,
    config: Config,
) -> Claim | None:
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
    return Claim(tracker, label, 0, prediction, parts[-1], [c.tracker for c in first])


@dataclass
class Matched:
    """What the tracks took in one frame: their ``claims`` (in the order they chose), the tracks
    whose streak merged into a blob another took (``merged``: the track and that blob's label,
    the track coasting), the labels ``taken``, those some track ``wanted`` first, and the first
    frames of tracks found to run the other way (``directed``)."""

    claims: list[Claim]
    merged: list[tuple[Tracker, int]]
    taken: set[int]
    wanted: set[int]
    directed: list[FrameResult]


def match_tracks(
    found: FrameBlobs, asked: list[tuple[Tracker, list[tuple[Prediction, FrameResult]]]], config: Config
) -> Matched:
    """Each live track's blob among a frame's (``asked``: each track and its predictions,
    :meth:`Tracker.predictions`): the tracks choose in :func:`choosing_order`; one whose best
    blob another took goes to the best blob left where that is its object
    (:func:`goes_elsewhere`), else shares the blob out (:func:`share_claim`), else takes the best
    blob left all the same, or none: then a track of two frames or more coasts, and a track of one
    frame (its direction unknown) ends, as does a track that finds no blob."""
    matched = Matched([], [], set(), set(), [])
    wants = [(t, follow(found, p, config)) for t, p in asked]
    elsewhere = [second_miss(found, p, w, config) for (_, p), (_, w) in zip(asked, wants, strict=True)]
    matched.wanted = {w[0][0] for _, w in wants if w is not None}
    for k in choosing_order(found, wants, elsewhere, gate=config.detect.gate):
        (tracker, predictions), followed = asked[k], wants[k][1]
        claim = None
        if followed is not None and followed[0][0] in matched.taken:
            # Its best blob is another track's too: their streaks touch or cross.
            rest = follow(found, predictions, config, frozenset(matched.taken), followed[2].fallback)
            if goes_elsewhere(found, followed, rest, matched.wanted):
                followed = rest
            elif (claim := share_claim(found, followed, matched.claims, tracker, config)) is None:
                crossing, followed = followed, rest
                if followed is None and tracker.length >= 2:
                    tracker.coast()
                    matched.merged.append((tracker, crossing[0][0]))
                    continue
        if followed is None:
            tracker.found(None)
            continue
        (label, others), option, prediction = followed
        reversed_first = tracker.found(option)
        if reversed_first is not None:
            matched.directed.append(reversed_first)
        matched.taken.add(label)
        matched.claims.append(claim or Claim(tracker, label, others, prediction))
    return matched
