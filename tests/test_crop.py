"""The object region of a crop: the thresholded difference grown into the streak's faint parts."""

from __future__ import annotations

import torch

from sfb_video.config import CropConfig
from sfb_video.crop import object_region


def _faint_streak(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """A noisy grey crop with a 60 x 8 px streak whose contrast falls from 0.3 at its right end
    to 0.03 over most of it (a grey object, seen briefly), and a bright speck far from it."""
    generator = torch.Generator().manual_seed(seed)
    background = torch.full((3, 80, 120), 0.4)
    streak = torch.zeros(80, 120, dtype=torch.bool)
    streak[36:44, 30:90] = True
    contrast = torch.zeros(80, 120)
    contrast[36:44, 30:80] = 0.013  # per channel: 0.039 summed, under the 0.05 threshold
    contrast[36:44, 80:90] = 0.1
    speck = torch.zeros(80, 120, dtype=torch.bool)
    speck[5:8, 5:8] = True
    contrast[speck] = 0.2
    noise = 0.004 * torch.randn(3, 80, 120, generator=generator)
    return background + contrast + noise, background, streak, speck


def test_the_region_grows_into_the_faint_streak_and_no_further() -> None:
    image, background, streak, speck = _faint_streak()
    config = CropConfig()
    thresholded = object_region(image, background, config.region_threshold, 0.0)
    grown = object_region(image, background, config.region_threshold, config.region_noise)
    # The threshold keeps the bright end alone; the grown region holds the streak.
    assert float((thresholded & streak).sum() / streak.sum()) < 0.3
    assert float((grown & streak).sum() / streak.sum()) > 0.9
    # It does not spread into the noise: outside the streak (grown by a pixel), the speck alone.
    near = torch.nn.functional.max_pool2d(streak[None, None].float(), 3, 1, 1)[0, 0] > 0
    assert int((grown & ~near & ~speck).sum()) < 10
    assert bool(grown[speck].all())  # a blob above the threshold stays (the largest is chosen later)


def test_noise_zero_keeps_the_threshold_alone() -> None:
    image, background, _, _ = _faint_streak(1)
    threshold = CropConfig().region_threshold
    expected = (image - background).abs().sum(0) > threshold
    assert torch.equal(object_region(image, background, threshold, 0.0), expected)
