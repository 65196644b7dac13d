import math

import numpy as np
import pytest

from sfb_video import metrics


def test_identical_subframes_score_perfectly() -> None:
    frames = np.random.default_rng(0).random((4, 16, 16, 3))
    assert metrics.psnr(frames, frames) == 100.0
    assert metrics.ssim(frames, frames) == pytest.approx(1.0)


def test_psnr_of_a_constant_offset() -> None:
    truth = np.zeros((2, 8, 8, 3))
    assert metrics.psnr(truth + 0.1, truth) == pytest.approx(20.0)


def test_disc_iou_by_hand() -> None:
    assert metrics.disc_iou(0.0, 5.0) == pytest.approx(1.0)
    assert metrics.disc_iou(10.0, 5.0) == pytest.approx(0.0)
    # Centres one radius apart: lens area (2 pi / 3 - sqrt(3) / 2) r^2.
    lens = 2 * math.pi / 3 - math.sqrt(3) / 2
    assert metrics.disc_iou(5.0, 5.0) == pytest.approx(lens / (2 * math.pi - lens))


def test_reversed_estimate_is_detected() -> None:
    truth = np.random.default_rng(1).random((5, 4, 4, 3))
    assert metrics.best_direction(truth[::-1], truth)
    assert not metrics.best_direction(truth, truth)


def test_rotation_error() -> None:
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    assert metrics.rotation_error_deg(rot, np.eye(3)) == pytest.approx(30.0)
