"""Tables of evaluation scores: every frame, the mean per sequence, and the total per mode.

The benchmark's 'Im' and 'Bg' baselines (the blurred frame, the background as every sub-frame)
are rows of every table, per sequence, so that each sequence's score reads against them.
Totals follow the benchmark: a dataset's TIoU, PSNR and SSIM are the mean over its sequences of
each sequence's mean over frames (so a long sequence does not outweigh a short one), and its
time is the mean over all frames. 3D errors, known only on synthetic data, are averaged the same
way; a column whose values are all unknown is left out.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from pathlib import Path

import numpy as np

from sfb_video.atomic import atomic_write_bytes
from sfb_video.evaluation.runner import BASELINES, MODES, FrameRow

MEASURES = {
    "tiou": ("TIoU", "{:.3f}"),
    "psnr": ("PSNR", "{:.2f}"),
    "ssim": ("SSIM", "{:.3f}"),
    "translation_err": ("transl. err", "{:.2f}"),
    "rotation_err_deg": ("rot. err (deg)", "{:.1f}"),
    "mesh_err": ("mesh err", "{:.3f}"),
    "windowed": ("by a window", "{:.2f}"),
    "seconds": ("s / frame", "{:.1f}"),
}
"""Column key -> (Markdown header, format)."""


def _mean(values: list[float]) -> float:
    finite = [v for v in values if not math.isnan(v)]
    return float(np.mean(finite)) if finite else math.nan


def summarise(rows: list[FrameRow]) -> list[dict]:
    """One record per (sequence, mode) with its frame count and mean measures, then a total per
    mode; the benchmark's baselines come first, as modes of their own."""
    records = []
    for mode in (*BASELINES, *MODES):
        sequences = list(dict.fromkeys(r.sequence for r in rows if r.mode == mode))
        per_sequence = []
        for name in sequences:
            frames = [r for r in rows if r.mode == mode and r.sequence == name]
            record = {"dataset": frames[0].dataset, "sequence": name, "mode": mode, "frames": len(frames)}
            # The shape the sequence ended with (its last fitted frame's), so the choice shows.
            record["prototype"] = next((r.prototype for r in reversed(frames) if r.prototype), "-")
            record |= {key: _mean([getattr(r, key) for r in frames]) for key in MEASURES}
            per_sequence.append(record)
        if not per_sequence:
            continue
        total = {"dataset": per_sequence[0]["dataset"], "sequence": "total", "mode": mode, "prototype": ""}
        total["frames"] = sum(r["frames"] for r in per_sequence)
        total |= {key: _mean([r[key] for r in per_sequence]) for key in MEASURES}
        total["seconds"] = _mean([r.seconds for r in rows if r.mode == mode])
        records += [*per_sequence, total]
    return records


def markdown(records: list[dict]) -> str:
    """A Markdown table of :func:`summarise`'s records, one row each."""
    keys = [k for k in MEASURES if any(not math.isnan(r[k]) for r in records)]
    lines = [
        "| sequence | mode | prototype | frames | " + " | ".join(MEASURES[k][0] for k in keys) + " |",
        "|---|---|---|---:|" + "---:|" * len(keys),
    ]
    for r in records:
        name = f"**{r['sequence']}**" if r["sequence"] == "total" else r["sequence"]
        cells = ["-" if math.isnan(r[k]) else MEASURES[k][1].format(r[k]) for k in keys]
        lines.append(f"| {name} | {r['mode']} | {r['prototype']} | {r['frames']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _csv(records: list[dict]) -> bytes:
    out = io.StringIO()
    writer = csv.DictWriter(out, fieldnames=list(records[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(records)
    return out.getvalue().encode()


TABLE = "table.md"
"""The Markdown table of an evaluation's output folder (beside sequences.csv and frames.csv)."""


def write_tables(folder: Path, rows: list[FrameRow], note: str = "") -> None:
    """Write frames.csv (every frame), sequences.csv and table.md (per sequence and total), atomically.

    Args:
        note: Markdown put above the table (e.g. that the evaluation is still incomplete).
    """
    if not rows:
        return
    records = summarise(rows)
    atomic_write_bytes(folder / "frames.csv", _csv([dataclasses.asdict(r) for r in rows]))
    atomic_write_bytes(folder / "sequences.csv", _csv(records))
    atomic_write_bytes(folder / TABLE, (note + markdown(records)).encode())
