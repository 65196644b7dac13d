"""The types the stages hand each other: a decoded frame, a frame with its background, a
detection and a track's prediction, a frame's status after tracking, a joint window.

They live here, below every stage, so that a stage imports the types it is given without
importing the stage that makes them.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import torch

from sfb_video.crop import Box
from sfb_video.imageio import as_float
from sfb_video.results import FrameKey, WindowKey


@dataclass(frozen=True)
class Registered:
    """How a frame of a moving camera was brought into its reference's coordinates
    (:mod:`sfb_video.registration`).

    Attributes:
        to_canvas: (3, 3) the homography from the frame's pixels to its reference's canvas
            (:class:`sfb_video.registration.Canvas`); None where registration failed (the frame
            is not fitted, and shows only the background).
        original: (3, H, W) the frame as filmed, in the frame's dtype.
        covered: (h, w) bool, the canvas's pixels the frame covers (the rest repeat its
            border, and are not compared with the background).
        segment: which reference frame (a pan longer than the frame takes several).
        note: why registration failed.
        to_next: (3, 3) the frame's pixels to the next reference's canvas, where the camera
            panned on to one (None: the last reference, or a cut): the new reference's
            background starts from the frames before it.
    """

    to_canvas: np.ndarray | None
    original: torch.Tensor
    covered: torch.Tensor
    segment: int
    note: str = ""
    to_next: np.ndarray | None = None

    @property
    def failed(self) -> bool:
        return self.to_canvas is None


@dataclass(frozen=True)
class Frame:
    """One decoded frame.

    Attributes:
        index: position in the clip, from 0.
        image: (3, H, W) RGB: uint8 for 8-bit sources, else float32 in [0, 1]; in its
            reference's coordinates when ``registered``.
        registered: how it was registered, for a moving camera (None: a still one).
    """

    index: int
    image: torch.Tensor
    registered: Registered | None = None


@dataclass(frozen=True)
class FrameWithBackground:
    """A frame and its background.

    Attributes:
        index: the frame's position in the clip.
        pixels, background_pixels: (3, H, W) each, kept as compact as the source allows: uint8
            from an 8-bit clip (a 4K frame is 25 MB, not 100), else float32 in [0, 1]; in the
            reference's coordinates when ``registered`` (pixels it does not cover are the
            background's).
        registered: the frame's registration, for a moving camera.
        known: (H, W) bool the pixels compared with a background (None: all); a moving
            camera's frame is its background's elsewhere (what it does not cover, what no frame
            before it saw), so those pixels say nothing of its noise.
    """

    index: int
    pixels: torch.Tensor
    background_pixels: torch.Tensor
    registered: Registered | None = None
    known: torch.Tensor | None = None

    @property
    def image(self) -> torch.Tensor:
        """(3, H, W) float32 in [0, 1] (made on each access from compact pixels)."""
        return as_float(self.pixels)

    @property
    def background(self) -> torch.Tensor:
        """(3, H, W) float32 in [0, 1] (made on each access from compact pixels)."""
        return as_float(self.background_pixels)

    def without(self, region: torch.Tensor) -> FrameWithBackground:
        """This frame with its (H, W) bool ``region`` showing the background: other objects'
        pixels, which a fit of this one should not try to explain."""
        pixels, background = self.pixels, self.background_pixels
        if pixels.dtype != background.dtype:
            pixels, background = as_float(pixels), as_float(background)
        return dataclasses.replace(self, pixels=torch.where(region.to(pixels.device), background, pixels))


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
    streak, its apparent diameter in pixels, its track's chromaticity (of its blobs so far), and
    the (u, v) ends of the streak (where two tracks' streaks touch, their pixels are shared out
    by nearness to them), and whether it is a ``fallback``: followed only where the track's
    other guesses find no blob."""

    centre: tuple[float, float]
    diameter: float
    colour: tuple[float, float, float] | None = None
    ends: tuple[tuple[float, float], tuple[float, float]] | None = None
    fallback: bool = False


class Status(StrEnum):
    """What happened to one object of a frame, spelt as ``detections.json`` spells it."""

    FITTED = "fitted"
    NO_OBJECT = "no_object"
    FAILED = "failed"
    MERGED = "merged"  # its streak merged into another track's blob: the track coasts
    DROPPED = "dropped"  # its track was too short to keep


@dataclass(frozen=True)
class FrameStatus:
    """What happened to one frame: ``fitted``, ``no_object`` or ``failed`` (with the reason),
    and for a fitted frame, the number of its track (0, 1, ... in the order tracks start) and
    whether its streak ``touched`` another track's: their blob's pixels shared out by nearness
    (not where another track's streak merged whole into this one's blob: that track coasts)."""

    index: int
    status: Status
    box: tuple[int, int, int, int] | None = None
    note: str = ""
    track: int | None = None
    touched: bool = False

    def __post_init__(self) -> None:
        # A status read back from JSON is its spelling; a typo fails here, not in a comparison.
        object.__setattr__(self, "status", Status(self.status))

    @property
    def key(self) -> FrameKey | None:
        """The (frame, track) of its object, or None for a frame without a track."""
        return None if self.track is None else FrameKey(self.index, self.track)


@dataclass(frozen=True)
class Window:
    """A window of a track: its number and its frame indices, consecutive, that one joint fit
    covers (:func:`~sfb_video.stages.run_results.track_windows`)."""

    track: int
    frames: tuple[int, ...]

    @property
    def key(self) -> WindowKey:
        return WindowKey(self.track, self.frames[0])
