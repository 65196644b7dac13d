"""The types the stages hand each other: a decoded frame, a frame with its background, a
detection and a track's prediction, a frame's status after tracking, a joint window.

They live here, below every stage, so that a stage imports the types it is given without
importing the stage that makes them.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from sfb_video.crop import Box
from sfb_video.imageio import as_float


@dataclass(frozen=True)
class Frame:
    """One decoded frame.

    Attributes:
        index: position in the clip, from 0.
        image: (3, H, W) RGB: uint8 for 8-bit sources, else float32 in [0, 1].
    """

    index: int
    image: torch.Tensor


@dataclass(frozen=True)
class FrameWithBackground:
    """A frame and its background.

    Attributes:
        index: the frame's position in the clip.
        pixels, background_pixels: (3, H, W) each, kept as compact as the source allows: uint8
            from an 8-bit clip (a 4K frame is 25 MB, not 100), else float32 in [0, 1].
    """

    index: int
    pixels: torch.Tensor
    background_pixels: torch.Tensor

    @property
    def image(self) -> torch.Tensor:
        """(3, H, W) float32 in [0, 1] (made on each access from compact pixels)."""
        return as_float(self.pixels)

    @property
    def background(self) -> torch.Tensor:
        """(3, H, W) float32 in [0, 1] (made on each access from compact pixels)."""
        return as_float(self.background_pixels)


@dataclass(frozen=True)
class Detection:
    """The object found in one frame.

    Attributes:
        index: the frame's index.
        box: (x, y, w, h) tight box of the object's blob.
        mask: (H, W) bool, the blob.
        others: how many other blobs could have been the object (at least a quarter of its
            area, within the track's gate): another fast mover, which is not tracked.
        colour: the blob's chromaticity (:func:`blob_colour`), when the frame was given.
    """

    index: int
    box: Box
    mask: torch.Tensor
    others: int = 0
    colour: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Prediction:
    """Where a tracked object should appear: the (u, v) pixel centre of its next exposure's
    streak, its apparent diameter in pixels, and its track's chromaticity (of its blobs so far)."""

    centre: tuple[float, float]
    diameter: float
    colour: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class FrameStatus:
    """What happened to one frame: ``fitted``, ``no_object`` or ``failed`` (with the reason),
    and for a fitted frame, the number of its track (0, 1, ... in the order tracks start)."""

    index: int
    status: str
    box: tuple[int, int, int, int] | None = None
    note: str = ""
    track: int | None = None


Window = tuple[int, list[int]]
"""A window: its track's number and its frame indices, consecutive."""
