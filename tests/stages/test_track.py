"""Tracking: which neighbouring masks the slow-mover test sees, and a track per fast mover."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from benchmarks import detect as detect_benchmark
from sfb_video.config import Config, load_config
from sfb_video.crop import crop_box
from sfb_video.errors import NoObjectError
from sfb_video.evaluation.objects import box_iou
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.results import FrameResult, save_result
from sfb_video.run_folder import saved_frames
from sfb_video.stages.background import running_median
from sfb_video.stages.detect import FrameBlobs, blob_cost, frame_blobs, share_out
from sfb_video.stages.fit import continued
from sfb_video.stages.frame_buffer import FrameBuffer
from sfb_video.stages.track import track_and_fit, with_neighbours
from sfb_video.stages.tracking.assignment import Matched, match_tracks
from sfb_video.stages.tracking.cost import track_options
from sfb_video.stages.tracking.look_back import Held, HeldFit, held_region, look_back_into, proven_length
from sfb_video.stages.tracking.prediction import glide, predict
from sfb_video.stages.tracking.splitting import Claim, on_its_streak
from sfb_video.stages.tracking.tracker import Tracker, TrackNumbers, new_objects, short_tracks_dropped
from sfb_video.stages.types import Detection, Frame, FrameStatus, FrameWithBackground, Prediction, Registered
from sfb_video.synth import generate_clip

CAMERA = PinholeCamera.from_fov(320, 240, 45.0)
CPU = torch.device("cpu")


def _frames(count: int) -> list[FrameWithBackground]:
    """Frames that all look the same, frame k differing from its own background at pixel (0, k)
    only: its difference mask, and what still shows of it in any other frame, is that pixel."""
    out = []
    for k in range(count):
        background = torch.full((3, 4, 8), 0.5)
        background[:, 0, k] = 0.0
        out.append(FrameWithBackground(k, torch.full((3, 4, 8), 0.5), background))
    return out


def _neighbours(count: int, failed: int | None = None) -> dict[int, list[int]]:
    """Frame index -> the indices of its neighbours, negative for the earlier ones (which say
    nothing of what still shows: a track passing the same place twice would look still)."""
    config = load_config("default", ["detect.open_px=1", "detect.weak_threshold=0.5"])
    out = {}
    frames = _frames(count)
    if failed is not None:  # a moving camera's frame that did not register
        pixels = frames[failed].pixels
        registered = Registered(None, pixels, torch.ones(pixels.shape[1:], dtype=torch.bool), 0)
        frames[failed] = dataclasses.replace(frames[failed], registered=registered)
    for frame, _, near in with_neighbours(iter(frames), config.detect):
        out[frame.index] = []
        for n in near:
            index = int(n.mask[0].nonzero()[0])
            assert bool(n.still.any()) == (index > frame.index)
            out[frame.index].append(index if index > frame.index else -index)
    return out


def test_the_neighbours_are_two_frames_away_and_never_adjacent_where_the_clip_is_long_enough() -> None:
    # An adjacent frame's streak can overlap this one's end and would cut it off; at the clip's
    # ends the frame three away joins the one two away, so that one frame alone (where an object
    # following on the same path passes) does not decide what is slow.
    assert _neighbours(8) == {
        0: [2, 3],
        1: [3, 4],
        2: [0, 4],
        3: [-1, 5],
        4: [-2, 6],
        5: [-3, 7],
        6: [-4, -3],
        7: [-5, -4],
    }
    assert _neighbours(4) == {0: [2, 3], 1: [3], 2: [0], 3: [-1, 0]}
    # A frame that did not register is no neighbour: the others are still taken by distance.
    near = _neighbours(8, failed=3)
    assert near[1] == [4] and near[5] == [7] and near[6] == [-4] and near[2] == [0, 4]
    assert _neighbours(3) == {0: [2], 1: [0, 2], 2: [0]}
    assert _neighbours(2) == {0: [1], 1: [0]}


def _two_movers() -> tuple[list[FrameWithBackground], list[list[tuple[int, int, int, int]]]]:
    """A generated ball clip with a box clip's object composited in (benchmarks.detect's two
    movers), its frames with a running median, and per frame the two objects' true boxes."""
    spec = dataclasses.replace(detect_benchmark.BASE, num_frames=6)
    clip = generate_clip(spec)
    other = generate_clip(dataclasses.replace(spec, shape="box", seed=7))
    pixels = detect_benchmark._add_object(clip.frames, other)
    frames = [Frame(k, torch.from_numpy(np.ascontiguousarray(f.transpose(2, 0, 1)))) for k, f in enumerate(pixels)]
    truth = [[t.bbox, o.bbox] for t, o in zip(clip.truth, other.truth, strict=True)]
    return list(running_median(iter(frames), 5)), truth


@pytest.mark.parametrize("max_objects", [0, 1])
def test_every_fast_mover_has_its_own_track_unless_one_is_asked_for(tmp_path: Path, max_objects: int) -> None:
    frames, truth = _two_movers()
    config = load_config("fast", [f"video.max_objects={max_objects}"])
    camera = PinholeCamera.from_fov(320, 240, config.camera.fov_y_deg)
    statuses = track_and_fit(iter(frames), tmp_path, camera, config, torch.device("cpu"))
    fitted = [s for s in statuses if s.status == "fitted"]
    tracks: dict[int, list[FrameStatus]] = {}
    for s in fitted:
        tracks.setdefault(s.track, []).append(s)
    long = [t for t, own in tracks.items() if len(own) >= 5]
    assert len(long) == (2 if max_objects == 0 else 1), {t: [s.index for s in own] for t, own in tracks.items()}
    for track in long:
        # A track follows one object: the same true box is the best match in all its frames.
        matched = {max(range(2), key=lambda j: box_iou(s.box, truth[s.index][j])) for s in tracks[track]}
        assert len(matched) == 1
    assert len(saved_frames(tmp_path)) == len(fitted)  # each object's fit saved on its own


def test_tracks_too_short_to_be_objects_are_dropped_unless_none_is_longer() -> None:
    def fitted(index: int, track: int) -> FrameStatus:
        return FrameStatus(index, "fitted", (0, 0, 4, 4), "", track)

    statuses = [fitted(k, 0) for k in range(4)] + [fitted(1, 1), FrameStatus(2, "merged", None, "", 1)]
    kept = short_tracks_dropped(statuses, 3)
    assert [s.status for s in kept] == ["fitted"] * 4 + ["dropped", "dropped"]
    assert "fewer than video.min_track_frames" in kept[-1].note and kept[-1].track == 1
    # A clip whose every track is short keeps its longest (the lower number on a tie).
    short = [fitted(0, 0), fitted(1, 1), fitted(2, 1)]
    assert [s.status for s in short_tracks_dropped(short, 3)] == ["dropped", "fitted", "fitted"]
    assert short_tracks_dropped(short, 1) == short


def _tracker(config: Config, numbers: TrackNumbers | None = None) -> Tracker:
    return Tracker(CAMERA, config.detect, config.track, config.video.exposure_fraction, numbers)


def _fitted(index: int, x0: tuple[float, float, float], dx: tuple[float, float, float]) -> FrameResult:
    vertices, topology = load_prototype("sphere")
    motion = Motion(torch.tensor(x0), torch.tensor(dx), torch.eye(3), torch.zeros(3))
    state = ObjectState(vertices, topology, torch.full((3, 8, 8), 0.5), motion)
    box = (0, 0, 8, 8)
    return FrameResult(index, box, box, CAMERA, state, "cold", "sphere", {"image": 0.1}, [], 1.0)


def test_a_track_goes_on_where_its_streak_moved_on_though_its_fits_lag_on_speed() -> None:
    # A falling object gathers speed, and one frame's fit is unsure of its speed: each streak here
    # is fitted as 0.1 units long, while the object came 1.5 units down from one frame to the next.
    # Its 3D motion continued lands short, beside another object; the image's pace lands on it.
    config = load_config("fast")
    tracker = _tracker(config)
    tracker.earlier, tracker.previous = (
        _fitted(0, (0.0, -2.0, 8.0), (0.0, 0.1, 0.0)),
        _fitted(1, (0.0, -0.5, 8.0), (0.0, 0.1, 0.0)),
    )
    tracker.length, tracker.number = 2, 0
    continued_3d = predict(continued(tracker.previous, tracker.earlier, 2, config.video.exposure_fraction), CAMERA)
    lagging, paced = continued_3d.centre, glide(tracker.previous, tracker.earlier, 2, CAMERA).centre
    assert paced[1] - lagging[1] > continued_3d.diameter  # the two guesses are apart
    moving = np.zeros((CAMERA.height, CAMERA.width), bool)
    yy, xx = np.mgrid[: CAMERA.height, : CAMERA.width]
    radius = 0.4 * continued_3d.diameter
    own, other = (paced[0], paced[1]), (lagging[0] + 0.2 * radius, lagging[1] - 0.2 * radius)
    for cx, cy in (own, other):
        moving |= (xx - cx) ** 2 + (yy - cy) ** 2 <= radius**2
    found = frame_blobs(torch.from_numpy(moving), config.detect)
    (claim,) = match_tracks(found, [(tracker, tracker.predictions(2))], config.detect, config.track).claims
    x, y = found.centroids[claim.label]
    assert math.hypot(x - own[0], y - own[1]) < 1.5, (x, y, own, other)


def test_a_track_paced_by_two_whole_streaks_follows_the_pace_over_a_lagging_3d_guess() -> None:
    # falling_three frame 13: the grey object's 3D guess lagged onto the red end's streak, which
    # lay nearer it than the grey object's own blob lay to its paced guess, and took it.
    config = load_config("fast")
    tracker = _tracker(config)
    whole = (100, 100, 8, 8)  # neither streak cut off at the frame's edge
    tracker.earlier, tracker.previous = (
        dataclasses.replace(_fitted(0, (0.0, -3.0, 8.0), (0.0, 0.1, 0.0)), detection_box=whole),
        dataclasses.replace(_fitted(1, (0.0, -0.5, 8.0), (0.0, 0.1, 0.0)), detection_box=whole),
    )
    tracker.length, tracker.number = 2, 0
    continued_3d = predict(continued(tracker.previous, tracker.earlier, 2, config.video.exposure_fraction), CAMERA)
    lagging, paced = continued_3d.centre, glide(tracker.previous, tracker.earlier, 2, CAMERA).centre
    radius = 0.4 * continued_3d.diameter
    own, other = (paced[0] + 0.8 * radius, paced[1] + 0.8 * radius), lagging  # the other lies on its guess
    yy, xx = np.mgrid[: CAMERA.height, : CAMERA.width]

    def followed_to(centres: list[tuple[float, float]]) -> tuple[float, ...]:
        """The centre of the blob followed, and whether a fallback guess found it."""
        moving = np.zeros((CAMERA.height, CAMERA.width), bool)
        for cx, cy in centres:
            moving |= (xx - cx) ** 2 + (yy - cy) ** 2 <= radius**2
        found = frame_blobs(torch.from_numpy(moving), config.detect)
        (claim,) = match_tracks(found, [(tracker, tracker.predictions(2))], config.detect, config.track).claims
        assert claim.prediction is not None
        return (*found.centroids[claim.label], claim.prediction.fallback)

    x, y, fallback = followed_to([own, other])
    assert math.hypot(x - own[0], y - own[1]) < 1.5 and not fallback
    # Nothing where the pace leads (an object that landed stops): the 3D guess is still followed.
    reach = (
        config.detect.gate * glide(tracker.previous, tracker.earlier, 2, CAMERA).diameter + radius
    )  # gate_distance's
    far = (paced[0], paced[1] - reach - 2)  # beyond the paced guess's reach, in the 3D guess's
    x, y, fallback = followed_to([far])
    assert math.hypot(x - far[0], y - far[1]) < 1.5 and fallback
    # A streak cut off at the frame's edge paces nothing: the nearer guess's blob, as before.
    tracker.previous = dataclasses.replace(tracker.previous, detection_box=(0, 100, 8, 8))
    x, y, _ = followed_to([own, other])
    assert math.hypot(x - other[0], y - other[1]) < 1.5


def _track(config: Config, number: int, length: int) -> Tracker:
    """A track of ``length`` frames numbered ``number`` (its last frame a stand-in)."""
    tracker = _tracker(config)
    tracker.number, tracker.length = number, length
    tracker.previous = _fitted(0, (0.0, 0.0, 8.0), (0.0, 0.1, 0.0))
    return tracker


def _guess(x: float, y: float, diameter: float = 10.0, fallback: bool = False) -> Prediction:
    """A guess at a streak centred on (x, y), running 10 px along x."""
    return Prediction((x, y), diameter, None, ((x - 5.0, y), (x + 5.0, y)), fallback)


def _blobs(config: Config, boxes: list[tuple[int, int, int, int]], shape: tuple[int, int] = (60, 120)) -> FrameBlobs:
    moving = np.zeros(shape, bool)
    for x, y, w, h in boxes:
        moving[y : y + h, x : x + w] = True
    return frame_blobs(torch.from_numpy(moving), config.detect)


def _label_at(found: FrameBlobs, x: float, y: float) -> int:
    return int(found.labels[int(y), int(x)])


def _taken(matched: Matched) -> dict[int | None, int]:
    return {c.tracker.number: c.label for c in matched.claims}


def _match(found: FrameBlobs, config: Config, tracks: list[tuple[int, int, list[Prediction]]]) -> Matched:
    """``match_tracks`` for new tracks (number, length, guesses), each guess from its last frame."""
    asked = []
    for number, length, guesses in tracks:
        tracker = _track(config, number, length)
        asked.append((tracker, [(g, tracker.previous) for g in guesses]))
    return match_tracks(found, asked, config.detect, config.track)


def test_a_track_of_one_frame_gives_way_to_a_longer_one_with_no_other_blob() -> None:
    # A pen's streak came in two pieces and the second started a track, whose guess landed nearer
    # the next frame's blob than the pen's did: the pen keeps its object.
    config = load_config("fast")
    found = _blobs(config, [(20, 10, 20, 10)])
    pen, piece = (0, 5, [_guess(30.0, 30.0)]), (1, 1, [_guess(30.0, 17.0)])
    for tracks in ([pen, piece], [piece, pen]):
        matched = _match(found, config, tracks)
        assert _taken(matched) == {0: 1} and not matched.merged
    # Where the longer track has a blob of its own in its gate, the nearer guess takes the blob.
    found = _blobs(config, [(20, 10, 20, 10), (20, 40, 20, 10)])
    mine, other = _label_at(found, 30, 15), _label_at(found, 30, 45)
    assert _taken(_match(found, config, [(0, 5, [_guess(30.0, 35.0)]), piece])) == {0: other, 1: mine}
    # A longer track whose only other blob a fallback guess reaches keeps the blob too.
    far = [_guess(30.0, 18.0, 4.0), _guess(30.0, 45.0, fallback=True)]  # the first's gate: 26 px
    assert _taken(_match(found, config, [(0, 5, far), piece]))[0] == mine


def test_a_track_whose_blob_another_takes_goes_to_a_blob_left_in_its_gate_else_shares_where_its_streak_covers_it() -> (
    None
):
    # Three objects: a track's guess lagged between the streak another track took and its own.
    config = load_config("fast")
    found = _blobs(config, [(10, 5, 20, 10), (10, 40, 20, 10)])
    upper, lower = _label_at(found, 20, 10), _label_at(found, 20, 45)
    lead, lagging = (0, 3, [_guess(20.0, 10.0)]), (1, 3, [_guess(20.0, 25.0)])
    matched = _match(found, config, [lead, lagging])
    assert _taken(matched) == {0: upper, 1: lower} and all(c.part is None for c in matched.claims)
    # Where only a fallback guess reaches the blob left, the two share the taken blob.
    lagging = (1, 3, [_guess(20.0, 13.0, 5.0), _guess(20.0, 45.0, fallback=True)])
    matched = _match(found, config, [lead, lagging])
    assert _taken(matched) == {0: upper, 1: upper}
    assert [[t.number for t in c.shared_with] for c in matched.claims] == [[1], [0]]
    # A share is only for a track whose predicted streak covers a pixel of the blob: one whose
    # streak runs just past it coasts, its streak merged into the other's.
    found = _blobs(config, [(10, 5, 40, 10)])
    lead = (0, 3, [_guess(15.0, 10.0)])
    matched = _match(found, config, [lead, (1, 3, [_guess(45.0, 18.0, 4.0)])])  # 2 px below the blob
    assert _taken(matched) == {0: 1} and [(t.number, k) for t, k in matched.merged] == [(1, 1)]
    matched = _match(found, config, [lead, (1, 3, [_guess(45.0, 16.0, 4.0)])])  # on its bottom row
    assert _taken(matched) == {0: 1, 1: 1} and all(c.part is not None for c in matched.claims)


def test_a_blob_is_taken_by_the_track_s_guess_that_lands_nearest_it_in_pixels() -> None:
    # A 3D guess from a fit unsure of its depth foresees a larger object: in its own diameters it
    # misses less, though its centre lies further off. The streak it would share a blob by is the
    # nearer guess's.
    config = load_config("fast")
    found = _blobs(config, [(20, 10, 20, 10)])
    label = _label_at(found, 30, 15)
    near, vague = _guess(30.0, 22.0), _guess(30.0, 25.0, 16.0)
    assert blob_cost(found, label, vague, config.detect) < blob_cost(found, label, near, config.detect)
    last = _fitted(0, (0.0, 0.0, 8.0), (0.0, 0.1, 0.0))
    for guesses in ([near, vague], [vague, near]):
        option = track_options(found, [(g, last) for g in guesses], config.detect, config.track)[label]
        assert option.prediction is near and option.cost == blob_cost(found, label, near, config.detect)
    # A fallback guess takes the blob only where no other guess reaches it, a tier dearer.
    fallback = _guess(30.0, 15.0, fallback=True)
    assert track_options(found, [(near, last), (fallback, last)], config.detect, config.track)[label].prediction is near
    option = track_options(found, [(fallback, last)], config.detect, config.track)[label]
    assert option.prediction is fallback
    assert option.cost == blob_cost(found, label, fallback, config.detect) + config.track.fallback_cost


def test_the_assignment_does_not_depend_on_the_order_of_the_tracks() -> None:
    config = load_config("fast")
    rng = np.random.default_rng(0)
    for _ in range(20):
        boxes = [(int(x), int(y), int(w), 10) for x, y, w in rng.integers((0, 0, 12), (100, 50, 30), (5, 3))]
        found = _blobs(config, boxes)
        tracks = []
        for number in range(int(rng.integers(2, 6))):
            guesses = [
                _guess(*rng.uniform((0, 0), (120, 60)), fallback=bool(k and rng.random() < 0.5)) for k in range(2)
            ]
            tracks.append((number, int(rng.choice([1, 2, 5])), guesses))
        outcomes = []
        for order in (tracks, tracks[::-1], [tracks[k] for k in rng.permutation(len(tracks))]):
            found_copy = _blobs(config, boxes)
            matched = _match(found_copy, config, order)
            outcomes.append(
                (
                    sorted(
                        (c.tracker.number, c.label, sorted(t.number for t in c.shared_with)) for c in matched.claims
                    ),
                    sorted((t.number, label) for t, label in matched.merged),
                    [
                        None if c.part is None else c.part.tobytes()
                        for c in sorted(matched.claims, key=lambda c: c.tracker.number)
                    ],
                )
            )
        assert outcomes[0] == outcomes[1] == outcomes[2]
    assert found.count > 1


def _merge(found: FrameBlobs, config: Config, holder: Tracker, merged: Tracker) -> Matched:
    """Two tracks' guesses on blob 1, the ``holder``'s nearer, without streaks to share it by."""
    return match_tracks(
        found,
        [
            (merged, [(Prediction((30.0, 18.0), 10.0), merged.previous)]),
            (holder, [(Prediction((30.0, 15.0), 10.0), holder.previous)]),
        ],
        config.detect,
        config.track,
    )


def test_a_track_whose_streak_merged_into_another_s_coasts_then_ends() -> None:
    # Its streak inside a blob the other track takes, nearer that one's guess, and no way to share
    # it out (no predicted streaks).
    for max_coast in (0, 2):
        config = load_config("fast", [f"track.max_coast={max_coast}"])
        found = _blobs(config, [(20, 10, 20, 10)])
        holder, merged = _track(config, 0, 5), _track(config, 1, 3)

        for _ in range(max_coast):
            matched = _merge(found, config, holder, merged)
            assert _taken(matched) == {0: 1} and matched.merged == [(merged, 1)]
            assert merged.length == 3
        assert _merge(found, config, holder, merged).merged == [(merged, 1)]
        assert merged.length == 0 and merged.previous is None  # ended
    # A track with no blob in its gate ends at once.
    lost = _track(config, 2, 5)
    matched = match_tracks(
        found, [(lost, [(Prediction((100.0, 50.0), 5.0), lost.previous)])], config.detect, config.track
    )
    assert not matched.claims and not matched.merged and lost.previous is None


def test_a_piece_of_a_track_s_streak_split_off_as_an_object_beside_it_is_joined_back() -> None:
    # The slow-beside scenario's pen, frame 7: its thin streak came in two cores end to end,
    # 3 px apart across, split as two objects beside each other; its track took one piece.
    mask = np.zeros((40, 80), np.uint8)
    mask[10:14, 10:25] = 1  # the piece the track took, centre (17, 11.5)
    mask[13:17, 27:40] = 1  # end to end with it, 3 px lower: on the streak
    mask[22:26, 12:27] = 1  # a streak 12 px lower: an object beside it
    count, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    by_x = {round(c[0]): k for k, c in enumerate(centroids[1:], 1)}
    mine, on, beside = by_x[17], by_x[33], by_x[19]
    found = FrameBlobs(count, labels, stats, centroids, joined=np.array([0, mine, mine, mine]))
    prediction = Prediction((25.0, 13.0), 9.0, ends=((40.0, 14.0), (10.0, 12.0)))
    claim = Claim(_tracker(load_config("fast")), mine, 0, prediction)
    assert on_its_streak(found, claim, {on, beside}) == [on]
    assert on_its_streak(found, claim, {beside}) == []  # another track took it or wants it
    assert on_its_streak(dataclasses.replace(found, joined=None), claim, {on, beside}) == []
    # A claim on a part of a shared blob, or with no prediction, takes nothing back.
    assert on_its_streak(found, dataclasses.replace(claim, part=labels == mine), {on, beside}) == []
    assert on_its_streak(found, dataclasses.replace(claim, prediction=None), {on, beside}) == []
    found.merge(mine, [on])
    assert tuple(found.stats[mine]) == (10, 10, 30, 7, 60 + 52) and found.area(on) == 0
    assert not (found.labels == on).any()
    assert found.centroids[mine][0] == pytest.approx((60 * 17 + 52 * 33) / 112)


def test_beside_a_tracked_object_only_objects_of_their_own_start_tracks() -> None:
    # circle_fast.avi with every mover tracked: the arm's fast fringes and the ball's shadow on
    # the wall started twelve tracks beside the ball's, which took its blob from it in turn.
    config = load_config("fast")
    background = torch.full((3, 60, 120), 160, dtype=torch.uint8)
    image = background.clone()
    ball, other, arm, fringe, shadow = (5, 5, 20, 8), (5, 40, 20, 8), (40, 30, 30, 25), (40, 30, 6, 25), (80, 5, 20, 10)
    for (x, y, w, h), rgb in (
        (ball, (150, 200, 80)),
        (other, (60, 60, 200)),
        (arm, (210, 150, 120)),
        (shadow, (144,) * 3),
    ):
        image[:, y : y + h, x : x + w] = torch.tensor(rgb, dtype=torch.uint8)[:, None, None]
    moving, changed = np.zeros((60, 120), bool), np.zeros((60, 120), bool)
    for (x, y, w, h), where in ((ball, (moving, changed)), (other, (moving, changed)), (arm, (changed,))):
        for m in where:
            m[y : y + h, x : x + w] = True
    for x, y, w, h in (fringe, shadow):
        moving[y : y + h, x : x + w] = changed[y : y + h, x : x + w] = True
    found = frame_blobs(torch.from_numpy(moving), config.detect, (image, background), torch.from_numpy(changed))
    box = {k: tuple(int(v) for v in found.stats[k, :4]) for k in range(1, found.count)}
    label = {b: k for k, b in box.items()}
    # No track yet: the largest blob starts one whatever it is, as with one object tracked.
    assert [box[k] for k in new_objects(found, set(), config.detect, config.track, alone=True)] == [shadow, ball, other]
    assert [box[k] for k in new_objects(found, {label[ball]}, config.detect, config.track, alone=False)] == [other]


def test_a_blob_three_streaks_touch_in_is_shared_out_among_all_three() -> None:
    config = load_config("fast")
    moving = np.zeros((40, 100), bool)
    moving[15:25, 5:95] = True  # three streaks end to end, one blob
    found = frame_blobs(torch.from_numpy(moving), config.detect)
    streaks = [Prediction((x + 12.5, 20.0), 10.0, None, ((x + 5.0, 20.0), (x + 20.0, 20.0))) for x in (5, 35, 65)]
    # A track of one frame only guesses its direction: it shares no blob, and gives way.
    matched = _match(found, config, [(0, 1, streaks[:1]), (1, 2, streaks[1:2]), (2, 2, streaks[2:])])
    assert sorted(_taken(matched)) == [1, 2]
    assert [[t.number for t in c.shared_with] for c in matched.claims] == [[2], [1]]
    matched = _match(found, config, [(n, 2, [s]) for n, s in enumerate(streaks)])
    claims = matched.claims
    parts = [c.part for c in claims]
    assert all(p is not None for p in parts)
    owners = np.stack(parts).sum(0)
    assert (owners[moving] == 1).all() and (owners[~moving] == 0).all()  # every pixel once
    for part, streak in zip(parts, streaks, strict=True):  # each around its own streak
        assert abs(np.nonzero(part)[1].mean() - streak.centre[0]) <= 2
    assert [len(c.shared_with) for c in claims] == [2, 2, 2]
    # A blob shared out in its region (a look back keeps only that) as in the whole frame.
    window = (slice(10, 30), slice(0, 100))
    assert all(
        (a == b[window]).all()
        for a, b in zip(share_out(moving[window], streaks, 1, (0, 10)), found.split(1, streaks, 1), strict=True)
    )


@pytest.mark.parametrize(("seed", "aspect"), [(0, 4 / 3), (1, 4 / 3), (2, 1.0), (3, 2.0)])
def test_the_region_kept_of_a_blob_holds_every_crop_of_a_part_of_it(seed: int, aspect: float) -> None:
    rng = np.random.default_rng(seed)
    config = dataclasses.replace(load_config("fast").crop, aspect=aspect)
    size = (320, 240)
    for _ in range(300):
        w, h = (int(v) for v in rng.integers(1, 120, 2))
        x, y = int(rng.integers(0, size[0] - w + 1)), int(rng.integers(0, size[1] - h + 1))
        rx, ry, rw, rh = held_region((x, y, w, h), size, config)
        assert rx >= 0 and ry >= 0 and rx + rw <= size[0] and ry + rh <= size[1]
        pw, ph = (int(v) for v in rng.integers(1, (w + 1, h + 1)))
        px, py = x + int(rng.integers(0, w - pw + 1)), y + int(rng.integers(0, h - ph + 1))
        # The fit's crop, and DeFMO's 4:3 window (sfb_video.defmo.defmo_masks).
        for crop in (config, dataclasses.replace(config, margin=config.defmo_margin, aspect=4 / 3)):
            cx, cy, cw, ch = crop_box((px, py, pw, ph), size, crop)
            assert rx <= cx and ry <= cy and cx + cw <= rx + rw and cy + ch <= ry + rh, ((x, y, w, h), (px, py, pw, ph))


def _disc_blob(shape: tuple[int, int], centres: list[tuple[float, float]], radius: float) -> np.ndarray:
    v, u = np.mgrid[: shape[0], : shape[1]]
    return np.any([(u - x) ** 2 + (v - y) ** 2 <= radius**2 for x, y in centres], axis=0)


def test_a_track_looks_back_only_into_a_blob_grown_by_its_object(tmp_path: Path) -> None:
    # A shred or a second track of one object, moving beside a tracked object, slid back onto
    # that object's whole blob and split it: only a blob larger than its track's own of the next
    # frame, by about the looking track's object, holds that object too.
    config = load_config("fast")
    assert (
        proven_length(config.video) == 3 and proven_length(load_config("fast", ["video.min_track_frames=1"]).video) == 2
    )
    numbers = TrackNumbers()
    owner, late = _tracker(config, numbers), _tracker(config, numbers)
    owner.number, late.number = 0, 1
    first = dataclasses.replace(_fitted(2, (0.0, 0.0, 8.0), (0.1, 0.0, 0.0)), track=1)
    last = dataclasses.replace(_fitted(4, (0.6, 0.0, 8.0), (0.1, 0.0, 0.0)), track=1)
    for result in (first, last):
        save_result(tmp_path, result)
    late.previous, late.length = last, 3
    owner.previous, owner.length = dataclasses.replace(_fitted(4, (0.0, 1.0, 8.0), (0.0, 0.1, 0.0)), track=0), 5
    shape = (240, 320)
    back = glide(first, last, 1, CAMERA)
    aside = (back.centre[0], back.centre[1] + 30.0)
    mine = _disc_blob(shape, [predict(first.state.motion, CAMERA).centre], 8.0)
    empty = torch.zeros((3, *shape))

    def held(index: int, blob: np.ndarray, fits: list[HeldFit]) -> list[Held]:
        return [Held(index, shape, (0, 0, shape[1], shape[0]), empty, empty, blob, fits)]

    def owner_fit(at: tuple[float, float]) -> HeldFit:
        ahead = Prediction(at, 36.0, None, ((at[0] - 5, at[1]), (at[0] + 5, at[1])))
        return HeldFit(owner, 0, ahead, None, None, None)

    fitted: list[int] = []

    def fit(frame: FrameWithBackground, *args: object) -> FrameResult:
        fitted.append(frame.index)
        raise NoObjectError("stop here")  # the look back gives up on the frame

    near = (back.centre[0] + 4.0, back.centre[1])
    for discs, at, looked in (
        ([back.centre], near, []),  # the owner's own object on the path: its blob no larger
        ([aside, back.centre], aside, [1]),  # the owner's object beside, and this one on the path
    ):
        frames = [
            held(1, _disc_blob(shape, discs, 12.0), [owner_fit(at)]),
            held(2, _disc_blob(shape, [aside], 12.0), [owner_fit(aside)])
            + held(2, mine, [HeldFit(late, 1, None, None, None, None)]),
            held(3, np.zeros(shape, bool), []),
        ]
        fitted.clear()
        buffer = FrameBuffer(tmp_path)
        look_back_into(late, frames, buffer, set(), CAMERA, config.detect, config.track, config.video, fit)
        assert fitted == looked  # refitted (and given up) only where the blob grew by the object
        assert buffer.close() == []  # nothing restated
    assert late.length == 3 and saved_frames(tmp_path) == {(2, 1), (4, 1)}


def test_a_track_coasts_for_its_config_s_frames_then_ends() -> None:
    for max_coast in (0, 2, 5):
        tracker = _tracker(load_config("default", [f"track.max_coast={max_coast}"]))
        tracker.length = 3
        for _ in range(max_coast):
            tracker.coast()
        assert tracker.length == 3, max_coast
        tracker.coast()
        assert tracker.length == 0, max_coast


def _streak_fit(
    frame: FrameWithBackground,
    detection: Detection,
    camera: PinholeCamera,
    config: Config,
    start: FrameResult | None,
    device: torch.device,
    masks: object = None,
    earlier: FrameResult | None = None,
) -> FrameResult:
    """A stand-in for the fit: the detection's pixels read as a ball of unit diameter smeared
    along their longest axis, as wide as they are across, at the depth that width gives."""
    ys, xs = np.nonzero(detection.mask.cpu().numpy())
    points = np.stack((xs, ys), 1).astype(np.float64)
    centre = points.mean(0)
    axes = np.linalg.svd(points - centre, full_matrices=False)[2]
    along, across = (points - centre) @ axes[0], (points - centre) @ axes[1]
    diameter = float(across.max() - across.min() + 1)
    half = max((float(along.max() - along.min()) + 1 - diameter) / 2, 0.5)
    ends = torch.tensor(np.stack((centre - half * axes[0], centre + half * axes[0])), dtype=torch.float32)
    x0, x1 = camera.unproject(ends, torch.full((2,), camera.fy / diameter))
    vertices, topology = load_prototype("sphere")
    state = ObjectState(
        vertices, topology, torch.full((3, 8, 8), 0.5), Motion(x0, x1 - x0, torch.eye(3), torch.zeros(3))
    )
    return FrameResult(frame.index, detection.box, detection.box, camera, state, "cold", "sphere", {}, [], 0.0)


MOVERS = {  # start (x, y) of the first streak, travel (x, y) per frame, first frame, colour
    "down": ((60.0, 30.0), (24.0, 16.0), 0, (0.9, 0.2, 0.2)),
    "up": ((60.0, 210.0), (24.0, -16.0), 0, (0.2, 0.3, 0.9)),
    "later": ((20.0, 20.0), (0.0, 24.0), 2, (0.2, 0.8, 0.3)),
}


def _streaks(
    frames: int, radius: float = 6.0
) -> tuple[list[FrameWithBackground], list[dict[str, tuple[float, float]]]]:
    """Frames of the :data:`MOVERS` as capsules (a shutter open the whole frame), and per frame
    the centre of each mover's streak."""
    yy, xx = np.mgrid[:240, :320].astype(np.float64)
    background = torch.full((3, 240, 320), 0.5)
    out, centres = [], []
    for k in range(frames):
        pixels, here = background.clone(), {}
        for name, ((x, y), (vx, vy), first, colour) in MOVERS.items():
            if k < first:
                continue
            a = np.array((x + vx * (k - first), y + vy * (k - first)))
            along = np.clip(((xx - a[0]) * vx + (yy - a[1]) * vy) / (vx * vx + vy * vy), 0, 1)
            inside = np.hypot(xx - a[0] - along * vx, yy - a[1] - along * vy) <= radius
            pixels[:, torch.from_numpy(inside)] = torch.tensor(colour)[:, None]
            here[name] = (a[0] + vx / 2, a[1] + vy / 2)
        out.append(FrameWithBackground(k, pixels, background))
        centres.append(here)
    return out, centres


def test_two_objects_that_cross_keep_their_tracks_and_one_outside_every_gate_starts_its_own(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The two streaks touch in frames 5 and 6; the third mover appears at frame 2, far from both.
    monkeypatch.setattr("sfb_video.stages.track.fit_detection", _streak_fit)
    frames, centres = _streaks(10)
    config = load_config("fast", ["video.max_objects=0"])
    statuses = track_and_fit(iter(frames), tmp_path, CAMERA, config, CPU)
    whose: dict[int, set[str]] = {}
    seen: dict[int, list[int]] = {}
    for s in statuses:
        if s.status != "fitted" or s.touched:
            continue
        assert s.box is not None and s.track is not None
        x, y, w, h = s.box
        name = min(centres[s.index], key=lambda n: math.dist(centres[s.index][n], (x + w / 2, y + h / 2)))
        whose.setdefault(s.track, set()).add(name)
        seen.setdefault(s.track, []).append(s.index)
    assert sorted(len(names) for names in whose.values()) == [1, 1, 1], whose  # no track swaps objects
    track = {names.pop(): t for t, names in whose.items()}
    assert set(track) == set(MOVERS)
    for name in ("down", "up"):  # one track each, before the crossing and after it
        assert {0, 1, 2, 3, 4, 7, 8, 9} <= set(seen[track[name]]), seen
    assert min(seen[track["later"]]) == 2 and len(seen[track["later"]]) >= 6
