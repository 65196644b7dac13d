"""The object region of a crop: the thresholded difference grown into the streak's faint parts."""

from __future__ import annotations

import torch

from sfb_video.config import CropConfig
from sfb_video.crop import make_crop, masks_onto, object_region
from sfb_video.geometry.camera import PinholeCamera


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


def test_masks_made_on_one_crop_are_drawn_where_the_same_pixels_are_on_another() -> None:
    # A touched frame's window crop covers the whole shared blob, not the part its single-frame
    # fit's crop (and its DeFMO masks) was made around.
    camera = PinholeCamera.from_fov(320, 240, 45.0)
    config = CropConfig(max_width=60)
    image = torch.full((3, 240, 320), 0.5)
    image[:, 100:110, 150:170] = 0.9  # the object: 20 x 10 px
    small = make_crop(image, torch.full_like(image, 0.5), (150, 100, 20, 10), camera, config)
    large = make_crop(image, torch.full_like(image, 0.5), (120, 80, 90, 60), camera, config)
    masks = torch.stack((small.object_mask, 1 - small.object_mask))
    moved = masks_onto(masks, small.box, large)
    assert moved.shape == (2, *large.image.shape[1:])
    # The object's mask lands on the object's pixels of the larger crop, within a pixel.
    ys, xs = torch.nonzero(moved[0] > 0.5, as_tuple=True)
    want_ys, want_xs = torch.nonzero(large.object_mask > 0.5, as_tuple=True)
    assert abs(float(xs.float().mean() - want_xs.float().mean())) <= 1.0
    assert abs(float(ys.float().mean() - want_ys.float().mean())) <= 1.0
    # Outside the small crop's box the masks are 0.
    scale = large.image.shape[2] / large.box[2]
    left = round((small.box[0] - large.box[0]) * scale) - 1
    assert float(moved[:, :, :left].abs().max()) == 0.0
