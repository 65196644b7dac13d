"""What a run's outputs show of each fitted object: windows cut from the tracks, the window that
stands for each frame, the frames it may stand for, and a run folder's statuses read back."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from sfb_video.config import JointConfig
from sfb_video.errors import SfbError
from sfb_video.results import FrameKey, SavedWindow, WindowKey
from sfb_video.run_folder import DETECTIONS, MARKER
from sfb_video.stages import run_results
from sfb_video.stages.run_results import (
    FolderSource,
    RunResults,
    frame_windows,
    read_run,
    shared_boxes,
    touched_blobs,
    track_windows,
    trusted_frames,
    write_statuses,
)
from sfb_video.stages.types import FrameStatus, Status, Window

JOINT = JointConfig(window=6, overlap=2)


def _statuses(tracks: list[int | None]) -> list[FrameStatus]:
    return [
        FrameStatus(i, Status.NO_OBJECT) if t is None else FrameStatus(i, Status.FITTED, (0, 0, 4, 4), track=t)
        for i, t in enumerate(tracks)
    ]


class _Source:
    """Saved fits: every fitted object's single fit (its key), and the ``windows`` given."""

    def __init__(self, windows: dict[WindowKey, object], missing: set[FrameKey] = frozenset()) -> None:
        self.windows, self.missing = windows, missing

    def single(self, key: FrameKey) -> object | None:
        return None if key in self.missing else key

    def window(self, key: WindowKey) -> object | None:
        return self.windows.get(key)

    def add_window(self, key: WindowKey, window: object) -> None:
        self.windows[key] = window


def _window(track: int, frames: range, accepted: bool = True, explained: dict | None = None) -> SavedWindow:
    fit = SimpleNamespace(losses={i: {} for i in frames})  # only the frames it names are read
    return SavedWindow(track, fit, {}, explained or {}, accepted)  # type: ignore[arg-type]


def test_tracks_are_cut_into_overlapping_windows_that_end_at_the_track_s_end() -> None:
    statuses = _statuses([0] * 11 + [None, 1, 1, 1, None, 2, 3, 3])
    assert track_windows(statuses, size=6, overlap=2) == [
        Window(0, (0, 1, 2, 3, 4, 5)),
        Window(0, (4, 5, 6, 7, 8, 9)),
        Window(0, (5, 6, 7, 8, 9, 10)),
        Window(1, (12, 13, 14)),  # a short track is one window
        Window(3, (17, 18)),  # track 2 has one frame: nothing to fit jointly
    ]


def test_two_objects_in_the_same_frames_are_two_tracks_of_windows() -> None:
    statuses = []
    for i in range(8):
        statuses += [FrameStatus(i, Status.FITTED, (0, 0, 4, 4), track=0)]
        if i >= 2:  # the second object enters at frame 2
            statuses += [FrameStatus(i, Status.FITTED, (9, 9, 4, 4), track=1)]
    assert [(w.track, w.frames) for w in track_windows(statuses, size=4, overlap=1)] == [
        (0, (0, 1, 2, 3)),
        (1, (2, 3, 4, 5)),
        (0, (3, 4, 5, 6)),
        (0, (4, 5, 6, 7)),
        (1, (4, 5, 6, 7)),
    ]


def test_each_frame_is_stood_for_by_the_window_whose_middle_is_nearest() -> None:
    windows = [Window(0, tuple(range(6))), Window(0, tuple(range(4, 10))), Window(1, (12, 13)), Window(2, (4, 5))]
    owner = frame_windows(windows)
    assert [owner[FrameKey(i, 0)] for i in range(10)] == [WindowKey(0, 0)] * 5 + [WindowKey(0, 4)] * 5
    assert owner[FrameKey(12, 1)] == owner[FrameKey(13, 1)] == WindowKey(1, 12) and FrameKey(11, 1) not in owner
    assert owner[FrameKey(4, 2)] == WindowKey(2, 4)  # another object's window in the same frames


def test_a_frame_whose_window_was_rejected_or_diverged_keeps_its_single_fit() -> None:
    # falling_three frames 12-13: their window was rejected, and the previous window, never
    # judged on them, drew its object there three times too large: no falling back to it.
    statuses = _statuses([0] * 10) + [FrameStatus(i, Status.FITTED, (9, 9, 4, 4), track=1) for i in (4, 5)]
    statuses.sort(key=lambda s: s.index)
    for later in (_window(0, range(4, 10), accepted=False), None):  # rejected; diverged (not saved)
        windows = {WindowKey(0, 0): _window(0, range(6)), WindowKey(1, 4): _window(1, range(4, 6))}
        if later is not None:
            windows[WindowKey(0, 4)] = later
        results = RunResults(statuses, _Source(windows), JOINT)  # type: ignore[arg-type]
        shown = [results.shown_window(FrameKey(i, 0)) for i in range(10)]
        assert shown == [WindowKey(0, 0)] * 5 + [None] * 5
        assert results.shown_window(FrameKey(4, 1)) == results.shown_window(FrameKey(5, 1)) == WindowKey(1, 4)
        assert results.stands_for(Window(0, tuple(range(4, 10)))) == [5, 6, 7, 8, 9]
        assert results.shown_frames(Window(0, tuple(range(6)))) == [0, 1, 2, 3, 4]


def test_a_frame_its_window_explains_far_worse_keeps_its_single_fit() -> None:
    # falling_three frame 13 (2026-12-06): the pale end's window was accepted on its mean
    # (frame 11 rose -0.13 -> 0.66) while frame 13 fell 0.22 -> 0.06, its fit off the streak.
    explained = {9: (0.40, 0.37), 10: (0.34, 0.61), 11: (-0.13, 0.66), 12: (0.66, 0.63), 13: (0.22, 0.06)}
    window = _window(2, range(9, 14), explained=explained)
    assert trusted_frames(window, 0.15) == {9, 10, 11, 12}
    assert trusted_frames(window, 0.2) == {9, 10, 11, 12, 13}
    assert trusted_frames(dataclasses.replace(window, accepted=False), 0.15) == set()
    # Where its streak touched another object's, the window held the pose, and the frame's own
    # fit, drawn to the other's pixels, explains more: the window stands there (the crossing).
    crossing = dataclasses.replace(window, explained=explained | {13: (0.53, 0.32)})
    assert trusted_frames(crossing, 0.15) == {9, 10, 11, 12}
    assert trusted_frames(crossing, 0.15, held=[13]) == {9, 10, 11, 12, 13}
    # Unless it explains less than half as much as the frame's own fit.
    assert trusted_frames(window, 0.15, held=[13]) == {9, 10, 11, 12}
    # Held is never judged more strictly than not held: 0.08 is less than half of 0.20, but
    # within 0.15 of it.
    near = dataclasses.replace(window, explained=explained | {13: (0.20, 0.08)})
    assert trusted_frames(near, 0.15, held=[13]) == trusted_frames(near, 0.15) == {9, 10, 11, 12, 13}
    # A frame the window was not judged on (a window saved before the judgement) is its own.
    unjudged = dataclasses.replace(window, explained={i: e for i, e in explained.items() if i != 13})
    assert trusted_frames(unjudged, 0.15) == {9, 10, 11, 12, 13}
    statuses = [FrameStatus(i, Status.FITTED, (0, 0, 4, 4), track=2) for i in range(9, 14)]
    results = RunResults(statuses, _Source({WindowKey(2, 9): window}), JointConfig(max_explained_drop=0.15))  # type: ignore[arg-type]
    assert [i for i in range(9, 14) if results.shown_window(FrameKey(i, 2))] == [9, 10, 11, 12]
    # The crossing, read from the statuses: frame 13's blob holds another fitted object.
    statuses += [FrameStatus(13, Status.FITTED, (2, 2, 4, 4), track=3, touched=True)]
    statuses[4] = dataclasses.replace(statuses[4], touched=True)
    results = RunResults(statuses, _Source({WindowKey(2, 9): crossing}), JointConfig(max_explained_drop=0.15))  # type: ignore[arg-type]
    assert results.shown_window(FrameKey(13, 2)) == WindowKey(2, 9)


def test_without_joint_windows_every_object_shows_its_single_fit() -> None:
    results = RunResults(
        _statuses([0] * 4), _Source({WindowKey(0, 0): _window(0, range(4))}), JointConfig(enabled=False)
    )  # type: ignore[arg-type]
    assert results.windows == () and results.shown(FrameKey(2, 0)) == FrameKey(2, 0)


def test_each_object_is_read_back_as_the_export_shows_it(monkeypatch: pytest.MonkeyPatch) -> None:
    # Windows of frames 0-3, 2-5 and 4-7; the middle one diverged and was not saved. Its frames
    # (3 and 4) keep their single-frame fits. A dropped track's frame is not in the outputs, nor
    # is an object whose fit is missing from the folder.
    statuses = [FrameStatus(i, Status.FITTED, (0, 0, 4, 4), track=0) for i in range(8)]
    statuses.insert(4, FrameStatus(3, Status.DROPPED, (9, 9, 4, 4), track=1))
    statuses.append(FrameStatus(7, Status.FITTED, (9, 9, 4, 4), track=2))
    windows = {WindowKey(0, first): _window(0, range(first, first + 4)) for first in (0, 4)}
    source = _Source(windows, missing={FrameKey(7, 2)})
    monkeypatch.setattr(run_results, "with_joint", lambda single, window: (single, window.frames[0]))
    results = RunResults(statuses, source, JointConfig(window=4, overlap=2)).final()  # type: ignore[arg-type]
    assert set(results) == {FrameKey(i, 0) for i in range(8)}
    shown = [results[FrameKey(i, 0)] for i in range(8)]
    assert shown[:3] == [(FrameKey(i, 0), 0) for i in range(3)]
    assert shown[3:5] == [FrameKey(3, 0), FrameKey(4, 0)]
    assert shown[5:] == [(FrameKey(i, 0), 4) for i in range(5, 8)]
    every = RunResults(statuses, source, JointConfig(window=4, overlap=2))  # type: ignore[arg-type]
    assert every.showing(FrameKey(1, 0)) == ((FrameKey(1, 0), 0), windows[WindowKey(0, 0)])
    assert every.showing(FrameKey(3, 0)) == (FrameKey(3, 0), None)
    with pytest.raises(SfbError, match="track 2 in frame 7 is missing from the run"):
        every.shown(FrameKey(7, 2))


def test_a_folder_keeps_the_window_just_fitted_and_reads_each_other_one_when_asked(tmp_path: Path) -> None:
    source = FolderSource(tmp_path)
    assert source.window(WindowKey(0, 0)) is None  # not saved: its fit diverged
    fitted = _window(0, range(4))
    source.add_window(WindowKey(0, 0), fitted)
    assert source.window(WindowKey(0, 0)) is fitted  # not read back from the folder
    assert source.window(WindowKey(0, 2)) is None and source.window(WindowKey(1, 0)) is None


def test_a_dropped_track_gives_its_share_of_a_blob_back() -> None:
    # falling_three frame 10: a two-frame track, dropped as too short, had taken the lower half
    # of the pale end's streak; the pale end's windows saw only the upper half.
    statuses = [
        FrameStatus(10, Status.FITTED, (323, 38, 28, 54), track=1, touched=True),
        FrameStatus(10, Status.DROPPED, (332, 68, 20, 28), track=2, touched=True),
        FrameStatus(10, Status.FITTED, (344, 52, 32, 68), track=3),
        FrameStatus(11, Status.FITTED, (100, 100, 20, 20), track=1, touched=True),
        FrameStatus(11, Status.FITTED, (110, 115, 20, 20), track=3, touched=True),
        FrameStatus(11, Status.FITTED, (200, 200, 9, 9), track=4, touched=True),
    ]
    # Frame 11: tracks 1 and 3 still share one blob; track 4's part touches neither.
    assert touched_blobs(statuses)[1] == {FrameKey(11, 1), FrameKey(11, 3)}


def test_a_touched_frame_is_cropped_around_the_whole_blob_its_streak_shares() -> None:
    # The slow-beside scenario's frame 4: two streaks one over the other, one track's part of
    # their blob a 13 x 10 sliver of a 34 x 22 streak; its window's crop around the sliver cut
    # the streak off (the track's TIoU 0.725 -> 0.765 with the whole blob, three runs).
    parts = {
        FrameKey(4, 1): (122, 67, 39, 31),
        FrameKey(4, 2): (125, 72, 13, 10),
        FrameKey(4, 3): (160, 90, 20, 12),  # touches track 1's part (one blob of three)
        FrameKey(4, 5): (10, 10, 8, 8),  # another blob of the same frame
        FrameKey(4, 6): (19, 14, 8, 8),
        FrameKey(5, 1): (100, 60, 30, 20),  # another frame
        FrameKey(5, 2): (131, 60, 10, 10),
    }
    boxes = shared_boxes(parts)
    assert boxes[FrameKey(4, 1)] == boxes[FrameKey(4, 2)] == boxes[FrameKey(4, 3)] == (122, 67, 58, 35)
    assert boxes[FrameKey(4, 5)] == boxes[FrameKey(4, 6)] == (10, 10, 17, 12)
    assert boxes[FrameKey(5, 1)] == boxes[FrameKey(5, 2)] == (100, 60, 41, 20)


def test_statuses_are_read_back_as_written_and_a_wrong_one_is_named(tmp_path: Path) -> None:
    statuses = [
        FrameStatus(0, Status.FITTED, (1, 2, 3, 4), "", 0, True),
        FrameStatus(1, Status.MERGED, None, "its streak merged into track 0's", 1),
        FrameStatus(2, Status.NO_OBJECT),
        FrameStatus(3, Status.FAILED, note="unregistered"),
        FrameStatus(4, Status.DROPPED, (5, 6, 7, 8), "too short", 2),
    ]
    (tmp_path / MARKER).write_text(json.dumps({"kind": "run"}))
    write_statuses(tmp_path, statuses)
    assert read_run(tmp_path) == ({"kind": "run"}, statuses)
    assert json.loads((tmp_path / DETECTIONS).read_text())[1]["status"] == "merged"
    (tmp_path / DETECTIONS).write_text(json.dumps([{"index": 0, "status": "fited", "box": None, "note": ""}]))
    with pytest.raises(SfbError, match="cannot read the frame statuses"):
        read_run(tmp_path)
