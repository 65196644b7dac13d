"""DeFMO's masks of a crop: weight files, input and output sizes, time bins (no download)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import torch
from kornia.feature import DeFMO
from torch import nn

from sfb_video import defmo
from sfb_video.config import CropConfig
from sfb_video.crop import Crop, make_crop
from sfb_video.errors import SfbError
from sfb_video.geometry.camera import PinholeCamera


@pytest.fixture(scope="module")
def network(defmo_weights: Path) -> DeFMO:
    return defmo.load_defmo(defmo_weights, torch.device("cpu"))


def _frame(height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    # A smooth pattern: it survives resizing to 320x240 and back nearly unchanged.
    ys, xs = torch.meshgrid(torch.linspace(0, 1, height), torch.linspace(0, 1, width), indexing="ij")
    image = torch.stack((xs, ys, (xs + ys) / 2))
    return image, image * 0.5


def _crop(image: torch.Tensor, background: torch.Tensor, box: tuple[int, int, int, int]) -> Crop:
    camera = PinholeCamera.from_fov(image.shape[2], image.shape[1], 45.0)
    return make_crop(image, background, box, camera, CropConfig())


class Echo(nn.Module):
    """Stands in for DeFMO: its alpha is the image's red channel in the first half of the
    exposure and the green one in the second, so where and when each mask comes from shows."""

    def __init__(self) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.zeros(1))
        self.inputs: list[torch.Tensor] = []

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        self.inputs.append(x)
        b, _, h, w = x.shape
        out = torch.zeros(b, 24, 4, h, w)
        out[:, :12, 3] = x[:, None, 0]
        out[:, 12:, 3] = x[:, None, 1]
        return out


def test_loaded_weights_are_the_saved_ones(defmo_weights: Path, network: DeFMO) -> None:
    assert not network.training
    for part, name in defmo.WEIGHT_FILES.items():
        saved = torch.load(defmo_weights / name, weights_only=True)
        loaded = getattr(network, part).state_dict()
        assert saved.keys() == loaded.keys()
        assert all(torch.equal(saved[k], loaded[k]) for k in saved)


@pytest.mark.parametrize(
    ("size", "box"),
    [((240, 320), (140, 100, 30, 20)), ((240, 320), (0, 0, 40, 12)), ((480, 640), (100, 200, 260, 60))],
)
def test_masks_have_the_crop_size_and_one_per_subframe(
    network: DeFMO, size: tuple[int, int], box: tuple[int, int, int, int]
) -> None:
    image, background = _frame(*size)
    crop = _crop(image, background, box)
    masks = defmo.defmo_masks(network, image, background, box, crop, 8, CropConfig())
    assert masks.shape == (8, *crop.image.shape[1:])
    assert masks.dtype == torch.float32 and not masks.requires_grad
    assert float(masks.min()) >= 0 and float(masks.max()) <= 1


@pytest.mark.parametrize("box", [(140, 100, 30, 20), (0, 0, 40, 12), (280, 200, 40, 40)])
def test_masks_are_defmo_alphas_from_a_wider_window_mapped_back_onto_the_crop(box: tuple[int, int, int, int]) -> None:
    echo = Echo()
    image, background = _frame(240, 320)
    crop = _crop(image, background, box)
    masks = defmo.defmo_masks(echo, image, background, box, crop, 4, CropConfig())
    (pair,) = echo.inputs
    assert pair.shape == (1, 6, 240, 320)
    assert torch.allclose(pair[0, 3:], pair[0, :3] * 0.5, atol=1e-6)  # the background, same window
    # DeFMO sees more around the object than the crop holds (as the SfB reference crops for it).
    seen, cropped = pair[0, 0], crop.image[0]
    assert float(seen.max() - seen.min()) > 1.1 * float(cropped.max() - cropped.min())
    # Instants 0..11 (times up to 11/23 < 1/2) fill sub-frames 0 and 1, the rest 2 and 3: each
    # mask lands on the crop's own pixels.
    for k in range(4):
        expected = crop.image[0] if k < 2 else crop.image[1]
        assert (masks[k] - expected).abs().max() < 0.02, k


def test_time_bins_average_every_instant_into_the_subframe_it_falls_in() -> None:
    bins = defmo.time_bins(24, 8)
    assert bins.shape == (8, 24)
    assert torch.allclose(bins.sum(1), torch.ones(8))
    assert torch.equal((bins > 0).sum(0), torch.ones(24, dtype=torch.long))  # each instant once
    assert torch.equal((bins > 0).sum(1), torch.full((8,), 3))
    # In time order: each sub-frame's instants come after the previous one's.
    firsts = [int(torch.nonzero(row)[0]) for row in bins]
    assert firsts == sorted(firsts)
    with pytest.raises(SfbError, match="cannot fill"):
        defmo.time_bins(24, 32)


def test_a_folder_missing_a_weight_file_or_holding_a_bad_one_is_a_clear_error(tmp_path: Path) -> None:
    assert not defmo.has_weights(tmp_path)
    (tmp_path / "encoder_best.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(SfbError, match=r"no DeFMO weights at .*rendering_best\.pt"):
        defmo.load_defmo(tmp_path, torch.device("cpu"))
    (tmp_path / "rendering_best.pt").write_bytes(b"not a checkpoint")
    assert defmo.has_weights(tmp_path)
    with pytest.raises(SfbError, match=r"cannot load the DeFMO weights .*encoder_best\.pt: not a PyTorch weight file"):
        defmo.load_defmo(tmp_path, torch.device("cpu"))
    torch.save({"conv.weight": torch.zeros(1)}, tmp_path / "encoder_best.pt")
    with pytest.raises(SfbError, match="do not fit DeFMO's encoder"):
        defmo.load_defmo(tmp_path, torch.device("cpu"))


@pytest.mark.filterwarnings("ignore:Transient failure")  # kornia retries, saying so
def test_a_download_that_cannot_connect_fails_fast_with_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    # Port 9 (discard) on localhost refuses the connection at once on any machine, online or not.
    for part in defmo.WEIGHT_FILES:
        monkeypatch.setitem(defmo.urls, f"defmo_{part}", f"http://127.0.0.1:9/{defmo.WEIGHT_FILES[part]}")
    start = time.perf_counter()
    with pytest.raises(SfbError, match="cannot download the DeFMO weights") as info:
        defmo.download_weights(timeout=5)
    assert time.perf_counter() - start < 30
    assert "\n" not in str(info.value)
    assert not defmo.has_weights(defmo.cache_dir())
