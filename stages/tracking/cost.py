"""What it costs each track to take each blob of a frame: the cheapest of its predictions'
:func:`~sfb_video.stages.detect.blob_cost`, a fallback guess's a tier dearer."""

from __future__ import annotations

from dataclasses import dataclass

from sfb_video.config import Config, DetectConfig
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
    found: FrameBlobs, predictions: list[tuple[Prediction, FrameResult]], config: Config
) -> dict[int, Option]:
    """Each blob within the gate of one of a track's ``predictions`` (:meth:`Tracker.predictions`),
    with its cheapest way to take it; a ``fallback`` prediction's costs ``track.fallback_cost``
    more, so that it is taken only where no other guess reaches a blob it may take."""
    options: dict[int, Option] = {}
    for prediction, last in predictions:
        tier = config.track.fallback_cost if prediction.fallback else 0.0
        for label in range(1, found.count):
            cost = blob_cost(found, label, prediction, config.detect)
            if cost is not None and (label not in options or cost + tier < options[label].cost):
                options[label] = Option(label, cost + tier, prediction, last)
    return options
