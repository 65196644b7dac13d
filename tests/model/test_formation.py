import pytest
import torch

from sfb_video.model.formation import composite, exposure_times, subframes


def test_composite_is_background_where_nothing_covers_and_object_where_always_covered() -> None:
    rgb = torch.rand(4, 3, 5, 6)
    alpha = torch.zeros(4, 1, 5, 6)
    alpha[:, :, 2, 3] = 1.0
    background = torch.rand(3, 5, 6)
    out = composite(rgb, alpha, background)
    assert torch.allclose(out[:, 0, 0], background[:, 0, 0])
    assert torch.allclose(out[:, 2, 3], rgb[:, :, 2, 3].mean(0))


def test_subframes_average_to_the_blurred_image() -> None:
    rgb, alpha, background = torch.rand(8, 3, 4, 4), torch.rand(8, 1, 4, 4), torch.rand(3, 4, 4)
    subs = subframes(rgb, alpha, background, 4)
    assert subs.shape == (4, 3, 4, 4)
    assert torch.allclose(subs.mean(0), composite(rgb, alpha, background), atol=1e-6)
    assert torch.allclose(subframes(rgb, alpha, background, 8)[2], composite(rgb[2:3], alpha[2:3], background))
    with pytest.raises(ValueError, match="cannot be split"):
        subframes(rgb, alpha, background, 3)


def test_exposure_times_are_slice_midpoints() -> None:
    assert torch.allclose(exposure_times(4), torch.tensor([0.125, 0.375, 0.625, 0.875]))
