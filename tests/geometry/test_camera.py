import math

import pytest
import torch

from sfb_video.geometry.camera import PinholeCamera


def test_from_fov_puts_the_fov_edge_on_the_image_edge() -> None:
    cam = PinholeCamera.from_fov(320, 240, 45.0)
    # A point at the top edge of the field of view projects onto the top edge of the image.
    z = 3.0
    top = torch.tensor([0.0, -z * math.tan(math.radians(22.5)), z])
    uv, depth = cam.project(top)
    assert uv[1].item() == pytest.approx(-0.5, abs=1e-4)
    assert uv[0].item() == pytest.approx(159.5)
    assert depth.item() == z


def test_crop_of_whole_image_is_identity() -> None:
    cam = PinholeCamera.from_fov(64, 48, 50.0)
    assert cam.crop(0, 0, 64, 48, 64, 48) == cam


def test_crop_maps_pixel_edges_onto_the_crop() -> None:
    cam = PinholeCamera.from_fov(320, 240, 45.0)
    crop = cam.crop(100, 50, 80, 60, 160, 120)
    points = torch.randn(20, 3) * 0.3 + torch.tensor([0.0, 0.0, 4.0])
    uv_full, _ = cam.project(points)
    uv_crop, _ = crop.project(points)
    # Full-frame pixel edge 100 - 0.5 is crop edge -0.5; the crop is scaled 2x.
    expected = (uv_full - torch.tensor([100 - 0.5, 50 - 0.5])) * 2 - 0.5
    assert torch.allclose(uv_crop, expected, atol=1e-4)


def test_unproject_inverts_project() -> None:
    cam = PinholeCamera.from_fov(100, 80, 60.0)
    points = torch.randn(10, 3) + torch.tensor([0.0, 0.0, 5.0])
    uv, depth = cam.project(points)
    assert torch.allclose(cam.unproject(uv, depth), points, atol=1e-5)
