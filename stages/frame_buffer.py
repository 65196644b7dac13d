"""The frames a later frame may still change, held in memory: results flow one way.

Tracking may still change a recent frame: a track's second frame fixes its first frame's time
direction, and a track that has just proven itself looks back into the frames before its first
and refits the blob it shares there with others. :class:`FrameBuffer` keeps those frames'
statuses and fits in memory, where such changes are edits, and writes each frame into the run
folder once, when nothing can change it any more (the tracker says when); then it reports it. A
run stopped midway loses the held frames' fits (a resumed run fits them again), never a written
one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from sfb_video.results import FrameKey, FrameResult, load_followed, save_result
from sfb_video.stages.types import FrameStatus

StepReport = Callable[[FrameStatus, FrameResult | None], None]
"""Called with each frame's object's final status and fit (None: no fit), in frame order."""


@dataclass
class Pending:
    """One object of a buffered frame: its status, the fit the run folder will keep, the fit its
    track went on from where a track that started later refitted the frame (``followed``), and
    whether the fit is the one the folder already holds (a resumed run's)."""

    status: FrameStatus
    result: FrameResult | None = None
    followed: FrameResult | None = None
    saved: bool = False


class FrameBuffer:
    """The recent frames of a run, each written into ``folder`` once nothing can change it.

    Args:
        folder: the run folder; None: nothing is written, each frame only reported (the
            evaluation keeps its fits in memory).
        report: called with each object's final status and fit as its frame is written.
    """

    def __init__(self, folder: Path | None, report: StepReport | None = None) -> None:
        self.folder, self.report = folder, report
        self.statuses: list[FrameStatus] = []  # the frames written, in frame order
        self._frames: dict[int, list[Pending]] = {}  # in frame order

    def add(self, index: int, objects: list[Pending]) -> None:
        """Frame ``index``'s objects (a frame without any: its one status), held."""
        self._frames[index] = sorted(objects, key=_track_order)

    def write_before(self, index: int) -> None:
        """Write every frame held before frame ``index``: no later frame can change them."""
        while self._frames and next(iter(self._frames)) < index:
            self._write(next(iter(self._frames)))

    def directed(self, result: FrameResult) -> None:
        """A track's first frame in the time direction its second frame's blob was found by: the
        fit the track goes on from (its next frame's warm start)."""
        pending = self._held(result.key)
        pending.result, pending.saved = result, False

    def reoriented(self, result: FrameResult) -> None:
        """A track's first frame joined to its second in the direction that meets it: kept, and
        the fit the track went on from kept as ``followed`` (a resumed run's warm start)."""
        pending = self._held(result.key)
        pending.followed = pending.followed or pending.result
        pending.result, pending.saved = result, False

    def refitted(self, status: FrameStatus, result: FrameResult, saved: bool = False) -> None:
        """A frame's object refitted by a track looking back: its status and fit in place of its
        track's there (or beside the frame's others), the fit the track went on from kept as
        ``followed``; ``saved``: the folder holds it already (a resumed run)."""
        assert status.key is not None and status.index in self._frames, f"frame {status.index} is no longer held"
        objects = self._frames[status.index]
        pending = self._pending(status.key)
        if pending is None:
            objects.append(Pending(status, result, saved=saved))
            objects.sort(key=_track_order)
            return
        pending.followed = pending.followed or pending.result
        pending.status, pending.result, pending.saved = status, result, saved and pending.saved

    def followed(self, key: FrameKey) -> FrameResult | None:
        """The fit ``key``'s track went on from in its frame, held or written; None if none."""
        pending = self._pending(key)
        if pending is not None:
            return pending.followed or pending.result
        if self.folder is None:
            return None
        path = key.path(self.folder)
        return load_followed(path) if path.is_file() else None

    def close(self) -> list[FrameStatus]:
        """Write every frame still held; every status, in frame order, then track order."""
        for index in list(self._frames):
            self._write(index)
        return self.statuses

    def _held(self, key: FrameKey) -> Pending:
        pending = self._pending(key)
        assert pending is not None, f"frame {key.index} of track {key.track} is no longer held"
        return pending

    def _pending(self, key: FrameKey) -> Pending | None:
        return next((p for p in self._frames.get(key.index, ()) if p.status.track == key.track), None)

    def _write(self, index: int) -> None:
        for pending in self._frames.pop(index):
            if self.folder is not None and pending.result is not None and not pending.saved:
                save_result(self.folder, pending.result, pending.followed)
            self.statuses.append(pending.status)
            if self.report is not None:
                self.report(pending.status, pending.result)


def _track_order(pending: Pending) -> int:
    return -1 if pending.status.track is None else pending.status.track
