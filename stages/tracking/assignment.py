"""Which blob each track takes in a frame: assignments of tracks to blobs at least total cost.

Costs (:mod:`~sfb_video.stages.tracking.cost`) are in one unit, ``log(1 + m**2)`` of a miss of
``m`` object diameters. Each frame is matched in two rounds, each one assignment
(:func:`assign`, ``scipy.optimize.linear_sum_assignment``: rows the tracks, columns the blobs,
copies of blobs to share and a "coast" column per track):

1. **The contest.** Each track takes one blob or none. Taking none costs a track of two frames or
   more a miss at the gate's edge (``log(1 + detect.gate**2)``: a track whose guess lands far off
   has little claim on a blob, and one with no other blob no more than that), and a track of one
   frame, which only guesses its direction, ``track.young_coast_cost``.
2. **The tracks left over** take what is left: a blob no track took, or a share of a blob that a
   track of two frames or more took (a copy of the blob per track whose predicted streak, of a
   guess that is no fallback, covers a pixel of it: :meth:`FrameBlobs.touches`;
   ``track.share_cost`` more), or a blob only a
   fallback guess reaches (``track.fallback_cost`` more); none only where nothing is left.

A blob no track takes is left to start a track of its own
(:func:`~sfb_video.stages.tracking.tracker.new_objects`): the "new track" choice. Tracks are
ordered by their numbers before the matrices are built, so the result does not depend on the order
they are handed in. Where tracks share a blob that cannot be shared out
(:func:`~sfb_video.stages.tracking.splitting.shared_out`), the second round is solved again
without it: the tracks of one frame among them may not take that blob, or, where there are none,
the blob has no copies to share.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from sfb_video.config import DetectConfig, TrackConfig
from sfb_video.results import FrameResult
from sfb_video.stages.detect import FrameBlobs
from sfb_video.stages.tracking.cost import Option, track_options
from sfb_video.stages.tracking.splitting import Claim, shared_out
from sfb_video.stages.tracking.tracker import Tracker
from sfb_video.stages.types import Prediction

NOTHING_LEFT = 1e9
"""The second round's cost of taking no blob: above every other choice (not a tunable)."""


def assign(
    options: Sequence[dict[int, Option]],
    coast: Sequence[float],
    shares: Sequence[dict[int, Option]] = (),
    share_cost: float = 0.0,
) -> list[Option | None]:
    """The assignment of least total cost of tracks to blobs: for each track (its ``options``,
    :func:`track_options`; what taking no blob costs it, ``coast``; the blobs it may take a share
    of, ``shares``, at ``share_cost`` more), the option it takes, or None. Each blob goes to one track at most, and
    each share copy to its own track."""
    labels = sorted({label for o in options for label in o})
    column = {label: k for k, label in enumerate(labels)}
    copies = [(i, shares[i][label]) for i in range(len(shares)) for label in sorted(shares[i])]
    first_coast = len(labels) + len(copies)
    cost = np.full((len(options), first_coast + len(options)), np.inf)
    for i, own in enumerate(options):
        for label, option in own.items():
            cost[i, column[label]] = option.cost
        cost[i, first_coast + i] = coast[i]
    for k, (i, option) in enumerate(copies):
        cost[i, len(labels) + k] = option.cost + share_cost
    choices: list[Option | None] = [None] * len(options)
    for i, j in zip(*linear_sum_assignment(cost), strict=True):
        if j < len(labels):
            choices[i] = options[i][labels[j]]
        elif j < first_coast:
            choices[i] = copies[j - len(labels)][1]
    return choices


@dataclass
class Matched:
    """What the tracks took in one frame: their ``claims`` (in track order), the tracks whose
    streak merged into a blob another took (``merged``: the track and that blob's label, the track
    coasting), the labels ``taken``, those some track ``wanted`` first (its cheapest), and the
    first frames of tracks found to run the other way (``directed``)."""

    claims: list[Claim]
    merged: list[tuple[Tracker, int]]
    taken: set[int]
    wanted: set[int]
    directed: list[FrameResult]


def _contest(
    options: list[dict[int, Option]], lengths: list[int], detect: DetectConfig, track: TrackConfig
) -> list[Option | None]:
    """The first round (module docstring): no fallback guess, no sharing."""
    edge = math.log1p(detect.gate**2)
    plain = [{k: o for k, o in own.items() if not o.prediction.fallback} for own in options]
    return assign(plain, [edge if n >= 2 else track.young_coast_cost for n in lengths])


def _left_over(
    found: FrameBlobs,
    trackers: list[Tracker],
    options: list[dict[int, Option]],
    first: list[Option | None],
    detect: DetectConfig,
    track: TrackConfig,
) -> dict[int, list[Claim]]:
    """The second round (module docstring) and the claims of both rounds, by blob, shared out."""
    held = {c.label: trackers[i] for i, c in enumerate(first) if c is not None}
    rest = [i for i, c in enumerate(first) if c is None]
    # A track of one frame shares no blob, and no blob with one.
    allowed = [{k: o for k, o in options[i].items() if k not in held} for i in rest]
    unshared: set[int] = {k for k, t in held.items() if t.length < 2}
    # The guess kept for a blob (the nearest, :func:`track_options`) is the one whose streak
    # must cover it.
    sharable = [
        {k: o for k, o in options[i].items() if not o.prediction.fallback and found.touches(k, o.prediction)}
        if trackers[i].length >= 2
        else {}
        for i in rest
    ]
    while True:
        shares = [{k: o for k, o in own.items() if k not in unshared} for own in sharable]
        second = assign(allowed, [NOTHING_LEFT] * len(rest), shares, track.share_cost)
        holders: dict[int, list[Claim]] = {}
        for i, option in [*enumerate(first), *zip(rest, second, strict=True)]:
            if option is not None:
                holders.setdefault(option.label, []).append(Claim(trackers[i], option.label, 0, option.prediction))
        failed = [c for c in holders.values() if len(c) > 1 and not shared_out(found, c, detect.min_area_px)]
        if not failed:
            return holders
        for claims in failed:
            young = [rest.index(trackers.index(c.tracker)) for c in claims if c.tracker.length < 2]
            for r in young:  # it only guesses its direction: the others may still share the blob
                allowed[r] = {k: o for k, o in allowed[r].items() if k != claims[0].label}
            if not young:
                unshared.add(claims[0].label)


def match_tracks(
    found: FrameBlobs,
    asked: list[tuple[Tracker, list[tuple[Prediction, FrameResult]]]],
    detect: DetectConfig,
    track: TrackConfig,
) -> Matched:
    """Each live track's blob among a frame's (``asked``: each track and its predictions,
    :meth:`Tracker.predictions`), in two rounds (module docstring). A blob several tracks take is
    shared out among them; a track of two frames or more that takes none while a blob of its gate
    is another's coasts (its streak merged into that blob), and any other track that takes none
    ends."""
    asked = sorted(asked, key=lambda a: (a[0].number is None, a[0].number or 0))
    trackers = [t for t, _ in asked]
    options = [track_options(found, predictions, detect, track) for _, predictions in asked]
    first = _contest(options, [t.length for t in trackers], detect, track)
    holders = _left_over(found, trackers, options, first, detect, track)
    wanted = {min(own.values(), key=lambda o: o.cost).label for own in options if own}
    matched = Matched([], [], set(holders), wanted, [])
    for tracker, own in zip(trackers, options, strict=True):
        claim = next((c for claims in holders.values() for c in claims if c.tracker is tracker), None)
        if claim is None:
            taken = [o for o in own.values() if o.label in holders]
            if taken and tracker.length >= 2:
                tracker.coast()
                matched.merged.append((tracker, min(taken, key=lambda o: o.cost).label))
            else:
                tracker.found(None)
            continue
        option = own[claim.label]
        if not claim.shared_with:
            claim.others = option.rivals(found, detect)
        if (reversed_first := tracker.found(option.last)) is not None:
            matched.directed.append(reversed_first)
        matched.claims.append(claim)
    return matched
