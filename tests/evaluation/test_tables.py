import csv
import math
from pathlib import Path

import pytest

from sfb_video.evaluation.runner import FrameRow
from sfb_video.evaluation.tables import markdown, summarise, write_tables


def _row(sequence: str, frame: int, tiou: float, seconds: float, mode: str = "per-frame", **extra: float) -> FrameRow:
    return FrameRow("tbd", sequence, frame, mode, "cold", tiou, 20.0 + tiou, 0.5, seconds, **extra)


def test_totals_average_sequences_not_frames_but_time_over_frames() -> None:
    rows = [_row("long", i, 1.0, 1.0) for i in range(3)] + [_row("short", 0, 0.0, 5.0)]
    records = summarise(rows)
    total = next(r for r in records if r["sequence"] == "total")
    assert total["frames"] == 4
    assert total["tiou"] == pytest.approx(0.5)  # (1.0 + 0.0) / 2, not 3 / 4
    assert total["seconds"] == pytest.approx(2.0)  # (1 + 1 + 1 + 5) / 4


def test_modes_get_their_own_rows_and_totals() -> None:
    rows = [_row("a", 0, 0.8, 1.0), _row("a", 0, 0.6, 0.5, mode="video")]
    records = summarise(rows)
    assert [(r["sequence"], r["mode"]) for r in records] == [
        ("a", "per-frame"),
        ("total", "per-frame"),
        ("a", "video"),
        ("total", "video"),
    ]
    assert records[3]["tiou"] == pytest.approx(0.6)


def test_unknown_3d_errors_are_left_out_of_the_table_and_known_ones_shown() -> None:
    benchmark = markdown(summarise([_row("a", 0, 0.8, 1.0)]))
    assert "TIoU" in benchmark and "transl. err" not in benchmark
    synthetic = markdown(summarise([_row("a", 0, 0.8, 1.0, translation_err=0.25, rotation_err_deg=10.0, mesh_err=0.1)]))
    assert "| 0.25 |" in synthetic and "mesh err" in synthetic


def test_written_tables_round_trip_and_carry_the_note(tmp_path: Path) -> None:
    rows = [_row("a", 0, 0.8, 1.0), _row("b", 1, 0.4, 3.0)]
    write_tables(tmp_path, rows, "Incomplete: 1 of 2 sequence runs finished.\n\n")
    with (tmp_path / "frames.csv").open() as f:
        frames = list(csv.DictReader(f))
    assert [(r["sequence"], float(r["tiou"])) for r in frames] == [("a", 0.8), ("b", 0.4)]
    assert math.isnan(float(frames[0]["mesh_err"]))
    with (tmp_path / "sequences.csv").open() as f:
        assert [r["sequence"] for r in csv.DictReader(f)] == ["a", "b", "total"]
    assert (tmp_path / "table.md").read_text().startswith("Incomplete: 1 of 2")


def test_the_baselines_come_first_as_modes_of_their_own() -> None:
    rows = [_row("a", 0, 0.8, 1.0), _row("a", 0, math.nan, 0.0, mode="Im"), _row("a", 0, math.nan, 0.0, mode="Bg")]
    assert [(r["sequence"], r["mode"]) for r in summarise(rows)] == [
        ("a", "Im"),
        ("total", "Im"),
        ("a", "Bg"),
        ("total", "Bg"),
        ("a", "per-frame"),
        ("total", "per-frame"),
    ]
