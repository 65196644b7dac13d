from pathlib import Path

import numpy as np
import pytest

from sfb_video.errors import SfbError
from sfb_video.evaluation.synthetic_set import (
    SET_FILE,
    SHAPE_CLASSES,
    benchmark_specs,
    ensure_set,
    hard_specs,
    list_synthetic,
    shape_class,
    shape_specs,
)
from sfb_video.synth import ClipSpec, make_scene


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


def test_the_hard_set_covers_shutters_lengths_arcs_a_bounce_faint_fence_and_contrast() -> None:
    specs = hard_specs()
    assert {round(s.exposure_fraction, 1) for s in specs.values()} >= {0.3, 1.0}
    assert all(8 <= s.num_frames <= 12 for s in specs.values())
    assert any(s.gravity > 0 for s in specs.values()) and any(s.bounce_time for s in specs.values())
    assert any(s.contrast < 0.5 for s in specs.values()) and any(s.fence_period_px for s in specs.values())
    assert any(s.split_background for s in specs.values())
    for name, spec in specs.items():
        # Every clip can be drawn: its object stays in view for all its frames.
        assert make_scene(spec).trajectory is not None, name


def test_a_shaken_set_is_registered_back_onto_the_still_clip(tmp_path: Path) -> None:
    # 160x120 frames shaken by up to 6 px and 1 degree: registered, each is the still frame
    # again but for interpolation, and far from the shaken one.
    spec = ClipSpec(shape="ball", width=160, height=120, num_frames=4, size_px_range=(14.0, 16.0), seed=3)
    ensure_set(tmp_path / "set", {"ball": spec}, quiet=True)
    (still,) = list_synthetic(tmp_path / "set")
    (shaken,) = list_synthetic(tmp_path / "set", shaken=True)
    from sfb_video.synth.shake import from_first, shake_frames, shake_transforms

    moves = from_first(shake_transforms(4, (160, 120), 3, max_shift_px=6.0, max_turn_deg=1.0))
    moved = shake_frames(still.clip.frames, moves).astype(np.float64) / 255
    for a, b, k in zip(still.frames(), shaken.frames(), range(4), strict=True):
        assert a.index == b.index and a.box == b.box
        inner = (slice(8, -8), slice(8, -8))
        error = np.abs(a.image - b.image)[inner].mean()
        assert error < 0.02  # measured 0.009-0.011 (the shaken frames: 0.04-0.08): interpolation
        if k > 0:
            assert np.abs(moved[k] - b.image)[inner].mean() > 3 * error


def test_the_shape_set_holds_eight_of_every_class_over_the_textures_sizes_and_shutters_asked_for() -> None:
    specs = shape_specs()
    assert len(specs) == 40 and len({s.seed for s in specs.values()}) == 40
    for name, shapes in SHAPE_CLASSES.items():
        members = [s for n, s in specs.items() if shape_class(n) == name]
        assert len(members) == 8 and {s.shape for s in members} == set(shapes)
    styles = {s.texture_style for s in specs.values()}
    assert {"plain", "stripes", "seam", "spokes"} <= styles
    assert any(s.contrast < 0.5 for s in specs.values()) and any(s.fence_period_px for s in specs.values())
    assert (
        min(s.size_px_range[0] for s in specs.values()) == 15 and max(s.size_px_range[1] for s in specs.values()) == 80
    )
    shutters = [s.exposure_fraction for s in specs.values()]
    assert min(shutters) == 0.3 and max(shutters) == 1.0
    assert all(6 <= s.num_frames <= 10 for s in specs.values())
