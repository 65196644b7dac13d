"""Stage 1b, register: a moving camera's frames brought into their reference frame's coordinates.

A first pass over the clip registers every frame (:func:`sfb_video.registration.register_frames`,
transforms only); the frames are then warped one at a time as they stream to the background,
so memory stays flat. A still camera's frames pass as they are.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import cv2
import numpy as np
import torch

from sfb_video.config import CameraConfig
from sfb_video.errors import SfbError
from sfb_video.registration import CameraMotion, register_frames, warp
from sfb_video.stages.read import read_frames
from sfb_video.stages.types import Frame, FrameWithBackground, Registered
from sfb_video.timing import timed


@timed("register")
def camera_motion(path: Path, frames: range | None, config: CameraConfig) -> CameraMotion | None:
    """The camera's motion over the frames of ``path`` that a run reads (``frames``, or all),
    or None when ``camera.motion`` is ``off`` or, with ``auto``, the camera held still."""
    if config.motion == "off":
        return None
    motion = register_frames(((f.index, f.image) for f in read_frames(path, frames)), config)
    return motion if motion.moving or config.motion == "on" else None


def registered(frames: Iterable[Frame], motion: CameraMotion | None) -> Iterator[Frame]:
    """``frames`` drawn on their reference's canvas. One that did not register is drawn where
    its reference was, covering nothing (it shows only the background, and is not fitted)."""
    for frame in frames:
        if motion is None:
            yield frame
            continue
        found = motion.of(frame.index)
        if found is None:
            raise SfbError(f"frame {frame.index} is not in the clip's registration (camera_motion.json is stale)")
        canvas = motion.canvas
        size = None if canvas is None else (canvas.width, canvas.height)
        to_canvas = motion.to_canvas(found)
        if to_canvas is None:
            image, _ = warp(frame.image, np.eye(3) if canvas is None else canvas.shift, size)
            nothing = torch.zeros(image.shape[1:], dtype=torch.bool)
            yield Frame(frame.index, image, Registered(None, frame.image, nothing, found.segment, found.note))
            continue
        image, covered = warp(frame.image, to_canvas, size)
        to_next = motion.to_next_canvas(found)
        yield Frame(frame.index, image, Registered(to_canvas, frame.image, covered, found.segment, to_next=to_next))


def onto_next(frame: Frame) -> Frame | None:
    """A registered ``frame`` drawn on the next reference's canvas instead of its own, where
    the camera panned on to one (:attr:`Registered.to_next`); else None."""
    found = frame.registered
    if found is None or found.to_next is None:
        return None
    height, width = frame.image.shape[1:]
    image, covered = warp(found.original, found.to_next, (width, height))
    return Frame(frame.index, image, Registered(found.to_next, found.original, covered, found.segment + 1))


def mask_onto_next(frame: Frame | FrameWithBackground, mask: torch.Tensor) -> torch.Tensor | None:
    """A registered ``frame``'s (h, w) bool ``mask`` on its canvas, drawn on the next
    reference's canvas where the camera panned on to one; else None."""
    found = frame.registered
    if found is None or found.to_next is None or found.to_canvas is None:
        return None
    between = found.to_next @ np.linalg.inv(found.to_canvas)
    height, width = mask.shape
    moved = cv2.warpPerspective(mask.cpu().numpy().astype(np.uint8), between, (width, height), flags=cv2.INTER_NEAREST)
    return torch.from_numpy(moved > 0)


def onto_canvas(image: torch.Tensor, motion: CameraMotion | None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """A (3, H, W) image of the first reference's view (a background image) drawn on the
    canvas the registered frames are, and the (h, w) bool canvas pixels it shows (None: all;
    its border is repeated into the margin)."""
    if motion is None or motion.canvas is None:
        return image, None
    canvas = motion.canvas
    return warp(image, canvas.shift, (canvas.width, canvas.height))


def segment_of(frame: Frame | FrameWithBackground) -> int:
    """The reference a frame is registered to (0 for a still camera)."""
    return 0 if frame.registered is None else frame.registered.segment


def usable(frame: Frame | FrameWithBackground) -> bool:
    """Whether a frame shows the scene in its reference's coordinates (a still camera's always)."""
    return frame.registered is None or not frame.registered.failed
