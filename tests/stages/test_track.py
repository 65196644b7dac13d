"""Tracking's frame plumbing: which neighbouring masks the slow-mover test sees."""

from __future__ import annotations

import torch

from sfb_video.config import load_config
from stages.background import FrameWithBackground
from stages.track import with_neighbours


def _frames(count: int) -> list[FrameWithBackground]:
    """Frames whose difference mask marks pixel (0, k) in frame k (one value per frame)."""
    out = []
    for k in range(count):
        pixels = torch.zeros(3, 4, 8)
        pixels[:, 0, k] = 1.0
        out.append(FrameWithBackground(k, pixels, torch.zeros(3, 4, 8)))
    return out


def _neighbours(count: int) -> dict[int, list[int]]:
    config = load_config("default", ["detect.open_px=1", "detect.weak_threshold=0.5"])
    return {
        frame.index: [int(m[0].nonzero()[0]) for m in near]
        for frame, _, near in with_neighbours(iter(_frames(count)), config)
    }


def test_the_neighbours_are_two_frames_away_and_never_adjacent_where_the_clip_is_long_enough() -> None:
    # An adjacent frame's streak can overlap this one's end and would cut it off.
    assert _neighbours(8) == {0: [2], 1: [3], 2: [0, 4], 3: [1, 5], 4: [2, 6], 5: [3, 7], 6: [4], 7: [5]}
    assert _neighbours(3) == {0: [2], 1: [0, 2], 2: [0]}
    assert _neighbours(2) == {0: [1], 1: [0]}
