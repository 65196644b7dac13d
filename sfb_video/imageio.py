"""Reading and writing images, atomically: a file either is complete or is not there."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from types import TracebackType
from typing import Self

import cv2
import numpy as np
import torch

from sfb_video.checks import SfbError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


FILE_MODE = 0o666 & ~_umask()
"""Permissions of a new file under this process's umask; mkstemp's private 0600 is set to it."""


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        # mkstemp makes the file private (0600); outputs should get the usual permissions.
        os.chmod(tmp, FILE_MODE)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


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


def to_uint8(image: torch.Tensor | np.ndarray) -> np.ndarray:
    """A (3, H, W) tensor or (H, W, 3) array in [0, 1] -> (H, W, 3) uint8 RGB."""
    if isinstance(image, torch.Tensor):
        image = image.detach().cpu().permute(1, 2, 0).numpy()
    return np.round(np.clip(image, 0.0, 1.0) * 255).astype(np.uint8)


def write_image(path: str | Path, image: torch.Tensor | np.ndarray) -> None:
    """Write an RGB image in [0, 1] (tensor (3, H, W) or array (H, W, 3)); format from the suffix."""
    rgb = to_uint8(image) if image.dtype != np.uint8 else image
    ok, buf = cv2.imencode(Path(path).suffix or ".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise SfbError(f"cannot encode an image as {Path(path).suffix!r}: {path}")
    atomic_write_bytes(path, buf.tobytes())


def read_image(path: str | Path) -> torch.Tensor:
    """Read an image file as a (3, H, W) float tensor in [0, 1]; grayscale and 16-bit converted."""
    path = Path(path)
    if not path.is_file():
        raise SfbError(f"image not found: {path}")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise SfbError(f"not a readable image: {path}")
    scale = 65535.0 if raw.dtype == np.uint16 else 255.0
    if raw.ndim == 2:
        raw = cv2.cvtColor(raw, cv2.COLOR_GRAY2BGR)
    elif raw.shape[2] == 4:
        raw = raw[:, :, :3]
    rgb = cv2.cvtColor(raw, cv2.COLOR_BGR2RGB).astype(np.float32) / scale
    return torch.from_numpy(rgb).permute(2, 0, 1).contiguous()
