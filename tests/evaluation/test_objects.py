"""Each true object is scored against the track that covers it: a track that swaps objects at a
crossing loses recall on one of them, and a track that covers nothing is spurious."""

from __future__ import annotations

from sfb_video.evaluation.objects import box_iou, cover_objects, spurious_tracks


def _path(x0: int, step: int, frames: range) -> dict[int, tuple[int, int, int, int]]:
    return {k: (x0 + step * k, 40, 20, 20) for k in frames}


def test_a_swap_at_a_crossing_costs_recall_and_kept_identities_do_not() -> None:
    a, b = _path(0, 20, range(8)), _path(140, -20, range(8))
    kept = {0: a, 1: b, 5: {3: (200, 150, 10, 10)}}
    swapped = {0: {k: (a if k < 5 else b)[k] for k in range(8)}, 1: {k: (b if k < 5 else a)[k] for k in range(8)}}
    right = cover_objects([a, b], kept)
    assert [(c.track, c.recall, c.precision) for c in right] == [(0, 1.0, 1.0), (1, 1.0, 1.0)]
    assert spurious_tracks(right, kept) == {5: 1}
    wrong = cover_objects([a, b], swapped)
    # Track 0 holds a for 5 frames and b for 3: it covers a; b's best, track 1, found it 5 times.
    assert [(c.track, c.found, c.present, c.detections) for c in wrong] == [(0, 5, 8, 8), (1, 5, 8, 8)]
    assert wrong[0].precision == 5 / 8


def test_an_object_no_track_matched_has_no_track_and_no_recall() -> None:
    far = {0: {k: (250, 200, 10, 10) for k in range(4)}}
    [coverage] = cover_objects([_path(0, 20, range(4))], far)
    assert coverage.track is None and coverage.recall == 0.0
    assert spurious_tracks([coverage], far) == {0: 4}


def test_box_iou() -> None:
    assert box_iou((0, 0, 10, 10), (0, 0, 10, 10)) == 1.0
    assert box_iou((0, 0, 10, 10), (5, 0, 10, 10)) == 50 / 150
    assert box_iou((0, 0, 10, 10), (20, 0, 10, 10)) == 0.0
