"""The output folder of every sfb-video command: its files, how it is recognised, created,
resumed, replaced and finished.

A folder is an sfb-video output when its ``run.json`` says so: ``{"format": "sfb-video",
"version": 1, "kind": ..., "finished": ...}`` (kinds: ``process``, ``fit``, ``eval``). The file's
mere presence proves nothing; a folder without that marker is never written into or removed,
``--overwrite`` or not (an empty folder is used as it is).

Life of a folder:

- **create**: a missing (or empty) folder is created with an unfinished marker and written in
  place;
- **resume** (``process`` only): an unfinished run of the same clip and config (same
  fingerprint) is continued in place, from its saved frames;
- **replace** (``--overwrite``): the new outputs are written into a hidden sibling,
  ``.<name>.sfb-video-new``, and swapped in only when finished, so the old folder stays whole
  until then and is untouched when the new run fails or is interrupted. An interrupted
  replacement of a ``process`` run that saved frames is kept there and resumed by the same
  command; any other is removed;
- **finish**: the marker is rewritten with ``finished: true`` (after every other file), then a
  replacement is swapped in: the old folder is renamed to ``.<name>.sfb-video-old``, the new one
  onto the name, and the old one removed. A swap cut short is completed or undone the next
  time the folder is opened.

``sfb-video export`` re-renders a run the same way: the run is cloned into the hidden sibling
with hard links (its files are only ever replaced, never changed, see :mod:`sfb_video.atomic`),
re-exported there and swapped in.

Files of a ``process`` run (every path of a run is spelled here)::

    run.json                  marker, the run's inputs and fingerprint
    config.yaml               the resolved config
    frames/frame_XXXXX_track_YY.pt    one saved fit per object fitted in a frame (what resume
                                      and export read)
    detections.json                   every frame's objects (or none), written when fitting is done
    windows/window_XXXXX_track_YY.pt  one saved joint fit per window of a track (from frame XXXXX)
    tsr.mp4, trajectory.csv, recording.rrd
    meshes/frame_XXXXX_track_YY.glb, meshes/track_YY.glb, meshes/best/mesh.obj (+ .mtl, .png)
    novel_views/frame_XXXXX_track_YY.mp4 (+ .png)
    summary.json              the last output written
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any, Self

from sfb_video.atomic import TEMPORARY_MARK, output_error, write_json
from sfb_video.errors import OutputError, SfbError

FORMAT = "sfb-video"
VERSION = 1
KINDS = ("process", "fit", "eval")

MARKER = "run.json"
CONFIG = "config.yaml"
FRAMES = "frames"
WINDOWS = "windows"
DETECTIONS = "detections.json"
CAMERA_MOTION = "camera_motion.json"
SUMMARY = "summary.json"
TSR_VIDEO = "tsr.mp4"
TRAJECTORY = "trajectory.csv"
RECORDING = "recording.rrd"
MESHES = "meshes"
BEST_MESH = "meshes/best"
NOVEL_VIEWS = "novel_views"

OUTPUTS = [TSR_VIDEO, TRAJECTORY, f"{MESHES}/", RECORDING, SUMMARY]
"""What a finished run offers its user (listed in its summary)."""

NEW_SUFFIX = ".sfb-video-new"
OLD_SUFFIX = ".sfb-video-old"


def frame_path(folder: Path, index: int, track: int) -> Path:
    """Where the saved fit of track ``track``'s object in frame ``index`` lives in a run folder."""
    return folder / FRAMES / f"frame_{index:05d}_track_{track:02d}.pt"


def saved_frames(folder: Path) -> set[tuple[int, int]]:
    """(frame index, track) of every object fit saved in a run ``folder``."""
    saved = set()
    for p in (folder / FRAMES).glob("frame_*_track_*.pt"):
        index, _, track = p.stem.removeprefix("frame_").partition("_track_")
        saved.add((int(index), int(track)))
    return saved


def window_path(folder: Path, track: int, first: int) -> Path:
    """Where the saved joint fit of track ``track``'s window from frame ``first`` lives."""
    return folder / WINDOWS / f"window_{first:05d}_track_{track:02d}.pt"


def mesh_path(folder: Path, index: int, track: int) -> Path:
    """The textured GLB of track ``track``'s object in frame ``index``."""
    return folder / MESHES / f"frame_{index:05d}_track_{track:02d}.glb"


def track_mesh_path(folder: Path, track: int) -> Path:
    """The textured GLB of track ``track`` (its shared mesh, at rest)."""
    return folder / MESHES / f"track_{track:02d}.glb"


def novel_view_path(folder: Path, index: int, track: int) -> Path:
    """The turntable video of track ``track``'s object in frame ``index`` (its PNG strip has the
    same stem)."""
    return folder / NOVEL_VIEWS / f"frame_{index:05d}_track_{track:02d}.mp4"


def sibling(path: Path, suffix: str) -> Path:
    """The hidden sibling of ``path`` that stages its replacement (``NEW_SUFFIX``) or holds the
    old folder during a swap (``OLD_SUFFIX``)."""
    return path.with_name(f".{path.name}{suffix}")


def read_marker(folder: Path) -> dict[str, Any] | None:
    """The marker of an sfb-video output folder, or None when ``folder`` is not one."""
    try:
        data = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("format") != FORMAT or data.get("kind") not in KINDS:
        return None
    return data


def ensure_folder(path: Path) -> Path:
    """Create the sub-folder ``path`` of an output folder that exists (never the folders above)."""
    try:
        path.mkdir(exist_ok=True)
    except OSError as exc:
        raise output_error(path / "-", exc) from None
    return path


class RunFolder:
    """An output folder opened for writing (:func:`open_run`, :func:`open_export`).

    Attributes:
        path: the folder the user named.
        work: where this command writes: ``path`` itself, or its hidden sibling when replacing.
        kind: ``process``, ``fit`` or ``eval``.
        record: the run's inputs as written in the marker.
        resumed: whether ``work`` already held this run's saved frames.

    As a context manager, an exception (Ctrl-C included) abandons the folder: a folder or
    staged replacement this command created is removed unless ``keep`` says it holds work worth
    resuming; the folder the user named is never touched then.
    """

    def __init__(
        self,
        path: Path,
        work: Path,
        kind: str,
        record: dict[str, Any],
        *,
        resumed: bool,
        created: bool,
        keep: Callable[[Path], bool],
    ) -> None:
        self.path, self.work, self.kind, self.record = path, work, kind, record
        self.resumed, self._created, self._keep = resumed, created, keep
        self.finished = False

    @property
    def replacing(self) -> bool:
        return self.work != self.path

    def check(self) -> None:
        """Raise :class:`OutputError` when the folder was removed or emptied during the run."""
        if read_marker(self.work) is None:
            raise OutputError(f"the output folder {self.work} was removed or emptied during the run")

    def finish(self) -> None:
        """Mark the outputs finished (the last write) and swap a replacement into place."""
        self.check()
        write_json(self.work / MARKER, _marker(self.kind, self.record, finished=True))
        if self.replacing:
            _swap(self.path, self.work)
        self.finished = True

    def abandon(self) -> None:
        """Give up after a failure: keep what can be resumed, remove what this command made."""
        if self.finished:
            return
        # A staged replacement is worth keeping only when the next run can resume it.
        resumable = not self.replacing or "fingerprint" in self.record
        if self.work.is_dir() and resumable and self._keep(self.work):
            _sweep_temporary(self.work)
        elif self.replacing or self._created:
            shutil.rmtree(self.work, ignore_errors=True)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is not None:
            self.abandon()


def open_run(
    path: Path,
    kind: str,
    record: dict[str, Any],
    *,
    overwrite: bool,
    keep: Callable[[Path], bool] = lambda _: False,
) -> RunFolder:
    """Create, resume or start replacing the output folder ``path`` for a command of ``kind``.

    Args:
        record: the run's inputs, written into the marker; a ``fingerprint`` key makes the run
            resumable: an unfinished run (or staged replacement) with the same fingerprint is
            continued instead of started again.
        overwrite: replace an existing sfb-video output (never another folder).
        keep: whether a folder this command made holds work worth keeping after a failure.

    Raises:
        SfbError: ``path`` is a file or a folder that is not an sfb-video output; it holds one
            and ``overwrite`` is off (unless it is resumed); it cannot be written.
    """
    path = Path(path)
    _recover(path)
    fingerprint = record.get("fingerprint")
    if not path.exists():
        _create(path, kind, record, parents=True)
        return RunFolder(path, path, kind, record, resumed=False, created=True, keep=keep)
    if not path.is_dir():
        raise SfbError(f"output path {path} exists and is not a folder")
    marker = read_marker(path)
    if marker is None:
        if _is_empty(path):
            _create(path, kind, record)
            return RunFolder(path, path, kind, record, resumed=False, created=False, keep=keep)
        raise SfbError(
            f"output folder {path} exists and is not an sfb-video output (no sfb-video {MARKER}); "
            "it is never replaced: choose another --out"
        )
    same = fingerprint is not None and marker.get("kind") == kind and marker.get("fingerprint") == fingerprint
    if not marker.get("finished") and same and not overwrite:
        _sweep_temporary(path)
        return RunFolder(path, path, kind, record, resumed=True, created=False, keep=keep)
    if not overwrite:
        if marker.get("kind") != kind:
            what = f"an sfb-video {marker.get('kind')} output"
        elif marker.get("finished"):
            what = "a finished run" if kind == "process" else f"a finished {kind} output"
        elif fingerprint is not None:
            what = "an unfinished run of another clip, config or mask source"
        else:
            what = f"an unfinished {kind} output"
        pending = " (and an interrupted replacement to resume)" if sibling(path, NEW_SUFFIX).exists() else ""
        raise SfbError(
            f"output folder {path} holds {what}{pending}; pass --overwrite to replace it "
            "(it stays as it is until the new outputs are finished)"
        )
    new = sibling(path, NEW_SUFFIX)
    staged = read_marker(new) if new.is_dir() else None
    resumable = staged is not None and fingerprint is not None and not staged.get("finished")
    if resumable and staged.get("kind") == kind and staged.get("fingerprint") == fingerprint:
        _sweep_temporary(new)
        return RunFolder(path, new, kind, record, resumed=True, created=False, keep=keep)
    shutil.rmtree(new, ignore_errors=True)
    _create(new, kind, record)
    return RunFolder(path, new, kind, record, resumed=False, created=True, keep=keep)


def open_export(path: Path) -> RunFolder:
    """Open the ``process`` run ``path`` for re-exporting: a hard-linked clone to write into,
    swapped in by :meth:`RunFolder.finish`.

    Raises:
        SfbError: ``path`` is not an sfb-video run, its fitting has not finished, or a
            replacement of it is still pending.
    """
    path = Path(path)
    _recover(path)
    marker = read_marker(path) if path.is_dir() else None
    if marker is None or marker.get("kind") != "process":
        raise SfbError(f"{path} is not an sfb-video run folder (run sfb-video process)")
    if not (path / DETECTIONS).is_file():
        raise SfbError(f"the run in {path} has not finished fitting; run the same sfb-video process command to resume")
    new = sibling(path, NEW_SUFFIX)
    if new.exists():
        raise SfbError(
            f"{path} has an unfinished replacement in {new}: resume it with its sfb-video process "
            "command and --overwrite, or delete that folder"
        )
    try:
        shutil.copytree(path, new, copy_function=_link_or_copy, ignore=_temporary_files)
    except (OSError, shutil.Error) as exc:
        shutil.rmtree(new, ignore_errors=True)
        raise OutputError(f"cannot stage the re-export of {path} in {new}: {exc}") from None
    record = {k: v for k, v in marker.items() if k not in ("format", "version", "kind", "finished")}
    folder = RunFolder(path, new, "process", record, resumed=True, created=True, keep=lambda _: False)
    write_json(new / MARKER, _marker("process", record, finished=False))
    return folder


def _marker(kind: str, record: dict[str, Any], *, finished: bool) -> dict[str, Any]:
    return {"format": FORMAT, "version": VERSION, "kind": kind, "finished": finished} | record


def _create(path: Path, kind: str, record: dict[str, Any], parents: bool = False) -> None:
    # Refused at the start, this is a bad --out (exit 2), not a failure during the run.
    try:
        path.mkdir(parents=parents, exist_ok=True)
        write_json(path / MARKER, _marker(kind, record, finished=False))
    except OSError as exc:
        raise SfbError(f"cannot write to output folder {path}: {exc.strerror or exc}") from None
    except OutputError as exc:
        raise SfbError(str(exc)) from None


def _is_empty(path: Path) -> bool:
    try:
        return not any(path.iterdir())
    except OSError as exc:
        raise SfbError(f"cannot read output folder {path}: {exc.strerror or exc}") from None


def _swap(path: Path, new: Path) -> None:
    old = sibling(path, OLD_SUFFIX)
    try:
        shutil.rmtree(old, ignore_errors=True)
        if path.exists():
            os.rename(path, old)
        os.rename(new, path)
    except OSError as exc:
        raise OutputError(f"cannot move the finished outputs from {new} to {path}: {exc.strerror or exc}") from None
    shutil.rmtree(old, ignore_errors=True)


def _recover(path: Path) -> None:
    """Complete or undo a swap that was cut short (see the module docstring)."""
    old = sibling(path, OLD_SUFFIX)
    if not old.is_dir():
        return
    if not path.exists():
        new = sibling(path, NEW_SUFFIX)
        staged = read_marker(new) if new.is_dir() else None
        source = new if staged is not None and staged.get("finished") else old
        os.rename(source, path)
    if old.is_dir() and read_marker(path) is not None:
        shutil.rmtree(old, ignore_errors=True)


def _sweep_temporary(folder: Path) -> None:
    """Remove the temporary files a killed process left (they never hold finished outputs)."""
    for tmp in folder.rglob(f".*{TEMPORARY_MARK}*"):
        if tmp.is_file():
            tmp.unlink(missing_ok=True)


def _temporary_files(folder: str, names: list[str]) -> list[str]:
    return [n for n in names if n.startswith(".") and TEMPORARY_MARK in n]


def _link_or_copy(source: str, target: str) -> None:
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)
