"""Tracking's frame plumbing: which neighbouring masks the slow-mover test sees."""

from __future__ import annotations

import torch

from sfb_video.config import load_config
from sfb_video.stages.track import with_neighbours
from sfb_video.stages.types import FrameWithBackground


def _frames(count: int) -> list[FrameWithBackground]:
    """Frames that all look the same, frame k differing from its own background at pixel (0, k)
    only: its difference mask, and what still shows of it in any other frame, is that pixel."""
    out = []
    for k in range(count):
        background = torch.full((3, 4, 8), 0.5)
        background[:, 0, k] = 0.0
        out.append(FrameWithBackground(k, torch.full((3, 4, 8), 0.5), background))
    return out


def _neighbours(count: int) -> dict[int, list[int]]:
    """Frame index -> the indices of its neighbours, negative for the earlier ones (which say
    nothing of what still shows: a track passing the same place twice would look still)."""
    config = load_config("default", ["detect.open_px=1", "detect.weak_threshold=0.5"])
    out = {}
    for frame, _, near in with_neighbours(iter(_frames(count)), config):
        out[frame.index] = []
        for n in near:
            index = int(n.mask[0].nonzero()[0])
            assert bool(n.still.any()) == (index > frame.index)
            out[frame.index].append(index if index > frame.index else -index)
    return out


def test_the_neighbours_are_two_frames_away_and_never_adjacent_where_the_clip_is_long_enough() -> None:
    # An adjacent frame's streak can overlap this one's end and would cut it off.
    assert _neighbours(8) == {0: [2], 1: [3], 2: [0, 4], 3: [-1, 5], 4: [-2, 6], 5: [-3, 7], 6: [-4], 7: [-5]}
    assert _neighbours(3) == {0: [2], 1: [0, 2], 2: [0]}
    assert _neighbours(2) == {0: [1], 1: [0]}
