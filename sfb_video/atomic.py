"""Writing files atomically: a file either is complete or is not there.

Every output of sfb-video goes through here. A file is written under a hidden temporary name in
its own folder (``.<name>.<random>.tmp<suffix>``) and renamed onto its name only when complete;
on any failure, Ctrl-C included, the temporary file is removed and an existing file of that
name is left as it was. A rename replaces the directory entry, never the old file's contents,
so a hard-linked copy of a run folder (:mod:`sfb_video.run_folder` stages replacements that
way) is never changed by writes into the original.

Writes never create folders (callers create the ones they own): a run folder removed during a
run is reported, not silently re-created half-empty.
"""

from __future__ import annotations

import errno
import json
import os
import secrets
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import numpy as np
import torch

from sfb_video.errors import OutputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


FILE_MODE = 0o666 & ~_umask()
"""Permissions of a new file under this process's umask (a private 0600 would surprise users)."""

TEMPORARY_MARK = ".tmp"
"""Every temporary file's name holds this, so that a run folder can sweep what a killed process left."""


def output_error(path: Path, exc: OSError) -> OutputError:
    """The one-line error for an ``OSError`` met while writing ``path``."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    if exc.errno == errno.ENOENT and not path.parent.is_dir():
        reason = f"its folder {path.parent} does not exist (removed during the run?)"
    return OutputError(f"cannot write {path}: {reason}")


def temporary_sibling(path: Path, suffix: str = "") -> Path:
    """Create an empty temporary file beside ``path`` (with the usual permissions) and return it.

    Raises:
        OutputError: the folder cannot be written.
    """
    tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}{TEMPORARY_MARK}{suffix}"
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    except OSError as exc:
        raise output_error(path, exc) from None
    return tmp


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename.

    Raises:
        OutputError: the file cannot be written (full disk, missing folder, no permission).
    """
    path = Path(path)
    tmp = temporary_sibling(path)
    try:
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise output_error(path, exc) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_json(path: Path, data: dict[str, Any] | list[Any]) -> None:
    """Write ``data`` as indented JSON, atomically; tensors and arrays become lists.

    Non-ASCII text is escaped, so names that are not valid UTF-8 (legal on Linux) survive.
    """
    atomic_write_bytes(path, (json.dumps(data, indent=2, default=_jsonable) + "\n").encode())


def _jsonable(x: Any) -> Any:
    if isinstance(x, torch.Tensor | np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(f"cannot write {type(x).__name__} as JSON")


class AtomicOutput:
    """Base of writers that build a file under a temporary name: as a context manager, it calls
    :meth:`close` (which renames the file into place) on success and :meth:`abort` (which removes
    it) on any exception, Ctrl-C included."""

    def close(self) -> None:
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
