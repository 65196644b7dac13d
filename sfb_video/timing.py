"""Where a run's wall time goes: seconds per pipeline stage, each stage's own time only.

Stages nest (the background stage pulls frames from the read stage; the joint fit reads the
clip again), so a stage's time excludes the stages timed inside it, and the stages' seconds add
up to at most the run's wall time. The clock is process-wide and always on: it costs two
``perf_counter`` calls per timed call, and nothing reads it but ``benchmarks.pipeline``.
"""

from __future__ import annotations

import functools
import time
from collections import defaultdict
from collections.abc import Callable, Generator, Iterable, Iterator
from contextlib import contextmanager
from typing import ParamSpec, TypeVar

P = ParamSpec("P")
R = TypeVar("R")
T = TypeVar("T")

_totals: defaultdict[str, float] = defaultdict(float)
_stack: list[list[float]] = []  # per open stage: [start, seconds of the stages inside it]


@contextmanager
def stage(name: str) -> Iterator[None]:
    """Count the time inside the block towards ``name``, less that of stages opened within it."""
    _stack.append([time.perf_counter(), 0.0])
    try:
        yield
    finally:
        start, inner = _stack.pop()
        elapsed = time.perf_counter() - start
        _totals[name] += elapsed - inner
        if _stack:
            _stack[-1][1] += elapsed


def timed(name: str) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """Decorate a function so that its calls count towards stage ``name``."""

    def decorate(function: Callable[P, R]) -> Callable[P, R]:
        @functools.wraps(function)
        def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
            with stage(name):
                return function(*args, **kwargs)

        return wrapper

    return decorate


def timed_iter(name: str, items: Iterable[T]) -> Generator[T, None, None]:
    """``items``, with the work of producing each one counted towards stage ``name`` (the
    consumer's work between items is not)."""
    iterator = iter(items)
    while True:
        with stage(name):
            try:
                item = next(iterator)
            except StopIteration:
                return
        yield item


def stage_seconds() -> dict[str, float]:
    """Seconds per stage since the last :func:`reset`."""
    return dict(_totals)


def reset() -> None:
    """Start counting from zero."""
    _totals.clear()
