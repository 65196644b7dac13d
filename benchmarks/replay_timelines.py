"""Copies of a run's recording whose layout opens on the frame and on the step timeline, for the
screenshots of ``benchmarks/replay_screenshot.py``: rerun draws its menus on a canvas that
scripted clicks did not reach, so the timeline is switched in the layout itself.

    python -m benchmarks.replay_timelines RUN OUT_DIR     # writes OUT_DIR/frame.rrd, step.rrd
    sfb-video replay OUT_DIR/frame.rrd --web

Each copy is the recording followed by a blueprint stream (rerun reads concatenated streams;
the last blueprint wins: one served beside the recording as a separate ``.rbl`` did not).
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np
import rerun.blueprint as rrb

from sfb_video.recording import APPLICATION_ID, layout
from sfb_video.run_folder import RECORDING

TIMELINES = ("frame", "step")


def _tabs(part: rrb.Container) -> rrb.Container:
    """The layout's one tab container."""
    if part.kind == rrb.components.ContainerKind.Tabs:
        return part
    (found,) = [_tabs(c) for c in part.contents if isinstance(c, rrb.Container) and _has_tabs(c)]
    return found


def _has_tabs(part: rrb.Container) -> bool:
    return part.kind == rrb.components.ContainerKind.Tabs or any(
        _has_tabs(c) for c in part.contents if isinstance(c, rrb.Container)
    )


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
    args.out.mkdir(parents=True, exist_ok=True)
    for timeline in TIMELINES:
        blueprint = layout(tracks, [np.array(points[t]) for t in tracks], subframes)
        blueprint.time_panel = rrb.TimePanel(timeline=timeline, state="expanded")
        if timeline == "step":
            # Only the fits' curves are on the step timeline: open their tab (after the tracks').
            _tabs(blueprint.root_container).active_tab = len(tracks)
        with tempfile.TemporaryDirectory() as scratch:
            saved = Path(scratch) / "layout.rbl"
            blueprint.save(APPLICATION_ID, saved)
            copy = args.out / f"{timeline}.rrd"
            copy.write_bytes((args.run / RECORDING).read_bytes() + saved.read_bytes())
        print(copy)


if __name__ == "__main__":
    main()
