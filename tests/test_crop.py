"""The object region of a crop: the thresholded difference grown into the streak's faint parts."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from sfb_video.config import CropConfig
from sfb_video.crop import box_mask, make_crop, mask_box, masks_onto, object_region, streak_width
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


def test_the_streak_width_is_its_thickness_in_any_direction() -> None:
    for end in ((180, 20), (180, 150), (20, 180)):  # along, diagonal, down
        blob = np.zeros((200, 200), np.uint8)
        cv2.line(blob, (20, 20), end, 1, 15)
        assert 14.0 <= streak_width(blob > 0) <= 19.0, end
    disc = np.zeros((60, 60), np.uint8)
    cv2.circle(disc, (30, 30), 12, 1, -1)
    assert 23.0 <= streak_width(disc > 0) <= 25.0
    assert streak_width(np.zeros((5, 5), bool)) == 0.0


@pytest.mark.parametrize("given", ["blob", "whole box", "none"])
def test_a_large_object_is_fitted_at_most_max_object_px_across(given: str) -> None:
    # A 1080p clip's ball, 72 px across: the crop is scaled so that the object spans
    # max_object_px, not as max_width's 200 px wide crop would; the camera follows the scale.
    camera = PinholeCamera.from_fov(1920, 1080, 45.0)
    image, background = torch.full((3, 1080, 1920), 0.3), torch.full((3, 1080, 1920), 0.3)
    blob = np.zeros((1080, 1920), np.uint8)
    cv2.line(blob, (900, 500), (940, 520), 1, 72)
    mask = torch.from_numpy(blob > 0)
    image[:, mask] = 0.8
    box = mask_box(blob > 0)
    assert box is not None
    # A joint window's blob may be its whole box: the width is the object's all the same.
    near = {"blob": mask, "whole box": box_mask(box, (1080, 1920)), "none": None}[given]
    bounded = make_crop(image, background, box, camera, CropConfig(), near)
    across, bound = streak_width(bounded.object_mask.numpy() > 0), CropConfig().max_object_px
    assert bound - 3 <= across <= bound + 2, across
    free = make_crop(image, background, box, camera, CropConfig(max_object_px=0), near)
    assert free.image.shape[2] == CropConfig().max_width > bounded.image.shape[2]
    # Both cameras see the object where it is: the box's centre projects to the crop's centre.
    for crop in (bounded, free):
        scale = crop.image.shape[2] / crop.box[2]
        assert crop.camera.fx == pytest.approx(camera.fx * scale, rel=0.01)


def test_an_object_under_the_bound_keeps_its_crop() -> None:
    camera = PinholeCamera.from_fov(320, 240, 45.0)
    image = torch.full((3, 240, 320), 0.5)
    image[:, 100:120, 150:190] = 0.9  # 40 x 20 px: 20 across, under the bound
    mask = image[0] > 0.6
    box = (150, 100, 40, 20)
    bounded = make_crop(image, torch.full_like(image, 0.5), box, camera, CropConfig(), mask)
    free = make_crop(image, torch.full_like(image, 0.5), box, camera, CropConfig(max_object_px=0), mask)
    assert torch.equal(bounded.image, free.image) and bounded.box == free.box
