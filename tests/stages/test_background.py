"""The background stage: running median, its start-of-clip rule, frame ranges, and a given image."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from sfb_video.config import VideoConfig
from sfb_video.errors import SfbError
from sfb_video.stages.background import _median, fixed_background, running_median, with_backgrounds
from sfb_video.stages.types import Frame
from sfb_video.video import VideoWriter


def _frames(n: int, h: int = 6, w: int = 8) -> list[Frame]:
    # A static grey scene with a bright square passing through; frame k holds it at column k.
    frames = []
    for k in range(n):
        image = torch.full((3, h, w), 0.5)
        image[:, 2:4, k : k + 1] = 1.0
        frames.append(Frame(k, image))
    return frames


def test_running_median_removes_a_mover_and_uses_only_earlier_frames() -> None:
    frames = _frames(8)
    out = list(running_median(iter(frames), 3))
    assert [f.index for f in out] == list(range(8))
    for f in out:
        assert torch.equal(f.background, torch.full_like(f.background, 0.5))
    # From frame K on the background is the median of exactly the K previous frames: a change
    # that appears in frame 5 must not be in frame 5's own background.
    frames[5].image[:, 0, 0] = 0.0
    frames[6].image[:, 0, 0] = 0.0
    frames[7].image[:, 0, 0] = 0.0
    out = list(running_median(iter(frames), 3))
    assert out[5].background[0, 0, 0] == 0.5
    assert out[7].background[0, 0, 0] == 0.0  # two of the three previous frames have it


def test_running_median_at_the_start_of_a_short_clip() -> None:
    out = list(running_median(iter(_frames(3)), 5))
    assert len(out) == 3
    assert all(torch.equal(f.background, torch.full_like(f.background, 0.5)) for f in out)


def test_running_median_needs_two_frames() -> None:
    with pytest.raises(SfbError, match="at least 2 frames"):
        list(running_median(iter(_frames(1)), 5))


def test_fixed_background_must_match_the_frame_size() -> None:
    with pytest.raises(SfbError, match="but the frames are"):
        list(fixed_background(iter(_frames(2)), torch.zeros(3, 5, 5)))


@pytest.mark.parametrize("frames", [range(0, 2), range(3, 5), range(7, 12)])
def test_a_frame_range_gets_the_backgrounds_of_a_run_over_the_whole_clip(tmp_path: Path, frames: range) -> None:
    path = tmp_path / "clip.mp4"
    with VideoWriter(path, 30.0, 32, 24) as video:
        for frame in _frames(10, 24, 32):
            video.write(frame.image)
    config = VideoConfig(background_window=3)
    whole = {f.index: f for f in with_backgrounds(path, config, None)}
    part = list(with_backgrounds(path, config, None, frames))
    assert [f.index for f in part] == [i for i in frames if i < 10]
    for f in part:
        assert torch.equal(f.image, whole[f.index].image)
        assert torch.equal(f.background, whole[f.index].background)


def _pixel_over_time(values: list[float]) -> list[Frame]:
    """Frames of a grey scene whose pixel (0, 0) takes ``values`` in turn (the rest 0.5)."""
    frames = []
    for k, value in enumerate(values):
        image = torch.full((3, 2, 2), 0.5)
        image[:, 0, 0] = value
        frames.append(Frame(k, image))
    return frames


def test_objects_following_one_path_leave_no_ghost_at_the_clip_start() -> None:
    # Frame 0's background is the median of frames 1-5: two show the scene (0.5), three show
    # objects passing, each another colour. Their median (0.7) is an object's; the scene is what
    # agrees with itself. From frame K on (the K frames before it) the median is kept as it is.
    values = [0.5, 0.7, 0.9, 0.5, 0.8, 0.5, 0.5]
    plain = list(running_median(iter(_pixel_over_time(values)), 5, tolerance=0.0))
    agreed = list(running_median(iter(_pixel_over_time(values)), 5, tolerance=0.05))
    assert plain[0].background[0, 0, 0] == pytest.approx(0.7)
    assert agreed[0].background[0, 0, 0] == pytest.approx(0.5)
    assert agreed[6].background[0, 0, 0] == plain[6].background[0, 0, 0] == pytest.approx(0.7)
    # Elsewhere (every frame agrees) the background is the median, to the bit.
    first, median = agreed[0].background, plain[0].background
    assert torch.equal(first[:, 1:], median[:, 1:]) and torch.equal(first[:, 0, 1], median[:, 0, 1])


def test_a_median_that_another_frame_backs_is_kept() -> None:
    # A slow mover covers the pixel in three of the five frames, much the same each time (0.7,
    # 0.72): the median stays (the mover stays out of the difference, as it always did) though
    # the scene's two frames agree as well.
    values = [0.5, 0.7, 0.72, 0.5, 0.9, 0.5]
    agreed = next(running_median(iter(_pixel_over_time(values)), 5, tolerance=0.05)).background
    assert agreed[0, 0, 0] == pytest.approx(0.7)


def test_frames_that_did_not_see_a_pixel_do_not_count_towards_its_agreement() -> None:
    images = [torch.full((3, 1, 1), v) for v in (0.5, 0.7, 0.9, 0.5, 0.8)]
    assert _median(images, None, 0.05)[0, 0, 0] == pytest.approx(0.5)
    unseen = torch.zeros(1, 1, dtype=torch.bool)
    covers = [None, None, None, unseen, None]  # one of the scene's two frames did not see it
    assert _median(images, covers, 0.05)[0, 0, 0] == pytest.approx(0.7)  # the median of the rest
    # 8-bit frames: the tolerance is scaled, the result the same value.
    bytes_ = [(i * 255).round().to(torch.uint8) for i in images]
    assert int(_median(bytes_, None, 0.05)[0, 0, 0]) == round(0.5 * 255)
