from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from sfb_video.errors import SfbError
from sfb_video.imageio import read_image, to_uint8, write_image


def test_round_trip_is_exact_at_8_bit(tmp_path: Path) -> None:
    image = torch.randint(0, 256, (3, 7, 9)).float() / 255
    write_image(tmp_path / "a.png", image)
    assert torch.allclose(read_image(tmp_path / "a.png"), image, atol=1e-6)
    assert [p.name for p in tmp_path.iterdir()] == ["a.png"]  # no temporary left behind


def test_grayscale_and_16_bit_are_converted(tmp_path: Path) -> None:
    gray = np.full((4, 5), 128, np.uint8)
    cv2.imwrite(str(tmp_path / "g.png"), gray)
    deep = np.full((4, 5, 3), 65535, np.uint16)
    cv2.imwrite(str(tmp_path / "d.png"), deep)
    assert read_image(tmp_path / "g.png").shape == (3, 4, 5)
    assert torch.allclose(read_image(tmp_path / "g.png"), torch.tensor(128 / 255))
    assert torch.allclose(read_image(tmp_path / "d.png"), torch.tensor(1.0))


def test_missing_and_corrupt_images_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(SfbError, match="not found"):
        read_image(tmp_path / "none.png")
    (tmp_path / "bad.png").write_bytes(b"not a png")
    with pytest.raises(SfbError, match="not a readable image"):
        read_image(tmp_path / "bad.png")


def test_to_uint8_interleaves_the_planes_of_any_tensor_in_rgb_or_bgr() -> None:
    generator = torch.Generator().manual_seed(0)
    values = torch.rand(3, 9, 14, generator=generator)
    expected = (values * 255).round().to(torch.uint8).permute(1, 2, 0).numpy()
    for image in (values, (values * 255).round().to(torch.uint8), values[:, :, 2:]):
        want = expected[:, 2:] if image.shape[2] == 12 else expected
        assert np.array_equal(to_uint8(image), want)
        assert np.array_equal(to_uint8(image, bgr=True), want[..., ::-1])
    assert np.array_equal(to_uint8(values.permute(1, 2, 0).numpy(), bgr=True), expected[..., ::-1])
