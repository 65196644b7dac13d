"""What a run's outputs show of each fitted object: the one owner of that rule.

A track's fitted frames are cut into windows (:func:`track_windows`). Each frame is stood for by
the window of its track whose middle is nearest (:func:`frame_windows`). Its outputs show that
window's joint fit where the window was saved (its fit did not diverge), was accepted, and
explains the frame well enough (:func:`trusted_frames`); else its single-frame fit.
:class:`RunResults` answers this for the export, the joint stage, the summary and the
evaluation, from a run folder (:class:`FolderSource`) or from memory (:class:`MemorySource`).
"""

from __future__ import annotations

import dataclasses
import json
from collections import Counter
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Protocol

from sfb_video.atomic import write_json
from sfb_video.config import JointConfig
from sfb_video.crop import Box, box_union
from sfb_video.errors import SfbError
from sfb_video.results import FrameKey, FrameResult, SavedWindow, WindowKey, load_result, load_window
from sfb_video.run_folder import DETECTIONS, MARKER
from sfb_video.stages.types import FrameStatus, Status, Window


def write_statuses(folder: Path, statuses: Sequence[FrameStatus]) -> None:
    """Save what happened to every frame (``detections.json``), for the exports to read."""
    write_json(folder / DETECTIONS, [dataclasses.asdict(s) for s in statuses])


def read_run(folder: Path) -> tuple[dict, list[FrameStatus]]:
    """The run record and frame statuses of a run folder whose fitting has finished."""
    try:
        record = json.loads((folder / MARKER).read_text())
        rows = json.loads((folder / DETECTIONS).read_text())
    except FileNotFoundError:
        raise SfbError(f"{folder} is not a run folder whose frames are all fitted (run sfb-video process)") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise SfbError(f"cannot read the run in {folder}: {exc}") from None
    try:
        statuses = [
            FrameStatus(
                r["index"],
                Status(r["status"]),
                None if r["box"] is None else tuple(r["box"]),
                r["note"],
                r.get("track"),
                r.get("touched", False),
            )
            for r in rows
        ]
    except (KeyError, TypeError, ValueError) as exc:
        raise SfbError(f"cannot read the frame statuses in {folder / DETECTIONS}: {exc}") from None
    return record, statuses


def track_windows(statuses: Sequence[FrameStatus], size: int, overlap: int) -> list[Window]:
    """The windows of every track of two fitted frames or more, by first frame (then track).

    Args:
        statuses: every frame's objects' statuses, in frame order.
        size: frames per window; overlap: frames a window shares with the previous one.
    """
    runs: list[list[int]] = []
    last: dict[int, list[int]] = {}  # track -> its latest run of consecutive frames
    tracks: list[int] = []
    for s in statuses:
        if s.status != Status.FITTED or s.track is None:
            continue
        run = last.get(s.track)
        if run is not None and run[-1] == s.index - 1:
            run.append(s.index)
        else:
            last[s.track] = [s.index]
            runs.append(last[s.track])
            tracks.append(s.track)
    windows: list[Window] = []
    for track, frames in zip(tracks, runs, strict=True):
        if len(frames) < 2:
            continue
        starts = list(range(0, max(1, len(frames) - overlap), size - overlap))
        starts = sorted({min(s, max(0, len(frames) - size)) for s in starts})
        windows += [Window(track, tuple(frames[s : s + size])) for s in starts]
    return sorted(windows, key=lambda w: (w.key.first, w.key.track))


def frame_windows(windows: Sequence[Window]) -> dict[FrameKey, WindowKey]:
    """Each object of ``windows``' frames -> the key of its track's window that covers it with
    the most frames on both sides (its middle nearest; the later window on a tie)."""
    owner: dict[FrameKey, tuple[float, WindowKey]] = {}
    for window in windows:
        middle = (window.frames[0] + window.frames[-1]) / 2
        for index in window.frames:
            key, distance = FrameKey(index, window.track), abs(index - middle)
            if key not in owner or distance <= owner[key][0]:
                owner[key] = (distance, window.key)
    return {key: window for key, (_, window) in owner.items()}


def trusted_frames(window: SavedWindow, max_drop: float, held: Collection[int] = ()) -> set[int]:
    """The frames whose outputs ``window``'s joint fit may show: none where the window was not
    accepted; else each frame but those it explains more than ``max_drop`` worse than their
    single-frame fits. A window is accepted on its frames' mean, and a gain on one frame (which
    takes in its neighbours' pixels) can hide a fit that lies off its streak on another. The
    frames whose pose the window ``held`` (their streak touched another object's) are its own
    also where it explains less, as long as it explains at least half as much as the single-frame
    fit: that fit, drawn to the other object's pixels, explains more and lies off, but a window
    that loses more than half has lost the object."""
    if not window.accepted:
        return set()
    explained = window.explained

    def kept(i: int) -> bool:
        if i not in explained:
            return True
        before, after = explained[i]
        bar = before - max_drop
        return after >= (min(bar, before / 2) if i in held else bar)

    return {i for i in window.frames if kept(i)}


def with_joint(result: FrameResult, window: SavedWindow) -> FrameResult:
    """Frame ``result`` with the window's object and pose in place of its single-frame fit."""
    joint = window.result
    return dataclasses.replace(
        result,
        state=joint.state(result.index),
        prototype=joint.prototype,
        losses=joint.frame_losses(result.index),
        curve=joint.curve,
    )


def shared_boxes(parts: dict[FrameKey, Box]) -> dict[FrameKey, Box]:
    """Per object whose streak touched others' (its box a ``part`` of their shared blob), the box
    of the whole blob: the union of the parts' boxes of that frame that touch it, in turn. A part
    can be a sliver where two streaks lie one over the other; a window's crop around it would cut
    off the object's streak."""
    out = {}
    for key, box in parts.items():
        union = box
        grown = True
        while grown:
            grown = False
            for other_key, other in parts.items():
                if other_key.index == key.index and _touch(union, other) and box_union(union, other) != union:
                    union, grown = box_union(union, other), True
        out[key] = union
    return out


def touched_blobs(statuses: Sequence[FrameStatus]) -> tuple[dict[FrameKey, Box], set[FrameKey]]:
    """Per object whose streak touched others' (dropped tracks' too), the box of their whole blob
    (:func:`shared_boxes`); and the fitted objects whose blob still holds another fitted object.
    A track dropped as too short gives its share of a blob back: the object beside it is then
    alone in its blob, and its window sees its whole streak."""
    parts = {key: s.box for s in statuses if s.touched and s.box is not None and (key := s.key) is not None}
    blobs = shared_boxes(parts)
    fitted = [key for s in statuses if s.status == Status.FITTED and (key := s.key) in blobs]
    holding = Counter((key.index, blobs[key]) for key in fitted)
    return blobs, {key for key in fitted if holding[key.index, blobs[key]] > 1}


def _touch(a: Box, b: Box, gap: int = 2) -> bool:
    return (
        a[0] <= b[0] + b[2] + gap
        and b[0] <= a[0] + a[2] + gap
        and a[1] <= b[1] + b[3] + gap
        and b[1] <= a[1] + a[3] + gap
    )


class ResultSource(Protocol):
    """Where a run's saved fits come from."""

    def single(self, key: FrameKey) -> FrameResult | None:
        """The object's single-frame fit, or None where none was saved."""
        ...

    def window(self, key: WindowKey) -> SavedWindow | None:
        """The window's joint fit, or None where none was saved (its fit diverged)."""
        ...

    def add_window(self, key: WindowKey, window: SavedWindow) -> None:
        """A window just fitted (and saved, for a folder): asked for next, it is not read again."""
        ...


class FolderSource:
    """The fits saved in a run folder, loaded when asked; one window per track is kept, as the
    exports walk the frames in order."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self._loaded: dict[int, tuple[WindowKey, SavedWindow]] = {}  # by track

    def single(self, key: FrameKey) -> FrameResult | None:
        path = key.path(self.folder)
        return load_result(path) if path.is_file() else None

    def window(self, key: WindowKey) -> SavedWindow | None:
        loaded = self._loaded.get(key.track)
        if loaded is not None and loaded[0] == key:
            return loaded[1]
        path = key.path(self.folder)
        if not path.is_file():
            return None
        self.add_window(key, load_window(path))
        return self._loaded[key.track][1]

    def add_window(self, key: WindowKey, window: SavedWindow) -> None:
        self._loaded[key.track] = (key, window)


class MemorySource:
    """Fits held in memory (the evaluation's), and the windows fitted so far."""

    def __init__(self, frames: dict[FrameKey, FrameResult]) -> None:
        self.frames = frames
        self.windows: dict[WindowKey, SavedWindow] = {}

    def single(self, key: FrameKey) -> FrameResult | None:
        return self.frames.get(key)

    def window(self, key: WindowKey) -> SavedWindow | None:
        return self.windows.get(key)

    def add_window(self, key: WindowKey, window: SavedWindow) -> None:
        self.windows[key] = window


class RunResults:
    """A run's frame statuses and saved fits, and what its outputs show of each object.

    Args:
        statuses: every frame's objects' statuses, in frame order.
        source: where the saved fits are read from.
        joint: the joint section: the windows' size, overlap and the explained-drop bar; no
            windows where it is not enabled.
    """

    def __init__(self, statuses: Sequence[FrameStatus], source: ResultSource, joint: JointConfig) -> None:
        self.statuses = tuple(statuses)
        self.source = source
        self.max_drop = joint.max_explained_drop
        self.windows = tuple(track_windows(self.statuses, joint.window, joint.overlap)) if joint.enabled else ()
        self._nearest = frame_windows(self.windows)
        self.blobs, self.holding = touched_blobs(self.statuses)
        self._fitted: dict[int, list[tuple[FrameKey, FrameStatus]]] = {}
        for s in self.statuses:
            if s.status == Status.FITTED and (key := s.key) is not None:
                self._fitted.setdefault(s.index, []).append((key, s))
        self._trusted: dict[WindowKey, frozenset[int]] = {}

    @classmethod
    def of_run(cls, folder: Path, joint: JointConfig) -> RunResults:
        """The results of a run folder whose fitting has finished."""
        _, statuses = read_run(folder)
        return cls(statuses, FolderSource(folder), joint)

    def fitted(self, index: int | None = None) -> list[tuple[FrameKey, FrameStatus]]:
        """The fitted objects (of frame ``index``; None: of every frame), in order."""
        if index is None:
            return [pair for frame in self._fitted.values() for pair in frame]
        return list(self._fitted.get(index, ()))

    def saved(self, index: int) -> list[tuple[FrameStatus, FrameResult]]:
        """The fitted objects of frame ``index`` whose single-frame fit was saved, with it."""
        out = []
        for key, s in self._fitted.get(index, ()):
            single = self.source.single(key)
            if single is not None:
                out.append((s, single))
        return out

    def stands_for(self, window: Window) -> list[int]:
        """The frames of ``window`` that it stands for: those whose nearest window it is."""
        return [i for i in window.frames if self._nearest[FrameKey(i, window.track)] == window.key]

    def held(self, window: Window) -> set[int]:
        """The frames of ``window`` whose blob it shares with another fitted object."""
        return {i for i in window.frames if FrameKey(i, window.track) in self.holding}

    def previous(self, window: Window) -> SavedWindow | None:
        """The last accepted window of ``window``'s track before it, or None."""
        earlier = [w.key for w in self.windows if w.track == window.track and w.frames[0] < window.frames[0]]
        for key in reversed(earlier):
            saved = self.source.window(key)
            if saved is not None and saved.accepted:
                return saved
        return None

    def window(self, key: WindowKey) -> SavedWindow | None:
        """The window's joint fit, or None where it was not saved (it diverged)."""
        return self.source.window(key)

    def shown_window(self, key: FrameKey) -> WindowKey | None:
        """The window whose joint fit object ``key``'s outputs show, or None: its single-frame fit."""
        owner = self._nearest.get(key)
        if owner is None:
            return None
        # A neighbour window that also covers the frame was never judged there (only on the
        # frames it stands for), and its pose there may be far off: no fall back to it.
        return owner if key.index in self._trusted_frames(owner) else None

    def shown_frames(self, window: Window) -> list[int]:
        """The frames whose outputs ``window``'s joint fit shows."""
        return [i for i in window.frames if self.shown_window(FrameKey(i, window.track)) == window.key]

    def single(self, key: FrameKey) -> FrameResult:
        """The object's single-frame fit.

        Raises:
            SfbError: none was saved.
        """
        single = self.source.single(key)
        if single is None:
            raise SfbError(f"the fit of track {key.track} in frame {key.index} is missing from the run")
        return single

    def showing(self, key: FrameKey, single: FrameResult | None = None) -> tuple[FrameResult, SavedWindow | None]:
        """The object as its outputs show it, and the window whose joint fit that is (None: its
        single-frame fit); ``single``: its single-frame fit, if already loaded."""
        single = single if single is not None else self.single(key)
        owner = self.shown_window(key)
        window = None if owner is None else self.source.window(owner)
        return (single, None) if window is None else (with_joint(single, window), window)

    def shown(self, key: FrameKey, single: FrameResult | None = None) -> FrameResult:
        """The object as its outputs show it (:meth:`showing`)."""
        return self.showing(key, single)[0]

    def final(self) -> dict[FrameKey, FrameResult]:
        """Every object fitted and saved (its track not dropped), as its outputs show it."""
        out = {}
        for key, _ in self.fitted():
            single = self.source.single(key)
            if single is not None:
                out[key] = self.shown(key, single)
        return out

    def _trusted_frames(self, key: WindowKey) -> frozenset[int]:
        if key not in self._trusted:
            saved = self.source.window(key)
            if saved is None:  # not (yet) saved: not cached, the joint stage may still save it
                return frozenset()
            held = {i for i in saved.frames if FrameKey(i, key.track) in self.holding}
            self._trusted[key] = frozenset(trusted_frames(saved, self.max_drop, held))
        return self._trusted[key]
