"""The mask stage: which masks a run uses and why, and each frame's masks in the track's order."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from sfb_video import defmo
from sfb_video.config import CropConfig, load_config
from sfb_video.crop import Box, Crop
from sfb_video.demo import demo_clip, demo_config
from sfb_video.errors import SfbError
from sfb_video.evaluation.synthetic import crop_masks
from sfb_video.results import FrameResult
from sfb_video.stages.fit import fit_detection
from sfb_video.stages.masks import MaskSource, choose_masks, mask_centroids, orient_masks
from sfb_video.stages.tracking.prediction import join
from sfb_video.stages.types import Detection, FrameWithBackground
from sfb_video.synth import SyntheticClip

CPU = torch.device("cpu")
CROP = CropConfig()


def test_auto_without_weights_falls_back_to_the_difference_image_saying_why_in_one_line() -> None:
    lines: list[str] = []
    source = choose_masks("auto", None, CROP, CPU, log=lines.append)
    assert source.name == "diff" and source.make is None
    assert len(lines) == 1 and "\n" not in lines[0]
    assert "difference image" in lines[0] and str(defmo.cache_dir()) in lines[0] and "--defmo-weights" in lines[0]


def test_auto_uses_defmo_with_weights_given_or_in_the_hub_cache(
    defmo_weights: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    lines: list[str] = []
    given = choose_masks("auto", defmo_weights, CROP, CPU, log=lines.append)
    assert given.name == "defmo" and given.make is not None
    assert lines == [f"masks: DeFMO's sub-frame masks (L_S): weights from {defmo_weights}"]
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    defmo.cache_dir().mkdir(parents=True)
    for name in defmo.WEIGHT_FILES.values():
        (defmo.cache_dir() / name).symlink_to(defmo_weights / name)
    assert choose_masks("auto", None, CROP, CPU, log=None).name == "defmo"


def test_diff_never_loads_defmo_and_bad_weight_folders_are_errors(defmo_weights: Path, tmp_path: Path) -> None:
    lines: list[str] = []
    assert choose_masks("diff", defmo_weights, CROP, CPU, log=lines.append).make is None
    assert lines == ["masks: the difference image (L_D): asked for with --masks diff"]
    with pytest.raises(SfbError, match=r"no encoder_best\.pt and rendering_best\.pt"):
        choose_masks("auto", tmp_path, CROP, CPU, log=None)
    with pytest.raises(SfbError, match="--masks must be one of"):
        choose_masks("truth", None, CROP, CPU, log=None)


def test_auto_falls_back_from_cached_weights_that_do_not_load(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("TORCH_HOME", str(tmp_path))
    defmo.cache_dir().mkdir(parents=True)
    for name in defmo.WEIGHT_FILES.values():
        (defmo.cache_dir() / name).write_bytes(b"cut short by a failed download")
    lines: list[str] = []
    assert choose_masks("auto", None, CROP, CPU, log=lines.append).name == "diff"
    assert len(lines) == 1 and "cannot load the DeFMO weights" in lines[0] and "delete them" in lines[0]
    with pytest.raises(SfbError, match="cannot load the DeFMO weights"):
        choose_masks("defmo", None, CROP, CPU, log=None)


@pytest.mark.filterwarnings("ignore:Transient failure")
def test_defmo_without_weights_downloads_and_fails_clearly_when_it_cannot(monkeypatch: pytest.MonkeyPatch) -> None:
    for part, name in defmo.WEIGHT_FILES.items():
        monkeypatch.setitem(defmo.urls, f"defmo_{part}", f"http://127.0.0.1:9/{name}")
    with pytest.raises(SfbError, match="cannot download the DeFMO weights"):
        choose_masks("defmo", None, CROP, CPU, log=None)


def _moving_masks(n: int = 4) -> torch.Tensor:
    masks = torch.zeros(n, 20, 40)
    for k in range(n):
        masks[k, 8:12, 5 + 8 * k : 9 + 8 * k] = 1
    return masks


def test_masks_are_put_in_the_order_that_starts_where_the_track_predicts() -> None:
    masks = _moving_masks()
    assert torch.allclose(mask_centroids(masks)[:, 0], torch.tensor([6.5, 14.5, 22.5, 30.5]))
    kept, flipped = orient_masks(masks, torch.tensor([2.0, 10.0]))
    assert not flipped and kept is masks
    turned, flipped = orient_masks(masks, torch.tensor([35.0, 10.0]))
    assert flipped and torch.equal(turned, masks.flip(0))


def test_fits_with_defmo_masks_use_the_silhouette_loss(defmo_weights: Path) -> None:
    config = load_config("fast", ["fit.iterations=10"])
    config = demo_config(config)
    clip = demo_clip(config)
    source = choose_masks("defmo", defmo_weights, CROP, CPU, log=None)
    result = fit_detection(_frame(clip, 0), _detection(clip, 0), clip.camera, config, None, CPU, source)
    assert result.mask_source == "defmo" and result.masks is not None
    assert result.masks.shape == (config.render.time_steps, *result_crop_size(result))
    assert "silhouette" in result.losses and "difference" not in result.losses
    assert all(np.isfinite(v) for v in result.losses.values())
    plain = fit_detection(_frame(clip, 0), _detection(clip, 0), clip.camera, config, None, CPU)
    assert plain.mask_source == "diff" and plain.masks is None and "difference" in plain.losses


def result_crop_size(result: FrameResult) -> tuple[int, int]:
    return result.crop_camera.height, result.crop_camera.width


def _frame(clip: SyntheticClip, index: int) -> FrameWithBackground:
    def tensor(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1).float() / 255

    return FrameWithBackground(index, tensor(clip.frames[index]), tensor(clip.scene.background))


def _detection(clip: SyntheticClip, index: int) -> Detection:
    x, y, w, h = clip.truth[index].bbox
    blob = torch.zeros(clip.spec.height, clip.spec.width, dtype=torch.bool)
    blob[y : y + h, x : x + w] = True
    return Detection(index, (x, y, w, h), blob)


def test_the_order_between_frames_wins_over_the_order_the_masks_come_in() -> None:
    # True sub-frame masks, handed over reversed in frames 0 and 2 as DeFMO may hand them: the
    # track must still run the true way, and each frame must know its masks were turned.
    config = demo_config(load_config("fast"))
    clip = demo_clip(config)
    turned = {0, 2}

    def true_masks(frame: FrameWithBackground, box: Box, crop: Crop, n: int) -> torch.Tensor:
        masks = crop_masks(clip, frame.index, crop)
        return masks.flip(0) if frame.index in turned else masks

    source = MaskSource("truth", "the generator's", true_masks)
    results: list[FrameResult] = []
    for index in range(4):
        previous = results[-1] if results else None
        result = fit_detection(_frame(clip, index), _detection(clip, index), clip.camera, config, previous, CPU, source)
        if previous is not None:
            # A warm fit already runs the way the track predicts, whatever order its masks came in.
            assert _runs_the_true_way(result, clip), f"frame {index} was fitted backwards"
            exposure = config.video.exposure_fraction
            results[-1], result = join(previous, result, clip.camera, exposure, may_flip_previous=index == 1)
        results.append(result)
    for index, result in enumerate(results):
        assert _runs_the_true_way(result, clip), f"frame {index} runs backwards"
        assert result.masks_reversed == (index in turned), f"frame {index}"
        assert result.mask_source == "truth" and "silhouette" in result.losses


def _runs_the_true_way(result: FrameResult, clip: SyntheticClip) -> bool:
    start, end = clip.camera.project(result.state.motion.at(torch.tensor([0.0, 1.0]))[1])[0].numpy()
    first, last = clip.truth[result.index].centres[[0, -1]]
    return bool(np.linalg.norm(start - first) < np.linalg.norm(start - last)) and bool(
        np.linalg.norm(end - last) < np.linalg.norm(end - first)
    )
