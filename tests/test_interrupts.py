"""Ctrl-C during compiled kernels: always a KeyboardInterrupt, never numba's SystemError."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest
import torch

from sfb_video.interrupts import kernel_call, sigint_outside_kernels
from sfb_video.render import kernels


def _interrupt_after(seconds: float) -> threading.Timer:
    timer = threading.Timer(seconds, os.kill, (os.getpid(), signal.SIGINT))
    timer.start()
    return timer


@pytest.mark.skipif(kernels.njit is None, reason="numba is not installed")
@pytest.mark.usefixtures("ctrl_c")
def test_a_sigint_amid_kernel_calls_is_a_keyboard_interrupt() -> None:
    # Without the handler every one of these came out as "SystemError: CPUDispatcher(...)
    # returned a result with an exception set".
    torch.manual_seed(0)
    uv, depth = torch.rand(4, 400, 2) * 60, torch.rand(4, 400) + 1
    faces = torch.randint(0, 400, (700, 3))
    with sigint_outside_kernels():
        for k in range(10):
            timer = _interrupt_after(0.01 + 0.003 * k)
            end = time.monotonic() + 5
            with pytest.raises(KeyboardInterrupt):
                while time.monotonic() < end:
                    kernels.nearest_faces(uv, depth, faces, True, 1e-6, (64, 64))
            timer.join()


@pytest.mark.usefixtures("ctrl_c")
def test_a_sigint_inside_a_kernel_call_is_raised_at_its_end() -> None:
    reached = []
    with sigint_outside_kernels(), pytest.raises(KeyboardInterrupt), kernel_call():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)  # the handler has run by now, and held the interrupt
        reached.append(True)
    assert reached
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_handler_set_by_the_caller_is_left_alone() -> None:
    def mine(signum: int, frame: object) -> None:
        pass

    previous = signal.signal(signal.SIGINT, mine)
    try:
        with sigint_outside_kernels():
            assert signal.getsignal(signal.SIGINT) is mine
    finally:
        signal.signal(signal.SIGINT, previous)
