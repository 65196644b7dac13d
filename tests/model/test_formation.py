import torch

from sfb_video.model.formation import blend, exposure_times


def test_blend_is_background_where_nothing_covers_and_object_where_always_covered() -> None:
    rgb = torch.rand(4, 3, 5, 6)
    alpha = torch.zeros(4, 1, 5, 6)
    alpha[:, :, 2, 3] = 1.0
    background = torch.rand(3, 5, 6)
    out = blend(rgb, alpha, background)
    assert torch.allclose(out[:, 0, 0], background[:, 0, 0])
    assert torch.allclose(out[:, 2, 3], rgb[:, :, 2, 3].mean(0))


def test_exposure_times_are_slice_midpoints() -> None:
    assert torch.allclose(exposure_times(4), torch.tensor([0.125, 0.375, 0.625, 0.875]))
