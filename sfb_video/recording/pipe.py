"""The named pipe rerun's file sink writes into, copied into the recording's file by a thread of
ours with plain writes: rerun's writer never fails, and a write error is an ``OSError`` of ours."""

from __future__ import annotations

import contextlib
import os
import tempfile
import threading
from pathlib import Path

PIPE_READ_SIZE = 1 << 20
"""How much of the pipe the copy thread takes at a time."""


class Pipe:
    """A named pipe for rerun's file sink to write into, copied into ``target`` by a thread.

    The pipe is made in a private temporary folder and its name removed once both ends are open
    (:meth:`start`), so that nothing of it outlives the process. The thread reads until rerun
    closes its end (on disconnect) and never stops reading before: after a write error it keeps
    draining and drops what it reads, so rerun's writer is never blocked and its flush and
    disconnect always return. The first error is kept in :attr:`error`.

    Raises:
        OSError: ``target`` cannot be opened, or the pipe cannot be made.
    """

    def __init__(self, target: Path) -> None:
        self.error: OSError | None = None
        self._thread: threading.Thread | None = None
        self._out: int | None = os.open(target, os.O_WRONLY | os.O_TRUNC | os.O_CLOEXEC)
        self._folder: Path | None = None
        self._in: int | None = None
        try:
            self._folder = Path(tempfile.mkdtemp(prefix="sfb-video-recording-"))
            self.path = self._folder / "pipe"
            os.mkfifo(self.path, 0o600)
            # Non-blocking, or opening the reading end would wait for a writer; rerun's save()
            # opens its end synchronously, and finds this one there.
            self._in = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except BaseException:
            self._close()
            raise

    def start(self) -> None:
        """Start copying, once rerun has opened its end (rerun's ``save`` returned)."""
        assert self._in is not None
        self._remove_name()
        os.set_blocking(self._in, True)
        self._thread = threading.Thread(target=self._copy, name="sfb-video recording writer", daemon=True)
        self._thread.start()

    def finish(self, timeout_s: float) -> None:
        """Wait for the copy to end (rerun has closed its end) and close the file.

        Raises:
            OSError: the first write error, or TimeoutError if the copy did not end in time.
        """
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                # A disk that stopped answering: the thread (a daemon) is left to it.
                raise TimeoutError(f"the recording was not written within {timeout_s:g} s")
        self._close()
        if self.error is not None:
            raise self.error

    def _copy(self) -> None:
        assert self._in is not None and self._out is not None
        try:
            while chunk := os.read(self._in, PIPE_READ_SIZE):
                if self.error is None:
                    try:
                        write_all(self._out, chunk)
                    except OSError as e:
                        self.error = e
        except OSError as e:  # reading a pipe fails only if something is badly wrong; keep it
            self.error = self.error or e
        finally:
            self._close()

    def _close(self) -> None:
        """Close both descriptors and remove the pipe's name; safe to call more than once."""
        fd_in, fd_out, self._in, self._out = self._in, self._out, None, None
        if fd_in is not None:
            with contextlib.suppress(OSError):
                os.close(fd_in)
        if fd_out is not None:
            try:
                os.close(fd_out)
            except OSError as e:  # some file systems (NFS) report a failed write only here
                self.error = self.error or e
        self._remove_name()

    def _remove_name(self) -> None:
        folder, self._folder = self._folder, None
        if folder is not None:
            with contextlib.suppress(OSError):
                (folder / "pipe").unlink(missing_ok=True)
                folder.rmdir()


def write_all(fd: int, data: bytes) -> None:
    """Write all of ``data`` to ``fd``: a write may take only part of it (a short write just
    before the disk is full), and only the next one reports why."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]
