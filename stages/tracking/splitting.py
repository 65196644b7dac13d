"""Where tracks' streaks touch: a blob several tracks take, shared out among them by nearness to
their predicted streaks, and the pieces of a streak split off beside it given back to its track."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from sfb_video.stages.detect import FrameBlobs
from sfb_video.stages.tracking.tracker import Tracker
from sfb_video.stages.types import Prediction


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
    (:func:`~sfb_video.stages.side_by_side.side_by_side`), among the ``free`` blobs (no track took them
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


def shared_out(found: FrameBlobs, claims: list[Claim], min_area: float) -> bool:
    """Share the blob that several tracks' ``claims`` took among them by nearness to their
    predicted streaks (:meth:`FrameBlobs.split`): each claim narrowed to its part, with the tracks
    it shares with. False, and the claims left as they were, where it cannot be shared: a track
    of one frame only guesses its direction, so it shares with none; a claim has no predicted
    streak; or a part would be under ``min_area`` pixels."""
    if any(c.tracker.length < 2 or c.prediction is None for c in claims):
        return False
    parts = found.split(claims[0].label, [c.prediction for c in claims if c.prediction is not None], min_area)
    if parts is None:
        return False
    for claim, part in zip(claims, parts, strict=True):
        claim.part = part
        claim.shared_with = [c.tracker for c in claims if c is not claim]
    return True
