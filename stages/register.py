"""Stage 1b, register: a moving camera's frames brought into their reference frame's coordinates.

A first pass over the clip registers every frame (:func:`sfb_video.registration.register_frames`,
transforms only); the frames are then warped one at a time as they stream to the background,
so memory stays flat. A still camera's frames pass as they are.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

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
    """``frames`` in their reference's coordinates. One that did not register comes as it is,
    covering nothing of its reference (it shows only the background, and is not fitted)."""
    for frame in frames:
        if motion is None:
            yield frame
            continue
        found = motion.of(frame.index)
        if found is None:
            raise SfbError(f"frame {frame.index} is not in the clip's registration (camera_motion.json is stale)")
        if found.to_reference is None:
            nothing = torch.zeros(frame.image.shape[1:], dtype=torch.bool)
            yield Frame(frame.index, frame.image, Registered(None, frame.image, nothing, found.segment, found.note))
            continue
        image, covered = warp(frame.image, found.to_reference)
        yield Frame(frame.index, image, Registered(found.to_reference, frame.image, covered, found.segment))


def segment_of(frame: Frame | FrameWithBackground) -> int:
    """The reference a frame is registered to (0 for a still camera)."""
    return 0 if frame.registered is None else frame.registered.segment


def usable(frame: Frame | FrameWithBackground) -> bool:
    """Whether a frame shows the scene in its reference's coordinates (a still camera's always)."""
    return frame.registered is None or not frame.registered.failed
