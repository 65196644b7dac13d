"""The run folder's contract on its own: what counts as an sfb-video output, create / resume /
replace / finish, a swap cut short, and that a failure never touches the folder the user named."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from sfb_video.atomic import atomic_write_bytes
from sfb_video.errors import SfbError
from sfb_video.run_folder import (
    MARKER,
    NEW_SUFFIX,
    OLD_SUFFIX,
    open_export,
    open_run,
    read_marker,
    sibling,
)

RECORD = {"video": "clip.mp4", "fingerprint": "abc"}


def _finished(path: Path, content: str = "old", kind: str = "process") -> Path:
    with open_run(path, kind, RECORD, overwrite=False) as run:
        (run.work / "result.txt").write_text(content)
        run.finish()
    return path


def _contents(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_new_folder_is_created_marked_unfinished_then_finished(tmp_path: Path) -> None:
    out = tmp_path / "a" / "run"
    run = open_run(out, "process", RECORD, overwrite=False)
    assert run.work == out and not run.resumed and not run.replacing
    marker = read_marker(out)
    assert marker is not None and marker["format"] == "sfb-video" and marker["version"] == 1
    assert marker["kind"] == "process" and marker["finished"] is False and marker["video"] == "clip.mp4"
    run.finish()
    assert read_marker(out)["finished"] is True


@pytest.mark.parametrize(
    "marker",
    [None, {"fingerprint": "abc", "video": "x"}, {"format": "sfb-video", "kind": "poster"}, "not json"],
)
def test_a_folder_without_our_marker_is_never_written_into(tmp_path: Path, marker: object) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.md").write_text("precious")
    if marker is not None:
        (out / MARKER).write_text(marker if isinstance(marker, str) else json.dumps(marker))
    before = _contents(out)
    with pytest.raises(SfbError, match="not an sfb-video output"):
        open_run(out, "process", RECORD, overwrite=True)
    assert _contents(out) == before
    assert not sibling(out, NEW_SUFFIX).exists()


def test_an_empty_folder_is_used_as_it_is(tmp_path: Path) -> None:
    out = tmp_path / "empty"
    out.mkdir()
    run = open_run(out, "fit", {}, overwrite=False)
    assert run.work == out and read_marker(out)["kind"] == "fit"


def test_an_unfinished_run_with_the_same_fingerprint_resumes_in_place(tmp_path: Path) -> None:
    out = tmp_path / "run"
    open_run(out, "process", RECORD, overwrite=False)
    (out / ".frame.pt.1234.tmp").write_text("left by a killed process")
    run = open_run(out, "process", RECORD, overwrite=False)
    assert run.resumed and run.work == out
    assert not (out / ".frame.pt.1234.tmp").exists()  # swept
    with pytest.raises(SfbError, match="unfinished run of another clip"):
        open_run(out, "process", RECORD | {"fingerprint": "other"}, overwrite=False)


def test_a_finished_run_needs_overwrite_and_stays_whole_until_the_new_one_finishes(tmp_path: Path) -> None:
    out = _finished(tmp_path / "run")
    with pytest.raises(SfbError, match="holds a finished run; pass --overwrite"):
        open_run(out, "process", RECORD, overwrite=False)
    before = _contents(out)
    run = open_run(out, "process", RECORD | {"fingerprint": "new"}, overwrite=True)
    assert run.replacing and run.work == sibling(out, NEW_SUFFIX)
    (run.work / "result.txt").write_text("new")
    assert _contents(out) == before  # untouched while the new run works
    run.finish()
    assert (out / "result.txt").read_text() == "new" and read_marker(out)["fingerprint"] == "new"
    assert not sibling(out, NEW_SUFFIX).exists() and not sibling(out, OLD_SUFFIX).exists()


def test_a_failed_replacement_leaves_the_old_run_as_it_was(tmp_path: Path) -> None:
    out = _finished(tmp_path / "run")
    before = _contents(out)
    with pytest.raises(RuntimeError), open_run(out, "process", RECORD, overwrite=True) as run:
        (run.work / "result.txt").write_text("half")
        raise RuntimeError("the new run failed")
    assert _contents(out) == before
    assert not sibling(out, NEW_SUFFIX).exists()  # nothing worth resuming: removed


def test_an_interrupted_replacement_with_work_to_resume_is_kept_and_resumed(tmp_path: Path) -> None:
    out = _finished(tmp_path / "run")
    before = _contents(out)
    record = RECORD | {"fingerprint": "new"}
    has_work = lambda folder: (folder / "frame.txt").exists()  # noqa: E731
    with pytest.raises(KeyboardInterrupt), open_run(out, "process", record, overwrite=True, keep=has_work) as run:
        (run.work / "frame.txt").write_text("frame 0")
        raise KeyboardInterrupt
    assert _contents(out) == before
    with pytest.raises(SfbError, match="interrupted replacement"):
        open_run(out, "process", record, overwrite=False)
    again = open_run(out, "process", record, overwrite=True, keep=has_work)
    assert again.resumed and (again.work / "frame.txt").read_text() == "frame 0"
    # Another config does not resume it: the staged work is cleanly dropped.
    fresh = open_run(out, "process", record | {"fingerprint": "third"}, overwrite=True)
    assert not fresh.resumed and not (fresh.work / "frame.txt").exists()


def test_a_replacement_of_a_kind_that_cannot_resume_is_not_kept(tmp_path: Path) -> None:
    out = _finished(tmp_path / "eval", kind="eval")
    with pytest.raises(KeyboardInterrupt), open_run(out, "eval", {}, overwrite=True, keep=lambda f: True) as run:
        (run.work / "table.md").write_text("half")
        raise KeyboardInterrupt
    assert not sibling(out, NEW_SUFFIX).exists() and (out / "result.txt").read_text() == "old"


def test_a_new_folder_that_failed_without_work_is_removed(tmp_path: Path) -> None:
    out = tmp_path / "run"
    with pytest.raises(RuntimeError), open_run(out, "process", RECORD, overwrite=False):
        raise RuntimeError
    assert not out.exists()


@pytest.mark.parametrize("staged_finished", [True, False])
def test_a_swap_cut_short_is_completed_or_undone(tmp_path: Path, staged_finished: bool) -> None:
    out = _finished(tmp_path / "run")
    run = open_run(out, "process", RECORD | {"fingerprint": "new"}, overwrite=True)
    (run.work / "result.txt").write_text("new")
    if staged_finished:
        marker = read_marker(run.work) | {"finished": True}
        (run.work / MARKER).write_text(json.dumps(marker))
    os.rename(out, sibling(out, OLD_SUFFIX))  # the process died between the swap's two renames
    assert not out.exists()
    open_run(tmp_path / "run", "process", RECORD | {"fingerprint": "x"}, overwrite=True)
    assert (out / "result.txt").read_text() == ("new" if staged_finished else "old")
    assert not sibling(out, OLD_SUFFIX).exists()


def test_export_works_on_a_hard_linked_clone_and_swaps_it_in(tmp_path: Path) -> None:
    out = _finished(tmp_path / "run")
    (out / "detections.json").write_text("[]")
    before = _contents(out)
    with pytest.raises(RuntimeError), open_export(out) as run:
        atomic_write_bytes(run.work / "result.txt", b"re-exported")  # replaces the link, not the file...
        raise RuntimeError("export failed")
    assert _contents(out) == before  # ...so the original is whole
    assert not sibling(out, NEW_SUFFIX).exists()
    run = open_export(out)
    atomic_write_bytes(run.work / "result.txt", b"re-exported")
    run.finish()
    assert (out / "result.txt").read_text() == "re-exported" and read_marker(out)["finished"] is True


def test_export_refuses_what_is_not_a_fitted_run(tmp_path: Path) -> None:
    with pytest.raises(SfbError, match="not an sfb-video run folder"):
        open_export(tmp_path)
    out = _finished(tmp_path / "run")
    with pytest.raises(SfbError, match="has not finished fitting"):
        open_export(out)
