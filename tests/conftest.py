"""Shared fixtures: the device to test on (``--device cuda`` opts in), a fixed seed, an empty torch
hub, DeFMO weights."""

from __future__ import annotations

import os
import shutil
import signal
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch


def pytest_configure(config: pytest.Config) -> None:
    # An empty torch hub cache: the suite must not depend on DeFMO weights a developer has
    # downloaded (``--masks auto`` would pick them up), nor ever download any.
    os.environ["TORCH_HOME"] = tempfile.mkdtemp(prefix="sfb-video-torch-home-")


def pytest_unconfigure(config: pytest.Config) -> None:
    shutil.rmtree(os.environ["TORCH_HOME"], ignore_errors=True)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--device", default="cpu", help="torch device to run device-aware tests on")


@pytest.fixture
def device(request: pytest.FixtureRequest) -> torch.device:
    name = request.config.getoption("--device")
    if name.startswith("cuda") and not torch.cuda.is_available():
        pytest.skip("CUDA requested but not available")
    return torch.device(name)


@pytest.fixture(scope="session")
def defmo_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding DeFMO's two weight files, with seeded random weights (no download)."""
    from kornia.feature import DeFMO

    from sfb_video.defmo import WEIGHT_FILES

    folder = tmp_path_factory.mktemp("defmo")
    torch.manual_seed(0)
    network = DeFMO(pretrained=False)
    for part, name in WEIGHT_FILES.items():
        torch.save(getattr(network, part).state_dict(), folder / name)
    return folder


@pytest.fixture(autouse=True)
def _seed() -> None:
    torch.manual_seed(0)


@pytest.fixture
def ctrl_c() -> Iterator[None]:
    """SIGINT handled as Python's default, for the tests that send it: a suite started as a
    background job of a shell without job control inherits SIGINT ignored (POSIX), and so do
    the processes it starts, where a Ctrl-C would then be lost before our handler sees it."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
