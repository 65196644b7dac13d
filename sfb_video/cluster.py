"""Independent jobs (clips, evaluation sequences) run on Ray, on this machine or on a cluster.

Ray is optional (``pip install 'sfb-video[cluster]'``). With no address a local Ray sized to
this machine is started (and stopped at the end); ``auto`` or ``HOST:PORT`` joins a running
cluster. Each job is one Ray task with ``cpus`` CPUs (its torch and numba threads follow them)
and ``gpus`` GPUs. A job that raises is a failure of that job, never retried (bad input fails
the same way twice); a job whose worker died (killed, out of memory, a node lost) is
resubmitted up to ``max_retries`` times. A job's function must itself be able to resume (the
pipeline resumes a clip from its saved frames).

Without Ray the same jobs run one after another in this process (:func:`run_here`).
"""

from __future__ import annotations

import contextlib
import os
import socket
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from sfb_video.errors import SfbError, printable

INSTALL = "pip install 'sfb-video[cluster]'"


@dataclass(frozen=True)
class Resources:
    """What one job asks of a worker: CPUs (its torch and numba threads) and GPUs."""

    cpus: int = 1
    gpus: float = 0.0


@dataclass(frozen=True)
class Outcome:
    """How a job ended: its function's value, or the one-line ``error`` that stopped it, and
    how many times its worker died and it was resubmitted."""

    value: Any = None
    error: str = ""
    retries: int = 0


def ray_installed() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


@contextlib.contextmanager
def limited_threads(cpus: int) -> Iterator[None]:
    """Torch and numba use ``cpus`` threads (a job's share of a worker's cores) inside the
    ``with`` block, and as many as before after it."""
    import torch

    numba: Any = None
    with contextlib.suppress(ImportError):
        import numba
    # numba first: starting its threading layer sets OpenMP's thread count, torch's with it.
    numba_before = None if numba is None else numba.get_num_threads()
    if numba is not None:
        numba.set_num_threads(max(1, min(cpus, numba.config.NUMBA_NUM_THREADS)))
    before = torch.get_num_threads()
    torch.set_num_threads(max(1, cpus))
    try:
        yield
    finally:
        if numba is not None:
            numba.set_num_threads(numba_before)
        torch.set_num_threads(before)


@contextlib.contextmanager
def connected(address: str | None, cpus: int | None = None) -> Iterator[None]:
    """Ray for the ``with`` block: a new local one (``address`` None, ``cpus`` CPUs, default
    this machine's), or the cluster at ``address`` (``auto``: the one ``ray start`` runs here).

    Raises:
        SfbError: Ray is not installed, or the cluster cannot be reached.
    """
    try:
        import ray
    except ImportError:
        raise SfbError(f"Ray is not installed; {INSTALL}") from None
    # Ray's start-up lines (token authentication, the dashboard) would break the one-line output.
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    options: dict[str, Any] = {"configure_logging": False, "log_to_driver": False, "include_dashboard": False}
    if address is not None and address != "auto":
        _check_reachable(address)
    try:
        if address is None:
            ray.init(num_cpus=cpus, **options)
        else:
            ray.init(address=address, **options)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = "a local Ray" if address is None else f"the Ray cluster at {address}"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise SfbError(f"cannot start or reach {where}: {first}") from None
    try:
        yield
    finally:
        ray.shutdown()


def _check_reachable(address: str, timeout: float = 10.0) -> None:
    """Raise :class:`SfbError` unless something listens at ``HOST:PORT`` (``ray://`` allowed):
    Ray itself would wait for minutes on a mistyped address."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise SfbError(f"--ray-address must be auto or HOST:PORT, got {address!r}")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as exc:
        raise SfbError(f"cannot reach the Ray cluster at {address}: {exc.strerror or exc}") from None


def run_on_ray(
    function: Callable[..., Any],
    jobs: Sequence[tuple[Any, ...]],
    resources: Resources,
    max_retries: int,
    on_done: Callable[[int, Outcome], None],
    on_retry: Callable[[int, str], None] | None = None,
    on_tick: Callable[[], None] | None = None,
) -> None:
    """Run ``function(*job)`` for every job as a Ray task, within :func:`connected`.

    ``on_done(i, outcome)`` is called as each job ends, in the order they end; ``on_retry(i,
    why)`` when job ``i``'s worker died and it is resubmitted; ``on_tick()`` twice a second
    while jobs run (to read their progress).
    """
    import ray
    from ray.exceptions import RayError, RayTaskError

    remote = ray.remote(_limited).options(
        num_cpus=resources.cpus, num_gpus=resources.gpus, max_retries=0, retry_exceptions=False
    )
    pending = {remote.remote(function, resources.cpus, *job): i for i, job in enumerate(jobs)}
    retries = [0] * len(jobs)
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
        if on_tick is not None:
            on_tick()
        if not ready:
            continue
        ref = ready[0]
        i = pending.pop(ref)
        try:
            on_done(i, Outcome(ray.get(ref), retries=retries[i]))
        except RayTaskError as exc:
            on_done(i, Outcome(error=_one_line(exc.cause if exc.cause is not None else exc), retries=retries[i]))
        except RayError as exc:  # the worker or its node died: the job itself did not fail
            why = _one_line(exc)
            if retries[i] >= max_retries:
                on_done(i, Outcome(error=f"its worker died {retries[i] + 1} time(s): {why}", retries=retries[i]))
                continue
            retries[i] += 1
            if on_retry is not None:
                on_retry(i, why)
            pending[remote.remote(function, resources.cpus, *jobs[i])] = i


def run_here(
    function: Callable[..., Any],
    jobs: Sequence[tuple[Any, ...]],
    resources: Resources,
    on_done: Callable[[int, Outcome], None],
) -> None:
    """:func:`run_on_ray`'s jobs one after another in this process (no retries: a death here
    is this process's)."""
    for i, job in enumerate(jobs):
        try:
            outcome = Outcome(_limited(function, resources.cpus, *job))
        except Exception as exc:  # one job's error must not stop the others
            outcome = Outcome(error=_one_line(exc))
        on_done(i, outcome)


def _limited(function: Callable[..., Any], cpus: int, *args: Any) -> Any:
    with limited_threads(cpus):
        return function(*args)


def _one_line(exc: BaseException) -> str:
    """An error as one line: its message's first line, or its type where it has none."""
    text = str(exc).strip()
    if isinstance(exc, SfbError):
        return printable(text)
    first = text.splitlines()[0] if text else ""
    return printable(f"{type(exc).__name__}: {first}" if first else type(exc).__name__)
