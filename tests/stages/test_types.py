"""The types the stages hand each other."""

from __future__ import annotations

import torch

from sfb_video.stages.types import FrameWithBackground


def test_a_frame_without_a_region_shows_its_background_there_and_is_itself_untouched() -> None:
    pixels = torch.full((3, 4, 5), 200, dtype=torch.uint8)
    region = torch.zeros(4, 5, dtype=torch.bool)
    region[1:3, 2:4] = True
    for background in (torch.full((3, 4, 5), 10, dtype=torch.uint8), torch.full((3, 4, 5), 0.25)):
        frame = FrameWithBackground(0, pixels.clone(), background)
        out = frame.without(region)
        image = out.image  # float in [0, 1] whatever the dtypes
        expected = background.float() / 255 if background.dtype == torch.uint8 else background
        assert torch.allclose(image[:, region], expected[:, region])
        assert torch.allclose(image[:, ~region], torch.full_like(image[:, ~region], 200 / 255))
        assert torch.equal(frame.pixels, pixels) and out.background_pixels is frame.background_pixels
