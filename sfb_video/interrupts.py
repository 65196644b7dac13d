"""Ctrl-C that never lands inside a call of a compiled kernel.

A KeyboardInterrupt raised while numba's dispatcher hands over to a compiled kernel is
mishandled: it comes out as "SystemError: CPUDispatcher(...) returned a result with an
exception set" (a traceback and exit status 1 instead of our one line and 130), or it is lost
and the run goes on to the end. Measured: every one of 40 SIGINTs sent into a loop of kernel
calls came out as the SystemError, and 1 in 4 interrupts of a fit from the command line.
So under :func:`sigint_outside_kernels` a SIGINT that arrives during a :func:`kernel_call` is
held until the call returns (a few milliseconds), and raised there.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

_inside = 0  # kernel calls in progress
_held = False  # a SIGINT arrived during one


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    global _held
    if _inside:
        _held = True
    else:
        raise KeyboardInterrupt


class _KernelCall:
    """The block of :func:`kernel_call`: a class, not a generator, because a run makes some
    220,000 kernel calls and contextlib's machinery cost more than the counting."""

    __slots__ = ()

    def __enter__(self) -> None:
        global _inside
        _inside += 1

    def __exit__(self, kind: type[BaseException] | None, *_: object) -> None:
        global _inside, _held
        _inside -= 1
        if kind is None and _held and not _inside:
            _held = False
            raise KeyboardInterrupt


_KERNEL_CALL = _KernelCall()


def kernel_call() -> _KernelCall:
    """Hold a SIGINT that arrives inside this block until its end (where it is raised): a
    compiled kernel's call, or an import that would swallow the KeyboardInterrupt."""
    return _KERNEL_CALL


@contextmanager
def sigint_outside_kernels() -> Iterator[None]:
    """SIGINT raises KeyboardInterrupt as usual, but never inside a :func:`kernel_call`.

    Installed only from the main thread over Python's default handler; a handler the caller set
    (a notebook's, a test runner's) is left alone.
    """
    main = threading.current_thread() is threading.main_thread()
    if not main or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield
        return
    signal.signal(signal.SIGINT, _on_sigint)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)
