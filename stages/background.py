"""Stage 2, background: pair every frame with the static scene behind the moving object.

Three sources, as the paper and users need them:
- ``running``: the per-pixel median of the K frames before this one (paper: K = 5). The first
  K frames have no K predecessors; they take the median of the other frames among the first
  K + 1, so the clip's start gets a background too. Only K + 1 frames are held in memory.
- ``global``: the median of frames spread evenly over the whole clip (a first pass reads them);
  for a camera that never moves and objects that never rest.
- a user-supplied image.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from itertools import chain, islice
from pathlib import Path

import torch

from sfb_video.config import VideoConfig
from sfb_video.errors import ConfigError, SfbError
from sfb_video.imageio import as_float, read_image
from sfb_video.stages.read import read_frames
from sfb_video.stages.types import Frame, FrameWithBackground
from sfb_video.timing import timed, timed_iter

MEDIAN_BAND_VALUES = 1 << 22
"""The per-pixel median is taken a band of rows at a time, over about this many values of the
stacked frames, so that a 4K clip's stack is never whole in memory."""


def _median(images: list[torch.Tensor]) -> torch.Tensor:
    """(3, H, W) per-pixel median of (3, H, W) frames, in their dtype (torch takes the lower
    middle value of an even count, so a uint8 median is exactly the float one, scaled)."""
    first = images[0]
    out = torch.empty_like(first)
    rows = max(1, MEDIAN_BAND_VALUES // (len(images) * first.shape[0] * first.shape[2]))
    for top in range(0, first.shape[1], rows):
        band = torch.stack([image[:, top : top + rows] for image in images])
        out[:, top : top + rows] = band.median(dim=0).values
    return out


def running_median(frames: Iterable[Frame], window: int) -> Iterator[FrameWithBackground]:
    """Pair each frame with the median of the ``window`` frames before it (see module docstring)."""
    if window < 1:
        raise ConfigError(f"video.background_window must be at least 1, got {window}")
    stream = iter(frames)
    head = list(islice(stream, window + 1))
    if len(head) < 2:
        raise SfbError("a running-median background needs at least 2 frames; give a background image instead")
    for frame in head[:window]:
        others = [f.image for f in head if f is not frame]
        yield FrameWithBackground(frame.index, frame.image, _median(others))
    previous = deque((f.image for f in head[:window]), maxlen=window)
    for frame in chain(head[window:], stream):
        yield FrameWithBackground(frame.index, frame.image, _median(list(previous)))
        previous.append(frame.image)


@timed("background")
def global_median(path: Path, samples: int, frame_count: int | None) -> torch.Tensor:
    """(3, H, W) float32 median of up to ``samples`` frames spread evenly over the clip at ``path``."""
    if samples < 1:
        raise ConfigError(f"video.global_samples must be at least 1, got {samples}")
    if frame_count is None:
        frame_count = sum(1 for _ in read_frames(path))
    step = max(1, frame_count // samples)
    # Deep sources are quantised to 8 bits here: 25 float frames of 4K would take 2.5 GB.
    kept = [_quantised(f.image) for f in read_frames(path) if f.index % step == 0]
    return as_float(_median(kept[:samples]))


def _quantised(image: torch.Tensor) -> torch.Tensor:
    return image if image.dtype == torch.uint8 else image.mul(255).round_().to(torch.uint8)


def fixed_background(frames: Iterable[Frame], background: torch.Tensor) -> Iterator[FrameWithBackground]:
    """Pair every frame with one given background image."""
    for frame in frames:
        if frame.image.shape != background.shape:
            raise SfbError(
                f"the background is {background.shape[2]}x{background.shape[1]} but the frames are "
                f"{frame.image.shape[2]}x{frame.image.shape[1]}"
            )
        yield FrameWithBackground(frame.index, frame.image, background)


def with_backgrounds(
    path: Path,
    config: VideoConfig,
    frame_count: int | None,
    frames: range | None = None,
    background: Path | None = None,
) -> Iterator[FrameWithBackground]:
    """The frames of ``path`` (those in ``frames`` when given) with their backgrounds.

    Args:
        background: a background image; without it ``config.background`` says how to estimate one.
    """
    stream = read_frames(path, frames)
    if background is not None:
        return timed_iter("background", fixed_background(stream, read_image(background)))
    if config.background == "running":
        if frames is None:
            return timed_iter("background", running_median(stream, config.background_window))
        # The frames around the range make its backgrounds, as in a run over the whole clip: a
        # short range alone has too few frames for a median without the object.
        window = config.background_window
        wider = range(max(0, frames.start - window), max(frames.stop, frames.start + window + 1))
        ranged = (f for f in running_median(read_frames(path, wider), window) if f.index in frames)
        return timed_iter("background", ranged)
    if config.background == "global":
        return timed_iter(
            "background", fixed_background(stream, global_median(path, config.global_samples, frame_count))
        )
    raise ConfigError(f"video.background must be 'running' or 'global', got {config.background!r}")
