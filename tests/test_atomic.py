"""Atomic writes: a file is complete or absent, nothing temporary outlives a failure, no folder is
created on the way, and every failure is one :class:`OutputError` naming the file."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from sfb_video.atomic import AtomicOutput, atomic_write_bytes, temporary_sibling, write_json
from sfb_video.errors import OutputError


def test_atomic_write_replaces_whole_files(tmp_path: Path) -> None:
    target = tmp_path / "file.bin"
    atomic_write_bytes(target, b"first version")
    atomic_write_bytes(target, b"second")
    assert target.read_bytes() == b"second"
    assert [p.name for p in tmp_path.iterdir()] == ["file.bin"]


def test_a_replaced_file_leaves_hard_links_to_the_old_one_unchanged(tmp_path: Path) -> None:
    # The run folder stages a re-export in a hard-linked clone: writes must never change a shared inode.
    target, link = tmp_path / "a.json", tmp_path / "b.json"
    write_json(target, {"v": 1})
    os.link(target, link)
    write_json(target, {"v": 2})
    assert '"v": 1' in link.read_text() and '"v": 2' in target.read_text()


def test_a_missing_folder_is_an_error_not_created(tmp_path: Path) -> None:
    with pytest.raises(OutputError, match=r"cannot write .*gone/x\.bin: its folder .*gone does not exist"):
        atomic_write_bytes(tmp_path / "gone" / "x.bin", b"x")
    assert not (tmp_path / "gone").exists()


def test_a_failed_write_leaves_no_temporary_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def full_disk(*args: object, **kwargs: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "replace", full_disk)
    with pytest.raises(OutputError, match="No space left on device"):
        atomic_write_bytes(tmp_path / "x.bin", b"x")
    assert list(tmp_path.iterdir()) == []


def test_temporary_files_are_hidden_marked_and_have_the_usual_permissions(tmp_path: Path) -> None:
    tmp = temporary_sibling(tmp_path / "video.mp4", ".mp4")
    assert tmp.name.startswith(".video.mp4.") and ".tmp" in tmp.name and tmp.suffix == ".mp4"
    mask = os.umask(0)
    os.umask(mask)
    assert tmp.stat().st_mode & 0o777 == 0o666 & ~mask


def test_an_atomic_output_aborts_on_any_exception_ctrl_c_included() -> None:
    calls: list[str] = []

    class Output(AtomicOutput):
        def close(self) -> None:
            calls.append("close")

        def abort(self) -> None:
            calls.append("abort")

    with Output():
        pass
    with pytest.raises(KeyboardInterrupt), Output():
        raise KeyboardInterrupt
    assert calls == ["close", "abort"]
