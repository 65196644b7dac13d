"""Several true objects against a run's tracks: which track covers each object, and how well.

A track covers an object when its box matches the object's true box (IoU >= 0.5) in more frames
than any other track's does; ties go to the lower track number. Each true object is then scored
against its covering track only, so a track that swaps from one object to another at a crossing
loses recall on one of them, and a track that covers no object is spurious.
"""

from __future__ import annotations

from dataclasses import dataclass

Box = tuple[int, int, int, int]
MATCH_IOU = 0.5


def box_iou(a: Box, b: Box) -> float:
    """IoU of two (x, y, w, h) pixel boxes."""
    ix = max(0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / float(a[2] * a[3] + b[2] * b[3] - inter)


@dataclass(frozen=True)
class Coverage:
    """How one true object was found.

    Attributes:
        track: the track that covers it (None: no track ever matched it).
        present: frames the object is in.
        detections: frames the covering track holds a box.
        found: frames the covering track's box matches the object's.
        matched: those frames' indices.
    """

    track: int | None
    present: int
    detections: int
    found: int
    matched: tuple[int, ...]

    @property
    def recall(self) -> float:
        return self.found / max(self.present, 1)

    @property
    def precision(self) -> float:
        return self.found / max(self.detections, 1)


def _matches(truth: dict[int, Box], boxes: dict[int, Box]) -> list[int]:
    return sorted(k for k, box in boxes.items() if k in truth and box_iou(box, truth[k]) >= MATCH_IOU)


def cover_objects(objects: list[dict[int, Box]], tracks: dict[int, dict[int, Box]]) -> list[Coverage]:
    """The :class:`Coverage` of each true object.

    Args:
        objects: per true object, frame index -> its true box (frames it is in).
        tracks: per track number, frame index -> the track's detected box.
    """
    out = []
    for truth in objects:
        scored = {t: _matches(truth, boxes) for t, boxes in sorted(tracks.items())}
        best = max(scored, key=lambda t: (len(scored[t]), -t), default=None)
        if best is None or not scored[best]:
            out.append(Coverage(None, len(truth), 0, 0, ()))
            continue
        matched = tuple(scored[best])
        out.append(Coverage(best, len(truth), len(tracks[best]), len(matched), matched))
    return out


def spurious_tracks(coverage: list[Coverage], tracks: dict[int, dict[int, Box]]) -> dict[int, int]:
    """Track number -> its detections, for the tracks that cover no object."""
    covering = {c.track for c in coverage}
    return {t: len(boxes) for t, boxes in tracks.items() if t not in covering}
