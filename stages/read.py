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


def check_video(video: Path) -> None:
    """Raise :class:`SfbError` unless ``video`` names a file (whether it decodes is the reader's)."""
    if video.is_dir():
        raise SfbError(f"{video} is a folder, not a video file")
    if not video.exists():
        raise SfbError(f"video not found: {video}")


def parse_frames(text: str) -> tuple[int | None, int | None]:
    """A frame selection as (start, stop), Python-style: STOP excluded, negative counts from the
    end, either may be left out (``10:40``, ``:5``, ``-10:``, ``7``).

    Raises:
        SfbError: the text is not such a selection.
    """
    start, sep, stop = text.partition(":")
    try:
        first = int(start) if start.strip() else None
        last = (int(stop) if stop.strip() else None) if sep else (None if first is None else first + 1)
    except ValueError:
        raise SfbError(
            f"--frames must be START:STOP (frame indices, STOP excluded, negative from the end), got {text!r}"
        ) from None
    if not sep and first == -1:
        last = None  # "-1" alone: the last frame
    return first, last


def select_frames(text: str | None, frame_count: int | None) -> range | None:
    """The frames the selection ``text`` (:func:`parse_frames`) picks of a clip of
    ``frame_count`` frames (None: the clip records no length); None selects them all.

    Raises:
        SfbError: the selection is empty, or counts from the end of a clip that records no length.
    """
    if text is None:
        return None
    start, stop = parse_frames(text)
    if frame_count is None and ((start or 0) < 0 or (stop is not None and stop < 0)):
        raise SfbError(f"--frames {text}: the clip does not record its length; give indices from its start")
    if frame_count is not None:
        frames = range(*slice(start, stop).indices(frame_count))
    else:
        frames = range(start or 0, 2**62 if stop is None else stop)
    if len(frames) == 0:
        raise SfbError(
            f"--frames {text} selects no frames" + (f" of the {frame_count}-frame clip" if frame_count else "")
        )
    return frames
