"""The project's error classes and the input checks that raise them.

Every check here raises a subclass of :class:`SfbError`, itself a ``ValueError``, with a
one-line message that names the problem. The CLI turns these into a message and an exit code.
"""

from __future__ import annotations

import math

import torch


def printable(text: str) -> str:
    """``text`` safe to print: a file name that is not valid UTF-8 (legal on Linux) reaches
    Python with surrogate escapes, which an UTF-8 stream refuses; they become U+FFFD."""
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")


class SfbError(ValueError):
    """Base class of every error that sfb-video reports to a user as one line."""


class MeshError(SfbError):
    """A mesh is malformed: non-finite vertices, faces out of range, wrong shapes."""


class PoseError(SfbError):
    """A pose puts geometry where it cannot be rendered (behind or on the camera plane)."""


class ConfigError(SfbError):
    """A configuration file or override is invalid."""


class OutputError(SfbError):
    """An output could not be written: a full disk, a folder removed or made read-only mid-run."""


class NoObjectError(SfbError):
    """The frame shows nothing that differs from the background (or too little to fit)."""


class DivergenceError(SfbError):
    """A fit's loss was not finite from its first step: nothing was learnt to keep.

    The only error a pipeline stage takes for "this fit diverged, go on without it"; any other
    error (a device mismatch, CUDA out of memory) is a bug or a resource problem and is raised.
    """


def check_shape(x: torch.Tensor, shape: tuple[int | None, ...], name: str) -> None:
    """Raise :class:`SfbError` unless ``x`` has ``shape`` (``None`` matches any size)."""
    ok = x.dim() == len(shape) and all(s is None or s == d for s, d in zip(shape, x.shape, strict=True))
    if not ok:
        want = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
        raise SfbError(f"{name} must have shape {want}, got {tuple(x.shape)}")


def check_finite(x: torch.Tensor, name: str, error: type[SfbError] = SfbError) -> None:
    """Raise ``error`` if ``x`` holds NaN or infinite values."""
    # A sum is finite when every value is, and costs a twentieth of isfinite(x).all() on a
    # texture (every render checks one); only a sum that is not (NaN, or finite values
    # overflowing) needs the values looked at one by one.
    if not math.isfinite(float(x.detach().sum())) and not bool(torch.isfinite(x).all()):
        raise error(f"{name} contains NaN or infinite values")


def check_faces(faces: torch.Tensor, num_vertices: int | None) -> tuple[int, int]:
    """Check that ``faces`` (F, 3) is an integer tensor indexing ``num_vertices`` vertices (any
    number of them: None).

    Returns:
        the lowest and highest index (0, -1 without faces), read from the device at once.
    """
    check_shape(faces, (None, 3), "faces")
    if faces.dtype not in (torch.int32, torch.int64):
        raise MeshError(f"faces must be an integer tensor, got {faces.dtype}")
    low, high = (0, -1) if not faces.numel() else torch.stack([faces.min(), faces.max()]).tolist()
    if num_vertices is not None:
        check_face_span((low, high), num_vertices)
    return low, high


def check_face_span(span: tuple[int, int], num_vertices: int) -> None:
    """Check that faces whose indices span ``span`` (lowest, highest) index ``num_vertices`` vertices."""
    low, high = span
    if low < 0 or high >= num_vertices:
        raise MeshError(
            f"faces index vertices out of range: indices span [{low}, {high}] but the mesh has {num_vertices} vertices"
        )


def check_in_front(depth: torch.Tensor, near: float) -> None:
    """Check that every vertex depth (*, V) lies beyond the near plane ``near``."""
    if depth.numel() and float(depth.min()) <= near:
        raise PoseError(
            f"the mesh reaches behind the camera or its near plane (min depth {float(depth.min()):.3g}"
            f" <= near {near:g}): move it in front of the camera"
        )
