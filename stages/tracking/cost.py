"""What it costs each track to take each blob of a frame: the :func:`~sfb_video.stages.detect.blob_cost`
of the one of its predictions that lands nearest the blob, a fallback guess's a tier dearer."""

from __future__ import annotations

import math
from dataclasses import dataclass

from sfb_video.config import DetectConfig, TrackConfig
from sfb_video.results import FrameResult
from sfb_video.stages.detect import FrameBlobs, blob_cost, rivals
from sfb_video.stages.types import Prediction


@dataclass(frozen=True)
class Option:
    """One way for a track to take one blob: the blob's ``label``, its ``cost``, the
    ``prediction`` that found it, and the track's last frame in the direction that predicts it
    (``last``: a track of one frame guesses both)."""

    label: int
    cost: float
    prediction: Prediction
    last: FrameResult

    def rivals(self, found: FrameBlobs, detect: DetectConfig) -> int:
        """How many other blobs could have been this one's object (:func:`rivals`)."""
        return rivals(found, self.label, self.prediction, detect)


def track_options(
    found: FrameBlobs, predictions: list[tuple[Prediction, FrameResult]], detect: DetectConfig, track: TrackConfig
) -> dict[int, Option]:
    """Each blob within the gate of one of a track's ``predictions`` (:meth:`Tracker.predictions`),
    taken by the guess whose centre lands nearest it in pixels, at that guess's cost; by a
    ``fallback`` guess only where no other reaches it, at ``track.fallback_cost`` more, so that
    the assignment gives a track such a blob only where it has nothing better.

    The guesses of one track are compared in pixels, not in the object diameters of the cost: a
    guess's diameter is its own (a 3D guess from a fit unsure of its depth foresees a larger
    object and a longer streak), and measured by it, the vaguer guess would win every blob."""
    options: dict[int, Option] = {}
    nearest: dict[int, tuple[bool, float]] = {}
    for prediction, last in predictions:
        tier = track.fallback_cost if prediction.fallback else 0.0
        for label in range(1, found.count):
            cost = blob_cost(found, label, prediction, detect)
            if cost is None:
                continue
            x, y = (float(v) for v in found.centroids[label])
            rank = (prediction.fallback, math.hypot(x - prediction.centre[0], y - prediction.centre[1]))
            if label not in nearest or rank < nearest[label]:
                nearest[label] = rank
                options[label] = Option(label, cost + tier, prediction, last)
    return options
