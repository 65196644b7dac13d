"""The FMO benchmark loader against small datasets written in the benchmark's layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sfb_video.errors import SfbError
from sfb_video.evaluation import datasets
from sfb_video.evaluation.datasets import DATASETS, BenchmarkFrame, list_sequences, tight_box
from tests.evaluation.fmo_fixture import FixtureDataset, write_fixture, write_plain_sequence


@pytest.fixture(params=DATASETS)
def fixture_set(request: pytest.FixtureRequest, tmp_path: Path) -> FixtureDataset:
    return write_fixture(tmp_path / request.param, request.param)


def _frames(root: Path, dataset: str) -> dict[str, list[BenchmarkFrame]]:
    return {seq.name: list(seq.frames()) for seq in list_sequences(root, dataset)}


def _one_line(error: pytest.ExceptionInfo[SfbError]) -> None:
    assert "\n" not in str(error.value)


# --- listing ---------------------------------------------------------------------------------


def test_lists_the_benchmarks_sequences_in_its_order(fixture_set: FixtureDataset) -> None:
    seqs = list_sequences(fixture_set.root, fixture_set.dataset)
    assert [s.name for s in seqs] == [s.name for s in fixture_set.sequences]
    assert not {s.name for s in seqs} & set(fixture_set.excluded)
    for seq, want in zip(seqs, fixture_set.sequences, strict=True):
        assert seq.dataset == fixture_set.dataset
        assert seq.folder == fixture_set.root / "imgs" / want.name
        assert seq.num_subframes == want.num_subframes
        assert seq.num_frames == want.num_frames
        assert seq.first_file == want.first_file


def test_tbd_order_drops_vs_and_picks_roi_rows_by_that_order(tmp_path: Path) -> None:
    fx = write_fixture(tmp_path, "tbd")
    seqs = list_sequences(tmp_path, "tbd")
    # A plain sort would list VS_mug_throw first (and give it roi row 0).
    assert [s.name for s in seqs] == ["hit_tennis", "VS_mug_throw"]
    # hit_tennis has files 0..4, roi [1, 3]: files 1..3. VS_mug_throw has files 1..4, roi [0, 2]:
    # numbered from 1, so files 1..3 too.
    assert [(s.first_file, s.num_frames) for s in seqs] == [(1, 3), (1, 3)]
    assert [s.frame_path(0).name for s in seqs] == ["00000001.png", "00000001.png"]
    assert len(list((fx.root / "imgs" / "hit_tennis").glob("*.png"))) == 5


def test_without_roi_every_png_is_a_frame_and_numbering_may_start_at_1(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd3d")
    one, two = list_sequences(tmp_path, "tbd3d")
    assert (one.first_file, one.num_frames, one.gt_offset) == (0, 4, 0)
    assert (two.first_file, two.num_frames, two.gt_offset) == (1, 3, 1)
    # "-12" in the name, and 12 columns in gt.txt.
    assert two.num_subframes == 12
    assert two.subframe_path(0, 0).name == f"{1 * 12 + 0 + 1:08d}.png"


def test_subframe_count_follows_the_trajectorys_columns(tmp_path: Path) -> None:
    h, w, n = 8, 8, 3
    frames = np.full((2, h, w, 3), 100, np.uint8)
    subframes = np.full((2, n, h, w, 3), 100, np.uint8)
    write_plain_sequence(tmp_path, "a_GT_b", frames, subframes, np.full((2, n, 2), 4.0), 2)
    (seq,) = list_sequences(tmp_path, "tbd3d")
    assert seq.num_subframes == 3  # not the name's 8
    assert [f.subframes.shape for f in seq.frames()] == [(3, h, w, 3)] * 2


# --- frames ----------------------------------------------------------------------------------


def test_frames_are_what_was_written(fixture_set: FixtureDataset) -> None:
    got = _frames(fixture_set.root, fixture_set.dataset)
    for want in fixture_set.sequences:
        frames = got[want.name]
        assert [f.index for f in frames] == list(range(want.num_frames))
        assert {f.sequence for f in frames} == {want.name}
        for f in frames:
            # Exact: both sides are the stored samples over the dtype's full scale (8 or 16 bit,
            # alpha dropped).
            np.testing.assert_array_equal(f.image, want.images[f.index])
            np.testing.assert_array_equal(f.subframes, want.subframes[f.index])
            # No pixel shows the disc in two frames, so the median is the background.
            np.testing.assert_array_equal(f.background, want.background)
            assert f.image.dtype == np.float64 and f.image.shape == (48, 64, 3)
            assert f.subframes.shape == (want.num_subframes, 48, 64, 3)
            assert f.radius == want.radius and isinstance(f.radius, int)
            known = np.ones(want.num_subframes, bool)
            known[[j for k, j in want.nan_subframes if k == f.index]] = False
            np.testing.assert_allclose(f.centres[known], want.centres[f.index][known], atol=1e-9)
            assert f.centres.shape == (want.num_subframes, 2) and np.isfinite(f.centres).all()


def test_sixteen_bit_frames_use_the_full_range(tmp_path: Path) -> None:
    fx = write_fixture(tmp_path, "falling")
    frame = next(list_sequences(tmp_path, "falling")[0].frames())
    assert fx.sequences[0].bit_depth == 16 and not fx.sequences[0].alpha
    # A 3-channel 16-bit file: divided by 65535 (the benchmark's imread would divide by 255).
    assert 0.5 < frame.image.max() <= 1.0
    # Finer than 8 bits: the values are not all multiples of 1/255.
    assert not np.allclose(frame.image * 255, np.round(frame.image * 255))


def test_nan_centres_are_filled_as_the_benchmark_fills_them(tmp_path: Path) -> None:
    fx = write_fixture(tmp_path, "tbd3d")
    truth = fx.sequences[0].centres
    assert fx.sequences[0].nan_subframes == ((1, 0), (1, 1), (2, 4), (2, 5), (3, 7))
    frames = _frames(tmp_path, "tbd3d")["ball_GT_one"]
    np.testing.assert_allclose(frames[1].centres[0], truth[1, 2])  # sub-frame 0: the first finite one
    np.testing.assert_allclose(frames[1].centres[1], truth[1, 2])  # mean of the filled 0 and 2
    np.testing.assert_allclose(frames[2].centres[4], truth[2, 3])  # next is NaN: the previous one
    np.testing.assert_allclose(frames[2].centres[5], (truth[2, 3] + truth[2, 6]) / 2)  # neighbours' mean
    np.testing.assert_allclose(frames[3].centres[7], truth[3, 6])  # the last: the previous one
    np.testing.assert_allclose(frames[0].centres, truth[0])


def test_frame_without_any_finite_centre_is_an_error(tmp_path: Path) -> None:
    frames = np.full((1, 8, 8, 3), 100, np.uint8)
    write_plain_sequence(
        tmp_path, "a_GT_b", frames, np.full((1, 2, 8, 8, 3), 100, np.uint8), np.full((1, 2, 2), np.nan), 2
    )
    with pytest.raises(SfbError, match="no finite GT sub-frame centre") as e:
        list(list_sequences(tmp_path, "tbd3d")[0].frames())
    _one_line(e)


# --- radius ----------------------------------------------------------------------------------


def test_radius_sources(tmp_path: Path) -> None:
    for dataset, source in (("tbd", "template"), ("tbd3d", "gtr"), ("falling", "gt_bbox")):
        fx = write_fixture(tmp_path / dataset, dataset)
        assert {s.radius_source for s in fx.sequences} == {source}
        for seq, want in zip(list_sequences(fx.root, dataset), fx.sequences, strict=True):
            # gtr: the nan-max of the row; template: rows / 2 / scale = r + 0.25; gt_bbox: half the
            # longer side, in spite of the sequence's gtr.txt (r + 4) which the benchmark ignores.
            assert [seq.radius(k) for k in range(seq.num_frames)] == [want.radius] * seq.num_frames


def test_gtr_wins_over_a_template(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd")
    np.savetxt(tmp_path / "imgs" / "hit_tennis" / "gtr.txt", np.full((5, 8), 6.6))
    seq = list_sequences(tmp_path, "tbd")[0]
    assert seq.radius(0) == 7


def test_per_frame_radius_rows_are_indexed_by_file_number(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd3d")
    rows = np.arange(4)[:, None] + np.full((4, 12), 3.0)  # file f: radius 3 + f
    np.savetxt(tmp_path / "imgs" / "box_GT_two-12" / "gtr.txt", rows)
    seq = list_sequences(tmp_path, "tbd3d")[1]
    assert seq.first_file == 1
    assert [seq.radius(k) for k in range(3)] == [4, 5, 6]


# --- background ------------------------------------------------------------------------------


_VALUES = (40, 10, 30, 20, 60, 50, 0)


def _median_sequence(root: Path) -> None:
    """Seven frames of value v_k plus a fixed per-pixel pattern, so each window has a known median."""
    pattern = (np.arange(8)[None, :, None] * 3 + np.arange(8)[:, None, None] + np.arange(3)).astype(np.uint8)
    frames = np.stack([np.full((8, 8, 3), v, np.uint8) + pattern for v in _VALUES])
    subframes = np.repeat(frames[:, None], 2, axis=1)
    write_plain_sequence(root, "m_GT_a", frames, subframes, np.full((7, 2, 2), 4.0), 1)


@pytest.mark.parametrize(
    ("window", "medians"),
    [
        # Frames 0..m-1 for k < m, then the m frames before k (frame k itself left out).
        (3, (30, 30, 30, 30, 20, 30, 50)),
        (4, (25, 25, 25, 25, 25, 25, 40)),
        (50, (30,) * 7),  # fewer frames than the window: all of them, always
    ],
)
def test_running_median_window(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, window: int, medians: tuple[int, ...]
) -> None:
    _median_sequence(tmp_path)
    monkeypatch.setattr(datasets, "MEDIAN_FRAMES", window)
    (seq,) = list_sequences(tmp_path, "tbd3d")
    frames = list(seq.frames())
    raw = np.stack([f.image for f in frames])  # (7, 8, 8, 3)
    m = min(window, 7)
    for k, (f, want) in enumerate(zip(frames, medians, strict=True)):
        lo = 0 if k < m else k - m
        # The benchmark's arithmetic (np.median of frames already divided by 255), bit for bit.
        np.testing.assert_array_equal(f.background, np.median(raw[lo : lo + m], axis=0))
        np.testing.assert_allclose(f.background[0, 0, 0], want / 255)


def test_median_frames_is_the_benchmarks() -> None:
    assert datasets.MEDIAN_FRAMES == 50


def test_frames_are_streamed_and_an_unreadable_png_is_an_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _median_sequence(tmp_path)
    monkeypatch.setattr(datasets, "MEDIAN_FRAMES", 3)
    bad = tmp_path / "imgs" / "m_GT_a" / "00000005.png"
    bad.write_bytes(b"not a png at all")
    got = []
    with pytest.raises(SfbError, match="cannot read PNG") as e:
        for f in list_sequences(tmp_path, "tbd3d")[0].frames():
            got.append(f.index)
    _one_line(e)
    assert str(bad) in str(e.value)
    # Frame 5 is read only when it is due.
    assert got == [0, 1, 2, 3, 4]


# --- tight box -------------------------------------------------------------------------------


def _box_case() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 48x64 grey frame and two sub-frames; returns (frames (1,H,W,3), subframes (1,2,H,W,3), centres (1,2,2))."""
    bg = np.full((48, 64, 3), 128, np.uint8)
    sub = np.repeat(bg[None], 2, axis=0)
    sub[0, 10:14, 20:24] = 255  # the object at sub-frame 0
    sub[1, 12:16, 24:28] = 255  # ... and 1, touching it
    sub[1, 12:14, 28] = 128 + 11  # channel sum 3 * 11 / 255 = 0.13 > 0.1: part of the object
    sub[1, 12:14, 19] = 128 + 5  # 0.06: not
    sub[1, 16, 28] = 255  # touches (15, 27) only diagonally: joined under 8-connectivity
    sub[0, 2, 12] = 255  # a smaller region inside the searched box: not the largest
    sub[0, 30:41, 45:61] = 255  # a larger one outside it: never seen
    centres = np.array([[[21.5, 11.5], [25.5, 13.5]]])
    return bg[None], sub[None], centres


def test_tight_box_by_hand(tmp_path: Path) -> None:
    frames, subframes, centres = _box_case()
    write_plain_sequence(tmp_path, "box_GT_a", frames, subframes, centres, 2)
    (frame,) = list_sequences(tmp_path, "tbd3d")[0].frames()
    # Centres' box (top 11, left 21, bottom 13, right 25), + radius 2 -> (9, 19, 15, 27), + 10 ->
    # (0, 9, 25, 37) after clipping: rows 0..24, columns 9..36 are searched. The object spans rows
    # 10..16 and columns 20..28.
    assert frame.box == (20, 10, 9, 7)


def test_tight_box_without_a_region_is_the_extended_box() -> None:
    frames, _, centres = _box_case()
    background = frames[0] / 255.0
    subframes = np.repeat(background[None], 2, axis=0)
    assert tight_box(centres[0], 2, subframes, background) == (9, 0, 28, 25)


def test_tight_box_never_searches_the_last_row_or_column() -> None:
    background = np.full((48, 64, 3), 0.5)
    subframes = np.repeat(background[None], 2, axis=0)
    subframes[:, 40:47, 56:63] = 1.0
    subframes[:, 47, 44:] = 1.0  # the last row ...
    subframes[:, 28:, 63] = 1.0  # ... and column, touching the object
    centres = np.array([[57.0, 41.0], [61.0, 45.0]])
    # (41, 57, 45, 61) + 3 -> (38, 54, 47, 63) clipped at H-1, W-1; + 10 -> (28, 44, 47, 63); the
    # benchmark crops [28:47, 44:63], which leaves row 47 and column 63 out.
    assert tight_box(centres, 3, subframes, background) == (56, 40, 7, 7)


def test_tight_box_of_the_fixture_bounds_the_object(fixture_set: FixtureDataset) -> None:
    got = _frames(fixture_set.root, fixture_set.dataset)
    for want in fixture_set.sequences:
        for f in got[want.name]:
            changed = (np.abs(want.subframes[f.index] - want.background).sum(-1) > 0.1).any(0)
            rows, cols = np.nonzero(changed)
            box = (cols.min(), rows.min(), cols.max() + 1 - cols.min(), rows.max() + 1 - rows.min())
            assert f.box == tuple(int(v) for v in box)


# --- errors ----------------------------------------------------------------------------------


def test_missing_root(tmp_path: Path) -> None:
    with pytest.raises(SfbError, match="does not exist") as e:
        list_sequences(tmp_path / "nowhere", "tbd")
    _one_line(e)
    assert str(tmp_path / "nowhere") in str(e.value)


def test_unknown_dataset(tmp_path: Path) -> None:
    with pytest.raises(SfbError, match="unknown FMO benchmark dataset 'tbd-3d'") as e:
        list_sequences(tmp_path, "tbd-3d")
    _one_line(e)


def test_root_without_sequences(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd3d")  # imgs/ holds folders, none of them *_GTgamma
    with pytest.raises(SfbError, match="no falling sequences") as e:
        list_sequences(tmp_path, "falling")
    _one_line(e)
    (tmp_path / "empty").mkdir()
    with pytest.raises(SfbError, match="no tbd sequences"):
        list_sequences(tmp_path / "empty", "tbd")


def test_sequence_without_trajectory(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd3d")
    (tmp_path / "imgs" / "ball_GT_one" / "gt.txt").unlink()
    with pytest.raises(SfbError, match="has no GT trajectory") as e:
        list_sequences(tmp_path, "tbd3d")
    _one_line(e)
    assert "ball_GT_one" in str(e.value)


def test_sequence_without_radius(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd")
    (tmp_path / "templates" / "VS_mug_throw_template.mat").unlink()
    with pytest.raises(SfbError, match="has no GT radius") as e:
        list_sequences(tmp_path, "tbd")
    _one_line(e)


def test_sequence_without_gt_subframes(tmp_path: Path) -> None:
    write_fixture(tmp_path, "falling")
    for p in (tmp_path / "imgs_gt" / "pen-12_GTgamma").iterdir():
        p.unlink()
    (tmp_path / "imgs_gt" / "pen-12_GTgamma").rmdir()
    with pytest.raises(SfbError, match="has no GT sub-frames") as e:
        list_sequences(tmp_path, "falling")
    _one_line(e)


def test_missing_gt_subframe(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd3d")
    gone = tmp_path / "imgs_gt" / "box_GT_two-12" / f"{2 * 12 + 3 + 1:08d}.png"  # frame 1, sub-frame 3
    gone.unlink()
    seq = list_sequences(tmp_path, "tbd3d")[1]
    frames = seq.frames()
    next(frames)
    with pytest.raises(SfbError, match="missing PNG") as e:
        next(frames)
    _one_line(e)
    assert str(gone) in str(e.value)


def test_short_roi_table(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd")
    np.savetxt(tmp_path / "roi_frames.txt", np.array([[1, 3]]), fmt="%d")
    with pytest.raises(SfbError, match=r"roi_frames\.txt has 1 rows") as e:
        list_sequences(tmp_path, "tbd")
    _one_line(e)


def test_short_trajectory(tmp_path: Path) -> None:
    write_fixture(tmp_path, "tbd3d")
    gt = tmp_path / "imgs" / "ball_GT_one" / "gt.txt"
    np.savetxt(gt, np.loadtxt(gt)[:6])
    with pytest.raises(SfbError, match="covers 3 frames, it needs 4") as e:
        list_sequences(tmp_path, "tbd3d")
    _one_line(e)
