"""The layout the viewer opens a recording on (its blueprint), and the texts it shows of the run."""

from __future__ import annotations

import uuid
from collections.abc import Sequence

import numpy as np
import rerun.blueprint as rrb

APPLICATION_ID = "sfb-video"
FRAME, SUBFRAME, STEP = "frame", "subframe", "step"
EYE_MIN_DISTANCE = 6.0
"""The 3D view's eye stands at least this far from the trajectories' middle, in object sizes."""


def shape_text(windows: Sequence[dict]) -> str:
    """Markdown: per joint window (summary.json's ``joint.windows``), its track, frames and
    shape, and where a trial of shapes chose it (a track's first window, with ``joint.prototypes``)
    how clearly: its margin and each shape's score over the sphere's. Other windows carry on the
    shape of the track's earlier fits (the previous window's, or the single-frame fits')."""
    if not windows:
        return "No joint windows: every frame shows its single-frame fit."
    lines = ["| track | frames | shape | margin | scores over the sphere's |", "|---:|---|---|---:|---|"]
    for w in windows:
        margin = w.get("shape_margin")
        scores = ", ".join(f"{name} {value:.2f}" for name, value in (w.get("shape_trial") or {}).items())
        scores = scores or "no trial: the shape of the track's earlier fits"
        lines.append(
            f"| {w['track']} | {spans(w['frames'])} | {w['prototype']} | "
            f"{'-' if margin is None else format(margin, '+.2f')} | {scores} |"
        )
    return "\n".join(lines)


def spans(frames: Sequence[int]) -> str:
    """Frame indices as runs: [0, 1, 2, 5] -> "0-2, 5"."""
    runs: list[list[int]] = []
    for f in sorted(frames):
        if runs and f == runs[-1][1] + 1:
            runs[-1][1] = f
        else:
            runs.append([f, f])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def layout(tracks: Sequence[int], paths: Sequence[np.ndarray], subframes: int) -> rrb.Blueprint:
    """The viewer's layout of a recording (its blueprint), for what a person comes to see.

    Top: the input frame with its detection (and masks) beside the super-resolved sub-frame.
    Bottom: the 3D view framed on the trajectories, beside tabs: one per track (its losses per
    frame and how much it explains), the fits' loss curves (on the step timeline), the
    reconstruction and background, the run's text (masks, summary, config). It opens on the
    subframe timeline (the frame timeline for a recording of one sub-frame per frame), where
    every panel it shows has content. Its views' ids are derived from their place in it, so the
    same recording's layout is the same at every load and two runs write the same layout.

    Args:
        tracks: the tracks fitted; paths: (P, 3) each track's 3D positions.
    """
    per_track = [
        rrb.TimeSeriesView(
            name=f"track {t}",
            origin="/",
            contents=[f"losses/track_{t:02d}/**", f"quality/track_{t:02d}/**"],
        )
        for t in tracks
    ]
    curves = rrb.TimeSeriesView(name="fit curves (step timeline)", origin="fit")
    text = rrb.Vertical(
        rrb.TextDocumentView(name="shapes", origin="run/shapes"),
        rrb.TextDocumentView(name="masks", origin="run/masks"),
        rrb.TextDocumentView(name="summary", origin="run/summary"),
        rrb.TextDocumentView(name="config", origin="run/config"),
        name="run",
    )
    images = rrb.Horizontal(
        rrb.Spatial2DView(name="reconstruction", origin="reconstruction"),
        rrb.Spatial2DView(name="background", origin="background"),
        name="reconstruction",
    )
    scene = rrb.Spatial3DView(
        name="3D",
        origin="world",
        # The frame on the camera's frustum would hide the object behind it from this eye.
        contents=["+ $origin/**", "- world/camera/image/**"],
        eye_controls=_eye(paths),
    )
    root = rrb.Vertical(
        rrb.Horizontal(
            rrb.Spatial2DView(name="input and detection", origin="world/camera/image"),
            rrb.Spatial2DView(name="super-resolved", origin="tsr"),
        ),
        rrb.Horizontal(scene, rrb.Tabs(*per_track, curves, images, text, active_tab=0)),
        row_shares=[3, 2],
    )
    _fix_ids(root, "root")
    timeline = SUBFRAME if subframes > 1 else FRAME
    return rrb.Blueprint(root, rrb.TimePanel(timeline=timeline, state="expanded"), auto_layout=False, auto_views=False)


def _eye(paths: Sequence[np.ndarray]) -> rrb.archetypes.EyeControls3D | None:
    """An eye looking along the camera's axis at the middle of the trajectories, back far enough
    to see them whole (None: no trajectory; the viewer frames the scene)."""
    points = [p for p in paths if len(p)]
    if not points:
        return None
    every = np.concatenate(points).astype(np.float64)
    low, high = every.min(0), every.max(0)
    target = (low + high) / 2
    # In object sizes: a still object is still seen at a few of its sizes.
    distance = 1.2 * float(np.linalg.norm(high - low)) + EYE_MIN_DISTANCE
    # The camera frame is RDF (y down): the eye sits a little above the camera's axis.
    direction = np.array([0.0, -0.35, -1.0]) / np.linalg.norm([0.0, -0.35, -1.0])
    return rrb.archetypes.EyeControls3D(
        kind="Orbital", position=target + distance * direction, look_target=target, eye_up=[0.0, -1.0, 0.0]
    )


def _fix_ids(part: rrb.Container | rrb.View, place: str) -> None:
    """Give ``part`` and what it holds ids derived from ``place``, not random ones."""
    part.id = uuid.uuid5(uuid.NAMESPACE_URL, f"{APPLICATION_ID}:layout:{place}")
    if isinstance(part, rrb.Container):  # a view's contents are its entity queries
        for i, inner in enumerate(part.contents):
            _fix_ids(inner, f"{place}/{i}")


def track_entity(track: int) -> str:
    """The entity of track ``track``'s object: its mesh and pose."""
    return f"world/track_{track:02d}/object"
