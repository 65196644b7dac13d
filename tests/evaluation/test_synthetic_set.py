from pathlib import Path

import numpy as np
import pytest

from sfb_video.checks import SfbError
from sfb_video.evaluation.synthetic_set import SET_FILE, benchmark_specs, ensure_set, list_synthetic
from sfb_video.synth import ClipSpec


def _small_set(seed: int = 1) -> dict[str, ClipSpec]:
    small = {"width": 64, "height": 48, "num_frames": 2, "size_px_range": (12.0, 14.0), "texture_size": 16}
    return {
        "ball": ClipSpec(shape="ball", speed_range=(1.0, 1.2), seed=seed, **small),
        "pen": ClipSpec(shape="pen", speed_range=(1.0, 1.2), seed=seed + 1, **small),
    }


def test_the_benchmark_set_has_every_shape_and_fixed_seeds() -> None:
    specs = benchmark_specs()
    assert sorted(s.shape for s in specs.values()) == ["ball", "box", "key", "pen", "ring"]
    assert len({s.seed for s in specs.values()}) == len(specs)
    assert specs == benchmark_specs()


def test_a_generated_set_reads_back_as_sequences_with_the_truth(tmp_path: Path) -> None:
    ensure_set(tmp_path / "set", _small_set(), quiet=True)
    sequences = list_synthetic(tmp_path / "set")
    assert [s.name for s in sequences] == ["ball", "pen"]
    ball = sequences[0]
    frames = list(ball.frames())
    assert [f.index for f in frames] == [0, 1]
    truth = ball.clip.truth[1]
    assert frames[1].box == truth.bbox
    np.testing.assert_allclose(frames[1].centres, truth.centres)
    np.testing.assert_allclose(frames[1].image, ball.clip.frames[1] / 255)
    assert frames[1].subframes.shape == (8, 48, 64, 3)
    # The object is inside its tight box in every sub-frame.
    x, y, w, h = frames[1].box
    assert truth.masks[:, y : y + h, x : x + w].sum() == pytest.approx(truth.masks.sum())


def test_an_existing_set_is_reused_and_a_different_one_refused(tmp_path: Path) -> None:
    root = tmp_path / "set"
    ensure_set(root, _small_set(), quiet=True)
    stamp = (root / "ball" / "gt.json").stat().st_mtime_ns
    ensure_set(root, _small_set(), quiet=True)
    assert (root / "ball" / "gt.json").stat().st_mtime_ns == stamp
    with pytest.raises(SfbError, match="different synthetic set"):
        ensure_set(root, _small_set(seed=7), quiet=True)


def test_a_folder_of_other_things_is_not_written_into(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(SfbError, match="not empty"):
        ensure_set(tmp_path, _small_set(), quiet=True)
    with pytest.raises(SfbError, match=SET_FILE):
        list_synthetic(tmp_path)
