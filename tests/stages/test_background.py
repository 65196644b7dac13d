"""The background stage: running median, its start-of-clip rule, frame ranges, and a given image."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from sfb_video.config import VideoConfig
from sfb_video.errors import SfbError
from sfb_video.stages.background import fixed_background, lower_median, running_median, with_backgrounds
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


@pytest.mark.parametrize("dtype", [torch.uint8, torch.float32])
def test_the_lower_median_is_torch_s_median_for_any_count_of_frames(dtype: torch.dtype) -> None:
    generator = torch.Generator().manual_seed(0)
    for n in range(1, 10):
        # Few distinct values, so that ties are common; torch takes the lower middle of an even count.
        values = torch.randint(0, 6, (n, 3, 7, 11), generator=generator).to(dtype)
        assert torch.equal(lower_median(list(values)), values.median(dim=0).values)
