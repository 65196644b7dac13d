"""The detection stage: a fast mover is found, a slow one is not, a track follows its prediction."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from sfb_video.config import load_config
from sfb_video.stages.detect import (
    FrameBlobs,
    Neighbour,
    blob_colour,
    box_blobs,
    choose_blob,
    detect,
    difference_mask,
    frame_blobs,
)
from sfb_video.stages.types import FrameWithBackground, Prediction

CONFIG = load_config("default").detect


def _mask(*boxes: tuple[int, int, int, int], size: tuple[int, int] = (60, 80)) -> torch.Tensor:
    mask = torch.zeros(size, dtype=torch.bool)
    for x, y, w, h in boxes:
        mask[y : y + h, x : x + w] = True
    return mask


def test_difference_mask_thresholds_the_colour_distance_and_drops_specks() -> None:
    background = torch.full((3, 40, 40), 0.5)
    image = background.clone()
    image[:, 10:20, 10:20] += 0.1  # ||diff|| = 0.17 > 0.1
    image[:, 30:31, 30:31] = 1.0  # a one-pixel speck, opened away
    image[0, 0:10, 30:40] += 0.08  # below the threshold
    mask = difference_mask(image, background, CONFIG)
    assert mask[10:20, 10:20].all() and int(mask.sum()) == 100


def test_the_fast_mover_is_chosen_over_a_larger_slow_one() -> None:
    arm = (50, 20, 25, 30)
    ball = (5, 5, 20, 8)
    mask = _mask(arm, ball)
    # The arm covers nearly the same pixels a frame before and after; the ball was elsewhere.
    before, after = _mask((52, 21, 25, 30), (30, 40, 20, 8)), _mask((48, 19, 25, 30))
    nothing = torch.zeros_like(mask)
    found = detect(3, mask, [Neighbour(before, nothing), Neighbour(after, nothing)], None, CONFIG)
    assert found is not None and found.box == ball


def test_what_differs_only_from_now_on_and_still_shows_is_not_a_fast_mover() -> None:
    # A line drawn over the video that grows each frame (an overlay), or a thing put down: not
    # there before, still showing after.
    ball, line = (5, 5, 20, 8), (10, 40, 60, 4)
    mask = _mask(ball, line)
    after = _mask(line, (40, 20, 20, 8))
    found = detect(3, mask, [Neighbour(after, _mask(line))], None, CONFIG)
    assert found is not None and found.box == ball
    # The same pixels differing in the frame before because its background held the object
    # there (it looks different now), and not in the frame after: the streak is kept.
    streak, nothing = (10, 40, 60, 4), torch.zeros(60, 80, dtype=torch.bool)
    neighbours = [Neighbour(_mask(streak), nothing), Neighbour(nothing, nothing)]
    found = detect(3, _mask(streak), neighbours, None, CONFIG)
    assert found is not None and found.box == streak


def test_only_slow_movers_means_no_object() -> None:
    mask = _mask((50, 20, 25, 30))
    arm = _mask((51, 20, 25, 30))
    assert detect(0, mask, [Neighbour(arm, arm & mask)], None, CONFIG) is None
    assert detect(0, torch.zeros(60, 80, dtype=torch.bool), [], None, CONFIG) is None


def test_a_tracked_object_is_looked_for_near_its_prediction() -> None:
    big, small = (40, 30, 30, 20), (5, 5, 12, 6)
    mask = _mask(big, small)
    assert detect(0, mask, [], None, CONFIG).box == big  # no track: the largest
    near_small = Prediction((11.0, 8.0), 6.0)
    assert detect(0, mask, [], near_small, CONFIG).box == small
    far_away = Prediction((300.0, 300.0), 6.0)
    assert detect(0, mask, [], far_away, CONFIG) is None


def test_a_tracked_object_is_preferred_by_its_colour() -> None:
    # A yellow-green ball's streak a little further from a poor prediction than a skin-coloured
    # shred of the arm of the same size, on a grey wall.
    background = torch.full((3, 60, 80), 128, dtype=torch.uint8)
    image = background.clone()
    ball, arm = (45, 20, 20, 8), (5, 20, 20, 8)
    for (x, y, w, h), rgb in ((ball, (190, 210, 90)), (arm, (200, 140, 110))):
        image[:, y : y + h, x : x + w] = torch.tensor(rgb, dtype=torch.uint8)[:, None, None]
    mask = _mask(ball, arm)
    green = blob_colour(image.numpy(), background.numpy(), _mask(ball).numpy())
    assert abs(sum(green) - 1) < 1e-5 and green[1] > green[0] > green[2]
    prediction = Prediction((30.0, 24.0), 10.0)  # 15 px from the arm's centre, 25 from the ball's
    assert choose_blob(0, mask, prediction, CONFIG).box == arm  # where nearness alone leads
    coloured = Prediction((30.0, 24.0), 10.0, green)
    assert choose_blob(0, mask, coloured, CONFIG, (image, background)).box == ball
    # Without the track's colour, or without the frame's pixels, nothing changes.
    assert choose_blob(0, mask, prediction, CONFIG, (image, background)).box == arm
    found = choose_blob(0, mask, coloured, CONFIG)
    assert found.box == arm and found.colour is None


def test_a_faint_tail_is_kept_with_its_strong_part_and_a_faint_blob_alone_is_not() -> None:
    generator = torch.Generator().manual_seed(0)
    background = torch.full((3, 40, 60), 0.5)
    image = background + 0.005 * torch.randn(background.shape, generator=generator)
    image[:, 10:20, 5:15] += 0.1  # strong: ||diff|| = 0.17
    image[:, 10:20, 15:30] += 0.04  # its faint tail: 0.07, above 4 x the noise (~0.009)
    image[:, 30:38, 40:55] += 0.04  # as faint, touching nothing strong
    mask = difference_mask(image, background, CONFIG)
    assert mask[10:20, 5:30].all()
    assert not mask[30:38, 40:55].any()
    # Noisier frames raise the weak level with their noise: the tail is lost in noise 0.03.
    noisy = image + 0.03 * torch.randn(background.shape, generator=generator)
    assert int(difference_mask(noisy, background, CONFIG)[10:20, 15:30].sum()) < 0.5 * 150


def test_fragments_of_a_streak_cut_by_a_fence_are_one_blob() -> None:
    streak = _mask((10, 20, 50, 12))
    for bar in range(14, 60, 10):  # 2 px bars every 10 px
        streak[:, bar : bar + 2] = False
    found = detect(0, streak, [], None, CONFIG)
    assert found is not None and found.box == (10, 20, 50, 12)
    apart = _mask((5, 5, 12, 8), (40, 40, 12, 8))  # two objects 23 px apart stay two
    assert detect(0, apart, [], None, CONFIG).box[2] == 12


def test_the_two_sides_of_a_ring_streak_are_one_blob() -> None:
    # A ring's blurred streak differs from the background on its two sides, far apart across
    # its hole; their boxes overlap.
    ring = _mask((10, 10, 40, 8), (10, 10, 8, 40))
    ring |= _mask((30, 30, 30, 8), (52, 22, 8, 16))
    found = detect(0, ring, [], None, CONFIG)
    assert found is not None and found.box == (10, 10, 50, 40)


def test_another_fast_mover_beside_the_chosen_one_is_counted() -> None:
    one, other, speck = (5, 5, 20, 8), (40, 40, 16, 8), (70, 5, 5, 5)
    found = detect(0, _mask(one, other, speck), [], None, CONFIG)
    assert found is not None and found.box == one and found.others == 1  # the speck is noise
    assert detect(0, _mask(one), [], None, CONFIG).others == 0


def test_the_weak_level_is_the_noise_of_the_pixels_compared_with_a_background() -> None:
    # A moving camera's frame equals its background where it saw nothing (a pan's margin):
    # those zeros are not its noise, or a noisy frame's weak level falls and a fence's faint
    # differences grow into a blob larger than the object.
    import numpy as np

    from sfb_video.stages.detect import weak_level

    rng = np.random.default_rng(0)
    difference = rng.uniform(0.015, 0.025, size=(120, 160)).astype(np.float32)
    known = torch.ones(120, 160, dtype=torch.bool)
    known[:, 64:] = False
    difference[:, 64:] = 0.0
    assert weak_level(difference, CONFIG) == CONFIG.weak_threshold
    noise = float(np.median(difference[:, :64]))
    assert abs(weak_level(difference, CONFIG, known) - CONFIG.weak_noise * noise) < 1e-3


def test_a_shred_of_a_larger_mover_or_a_shade_is_no_object_of_its_own() -> None:
    # On a grey wall: a green ball's streak, the fast fringe of a skin-coloured arm whose
    # changed region is much larger than the fringe, a shadow (the wall 10% darker) and a dark
    # grey object (the wall 60% darker, as grey as the shadow but no faint change).
    background = torch.full((3, 60, 120), 160, dtype=torch.uint8)
    image = background.clone()
    ball, arm, fringe = (5, 5, 20, 8), (40, 30, 30, 25), (40, 30, 6, 25)
    shadow, dark = (80, 5, 20, 10), (80, 40, 20, 10)
    for (x, y, w, h), rgb in ((ball, (150, 200, 80)), (arm, (210, 150, 120)), (shadow, (144,) * 3), (dark, (64,) * 3)):
        image[:, y : y + h, x : x + w] = torch.tensor(rgb, dtype=torch.uint8)[:, None, None]
    moving, changed = _mask(ball, fringe, shadow, dark, size=(60, 120)), _mask(ball, arm, shadow, dark, size=(60, 120))
    found = frame_blobs(moving, CONFIG, (image, background), changed)
    own = {tuple(int(v) for v in found.stats[k, :4]): found.own_object(k) for k in range(1, found.count)}
    assert own == {ball: True, fringe: False, shadow: False, dark: True}
    # The arm's fringe is its own object where its changed region is no larger than it.
    alone = frame_blobs(moving, CONFIG, (image, background), moving)
    own = {tuple(int(v) for v in alone.stats[k, :4]): alone.own_object(k) for k in range(1, alone.count)}
    assert own == {ball: True, fringe: True, shadow: False, dark: True}
    assert all(frame_blobs(moving, CONFIG).own_object(k) for k in range(1, found.count))
    # The rules are the config's: a larger shred ratio keeps the fringe, a dimmer shade bar the shadow.
    lenient = dataclasses.replace(CONFIG, shred_ratio=40.0, shade_contrast=0.05)
    found = frame_blobs(moving, lenient, (image, background), changed)
    own = {tuple(int(v) for v in found.stats[k, :4]): found.own_object(k) for k in range(1, found.count)}
    assert own == {ball: True, fringe: True, shadow: True, dark: True}
    # A frame of an 8-bit clip over a float background (a given image, or the whole clip's
    # median), and both float: each is read by its own type.
    for pair in ((image, background.float() / 255), (image.float() / 255, background.float() / 255)):
        mixed = frame_blobs(moving, CONFIG, pair, changed)
        own = {tuple(int(v) for v in mixed.stats[k, :4]): mixed.own_object(k) for k in range(1, mixed.count)}
        assert own == {ball: True, fringe: False, shadow: False, dark: True}


def test_a_tracked_object_is_not_taken_for_a_nearer_shadow_but_a_shade_alone_is_taken() -> None:
    # circle_fast.avi, frame 50: the ball's shadow on the wall lay nearer a poor prediction than
    # the ball's streak, and the track's colour, tinted by the arm, did not tell them apart.
    background = torch.full((3, 60, 120), 160, dtype=torch.uint8)
    image = background.clone()
    ball, shadow = (70, 20, 20, 10), (20, 20, 20, 10)
    for (x, y, w, h), rgb in ((ball, (150, 200, 80)), (shadow, (144,) * 3)):
        image[:, y : y + h, x : x + w] = torch.tensor(rgb, dtype=torch.uint8)[:, None, None]
    prediction = Prediction((50.0, 25.0), 20.0)  # 20 px from the shadow's centre, 30 from the ball's
    mask = _mask(ball, shadow, size=(60, 120))
    assert choose_blob(0, mask, prediction, CONFIG).box == shadow  # without the frame's pixels
    assert choose_blob(0, mask, prediction, CONFIG, (image, background)).box == ball
    unpenalised = dataclasses.replace(CONFIG, shade_penalty=1.0)
    assert choose_blob(0, mask, prediction, unpenalised, (image, background)).box == shadow
    alone = choose_blob(0, _mask(shadow, size=(60, 120)), prediction, CONFIG, (image, background))
    assert alone is not None and alone.box == shadow


def _streaks(*boxes: tuple[int, int, int, int], fringe: int = 4) -> tuple[torch.Tensor, ...]:
    """A frame, its background and its moving mask: strong streaks (``boxes``), each with a faint
    ``fringe`` px wide around it that joins them into one region of the mask where they lie
    close, as the hysteresis joins objects falling a few pixels apart."""
    background = torch.full((3, 110, 120), 0.5)
    image = background.clone()
    for x, y, w, h in boxes:
        image[:, max(0, y - fringe) : y + h + fringe, max(0, x - fringe) : x + w + fringe] = 0.54
    for k, (x, y, w, h) in enumerate(boxes):  # each its own colour; the fringe: ||diff|| 0.07,
        image[:, y : y + h, x : x + w] = 0.5  # under the threshold, over the weak one
        image[k % 3, y : y + h, x : x + w] += 0.3
    return image, background, difference_mask(image, background, CONFIG)


def _boxes(found: FrameBlobs) -> list[tuple[int, int, int, int]]:
    return sorted(tuple(int(v) for v in found.stats[k, :4]) for k in range(1, found.count) if found.stats[k, 4])


@pytest.mark.parametrize("dtype", [torch.float32, torch.uint8])
def test_objects_falling_side_by_side_one_a_little_ahead_are_split_from_their_joined_blob(dtype: torch.dtype) -> None:
    # falling_three.mp4, frames 10-11: three parallel streaks 7-12 px apart, each a third of its
    # length ahead of the next, joined by their faint fringes into one blob. A clip's frames are
    # kept as uint8.
    streaks = [(10, 10, 14, 40), (30, 35, 14, 40), (50, 60, 14, 40)]
    image, background, mask = _streaks(*streaks)
    if dtype == torch.uint8:
        image, background = ((255 * t).round().to(torch.uint8) for t in (image, background))
    assert len(_boxes(frame_blobs(mask, CONFIG))) == 1  # one blob without the frame's colours
    found = frame_blobs(mask, CONFIG, (image, background), changed=mask)
    boxes = _boxes(found)
    assert len(boxes) == 3
    for (x, y, w, h), (bx, by, bw, bh) in zip(streaks, boxes, strict=True):
        # Each part holds its whole streak and little of the others'.
        assert bx <= x and by <= y and bx + bw >= x + w and by + bh >= y + h
        assert bw <= w + 10 and bh <= h + 10, ((x, y, w, h), (bx, by, bw, bh))
    # Split from one changed region, each is an object of its own, not a shred of a larger mover.
    parts = [k for k in range(1, found.count) if found.stats[k, 4]]
    assert all(found.own_object(k) for k in parts)
    assert found.joined is not None and len({int(found.joined[k]) for k in parts}) == 1


def test_a_rings_two_sides_a_fence_cut_streak_and_streaks_at_an_angle_stay_one_blob() -> None:
    cases = {
        "a ring's two sides, level": [(10, 10, 14, 40), (34, 10, 14, 40)],
        "a streak cut by a wire": [(10, 10, 14, 30), (12, 48, 14, 30)],
        "streaks at a right angle": [(10, 10, 14, 40), (40, 60, 40, 14)],
    }
    for name, streaks in cases.items():
        image, background, mask = _streaks(*streaks, fringe=8)
        assert len(_boxes(frame_blobs(mask, CONFIG, (image, background)))) == 1, name


def test_a_given_box_is_one_blob_of_its_changed_pixels_or_of_all_of_them_when_asked() -> None:
    background = torch.full((3, 40, 60), 0.5)
    image = background.clone()
    image[:, 12:18, 22:30] = 0.9  # 48 changed pixels inside the box
    box = (20, 10, 15, 12)
    found = box_blobs(FrameWithBackground(0, image, background), box, CONFIG)
    assert found.count == 2 and found.area(1) == 48 and tuple(found.stats[1, :4]) == box
    still = box_blobs(FrameWithBackground(0, background.clone(), background), box, CONFIG)
    assert still.count == 1  # nothing changed: no blob
    whole = box_blobs(FrameWithBackground(0, background.clone(), background), box, CONFIG, whole=True)
    assert whole.count == 2 and whole.area(1) == 15 * 12 and (whole.labels == 1).sum() == 15 * 12


def test_a_predicted_streak_touches_a_blob_where_its_width_covers_one_of_its_pixels() -> None:
    found = frame_blobs(_mask((10, 5, 20, 10)), CONFIG)  # rows 5-14, columns 10-29
    label = int(found.labels[10, 20])

    def streak(a: tuple[float, float], b: tuple[float, float]) -> Prediction:
        return Prediction(((a[0] + b[0]) / 2, (a[1] + b[1]) / 2), 4.0, None, (a, b))  # 2 px wide each side

    # Above, below and beside the blob: touching at 2 px from its edge pixels, not at 3.
    assert found.touches(label, streak((12.0, 3.0), (20.0, 3.0)))
    assert not found.touches(label, streak((12.0, 2.0), (20.0, 2.0)))
    assert found.touches(label, streak((12.0, 16.0), (20.0, 16.0)))
    assert not found.touches(label, streak((12.0, 17.0), (20.0, 17.0)))
    assert found.touches(label, streak((31.0, 10.0), (40.0, 10.0)))
    assert not found.touches(label, streak((32.0, 10.0), (40.0, 10.0)))
    assert not found.touches(label, Prediction((20.0, 10.0), 4.0))  # no streak to cover it with
