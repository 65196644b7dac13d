"""Copies of a run's recording whose layout opens on the frame and on the step timeline, for the
screenshots of ``benchmarks/replay_screenshot.py``: rerun draws its menus on a canvas that
scripted clicks did not reach, so the timeline is switched in the layout itself.

    python -m benchmarks.replay_timelines RUN OUT_DIR     # writes OUT_DIR/frame.rrd, step.rrd
    sfb-video replay OUT_DIR/frame.rrd --web

Each copy is the recording followed by a blueprint stream (the viewer reads concatenated streams,
rerun-sdk's RrdReader does not; the last blueprint wins: a separate ``.rbl`` served beside the
recording did not).
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import rerun.blueprint as rrb

from sfb_video.recording import APPLICATION_ID, layout
from sfb_video.run_folder import RECORDING

TIMELINES = ("frame", "step")


def _containers(part: rrb.Container) -> Iterator[rrb.Container]:
    """``part`` and every container inside it."""
    yield part
    for inner in part.contents:
        if isinstance(inner, rrb.Container):
            yield from _containers(inner)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("out", type=Path)
    args = parser.parse_args()
    if not (args.run / RECORDING).is_file():
        parser.error(f"no recording in {args.run}")
    points: dict[int, list[list[float]]] = defaultdict(list)
    subframes = 1
    with (args.run / "trajectory.csv").open() as rows:
        for row in csv.DictReader(rows):
            points[int(row["track"])].append([float(row[c]) for c in ("x", "y", "z")])
            subframes = max(subframes, int(row["subframe"]) + 1)
    tracks = sorted(points)
    recording = (args.run / RECORDING).read_bytes()
    args.out.mkdir(parents=True, exist_ok=True)
    for timeline in TIMELINES:
        blueprint = layout(tracks, [np.array(points[t]) for t in tracks], subframes)
        blueprint.time_panel = rrb.TimePanel(timeline=timeline, state="expanded")
        if timeline == "step":
            # Only the fits' curves are on the step timeline: open their tab (after the tracks').
            (tabs,) = [c for c in _containers(blueprint.root_container) if c.kind == rrb.components.ContainerKind.Tabs]
            tabs.active_tab = len(tracks)
        with tempfile.TemporaryDirectory() as scratch:
            saved = Path(scratch) / "layout.rbl"
            blueprint.save(APPLICATION_ID, saved)
            copy = args.out / f"{timeline}.rrd"
            copy.write_bytes(recording + saved.read_bytes())
        print(copy)


if __name__ == "__main__":
    main()
