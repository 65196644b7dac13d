"""Stage 1, read: a video file -> its description and a stream of frames.

Frames are decoded one at a time (memory does not grow with the clip) and kept compact: 8-bit
sources as uint8, deeper ones as float32 in [0, 1] (``sfb_video.imageio.as_float`` turns either
into float); grayscale sources come out as RGB.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from sfb_video.config import VideoConfig
from sfb_video.errors import SfbError
from sfb_video.stages.types import Frame
from sfb_video.timing import timed_iter
from sfb_video.video import VideoInfo, VideoReader

MIN_SIDE = 16
"""Frames smaller than this on a side cannot hold a streak and an object box around it."""


def probe(path: Path, config: VideoConfig) -> VideoInfo:
    """Open ``path``, check its frame size and return its description without decoding it.

    Raises:
        SfbError: missing or unreadable file, frames too small or too large.
    """
    with VideoReader(path) as reader:
        info = reader.info
    if min(info.width, info.height) < MIN_SIDE:
        raise SfbError(f"{path}: frames of {info.width}x{info.height} are too small (at least {MIN_SIDE} px a side)")
    if max(info.width, info.height) > config.max_side:
        raise SfbError(
            f"{path}: frames of {info.width}x{info.height} exceed video.max_side={config.max_side}; "
            "downscale the clip or raise the limit"
        )
    return info


def read_frames(path: Path, frames: range | None = None) -> Iterator[Frame]:
    """Decode the frames of ``path`` in order, those in ``frames`` only when it is given.

    Raises:
        SfbError: when the file cannot be decoded or holds no frame.
    """
    return timed_iter("read", _decode(path, frames))


def _decode(path: Path, frames: range | None) -> Iterator[Frame]:
    with VideoReader(path, compact=True) as reader:
        for index, image in enumerate(reader):
            if frames is not None and index >= frames.stop:
                return
            if frames is None or index in frames:
                yield Frame(index, image)
