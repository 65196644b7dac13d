"""Clips made by pasting a real streak along a path."""

from __future__ import annotations

import numpy as np
import pytest

from sfb_video.synth.pasted import paste_streak


def _pair() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    background = rng.integers(60, 200, (60, 90, 3)).astype(np.uint8)
    image = background.copy()
    image[20:30, 10:30] = 250  # the streak
    return image, background


def test_the_streak_moves_by_each_offset_and_the_rest_is_the_background() -> None:
    image, background = _pair()
    frames, boxes = paste_streak(image, background, [(0, 0), (30, 5), (55, 20)], noise_sigma=0.0)
    assert boxes == [(10, 20, 20, 10), (40, 25, 20, 10), (65, 40, 20, 10)]
    streak = image[20:30, 10:30].astype(int) - background[20:30, 10:30]
    for frame, (x, y, w, h) in zip(frames, boxes, strict=True):
        # The streak's difference from its own background, added to the background it moves over.
        expected = np.clip(background[y : y + h, x : x + w] + streak, 0, 255)
        assert (frame[y : y + h, x : x + w] == expected).all()
        away = np.ones(frame.shape[:2], dtype=bool)
        away[max(0, y - 4) : y + h + 4, max(0, x - 4) : x + w + 4] = False
        assert (frame[away] == background[away]).all()


def test_a_streak_moved_out_of_the_frame_is_refused() -> None:
    image, background = _pair()
    with pytest.raises(ValueError, match="out of the frame"):
        paste_streak(image, background, [(70, 0)])
