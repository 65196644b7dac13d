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
from collections.abc import Generator, Iterable, Iterator
from itertools import groupby, islice
from pathlib import Path

import torch

from sfb_video.config import VideoConfig
from sfb_video.errors import ConfigError, SfbError
from sfb_video.imageio import as_float, read_image
from sfb_video.registration import CameraMotion
from sfb_video.stages.read import read_frames
from sfb_video.stages.register import onto_canvas, onto_next, registered, segment_of, usable
from sfb_video.stages.types import Frame, FrameWithBackground
from sfb_video.timing import timed, timed_iter

MEDIAN_BAND_VALUES = 1 << 22
"""The per-pixel median is taken a band of rows at a time, over about this many values of the
stacked frames, so that a 4K clip's stack is never whole in memory."""


def lower_median(values: list[torch.Tensor]) -> torch.Tensor:
    """The element-wise lower middle of ``values`` (tensors of one shape), as ``torch.median``
    over a stacked first dimension gives it: the list sorted element-wise by an odd-even
    transposition network of minima and maxima. For a background's few frames this is about
    ten times faster than ``torch.median``, which sorts each pixel's few values on its own."""
    ordered = list(values)
    n = len(ordered)
    for sweep in range(n):
        for j in range(sweep % 2, n - 1, 2):
            a, b = ordered[j], ordered[j + 1]
            ordered[j], ordered[j + 1] = torch.minimum(a, b), torch.maximum(a, b)
    return ordered[(n - 1) // 2]


def _median(images: list[torch.Tensor], covers: list[torch.Tensor | None] | None = None) -> torch.Tensor:
    """(3, H, W) per-pixel median of (3, H, W) frames, in their dtype (torch takes the lower
    middle value of an even count, so a uint8 median is exactly the float one, scaled).

    ``covers``: per frame the (H, W) bool pixels it saw (a registered frame's), or None for all;
    a pixel's median is then of the frames that saw it (of all, where none did).
    """
    first = images[0]
    out = torch.empty_like(first)
    masked = covers is not None and any(c is not None for c in covers)
    rows = max(1, MEDIAN_BAND_VALUES // (len(images) * first.shape[0] * first.shape[2]))
    for top in range(0, first.shape[1], rows):
        plain = lower_median([image[:, top : top + rows] for image in images])
        if masked:
            assert covers is not None
            band = torch.stack([image[:, top : top + rows] for image in images])
            seen = torch.stack(
                [torch.ones_like(band[0, 0], dtype=torch.bool) if c is None else c[top : top + rows] for c in covers]
            )
            values = band.float().masked_fill(~seen[:, None], float("nan")).nanmedian(dim=0).values
            filled = torch.where(values.isnan(), plain.float(), values)
            plain = filled.round().to(first.dtype) if first.dtype == torch.uint8 else filled.to(first.dtype)
        out[:, top : top + rows] = plain
    return out


def _cover(frame: Frame) -> torch.Tensor | None:
    return None if frame.registered is None else frame.registered.covered


def _seen(frames: list[Frame]) -> torch.Tensor | None:
    """(H, W) bool the reference's pixels at least one of ``frames`` saw (None: all of them)."""
    covers = [_cover(f) for f in frames]
    if not covers or any(c is None for c in covers):
        return None
    return torch.stack(covers).any(dim=0)


def _paired(frame: Frame, background: torch.Tensor, seen: torch.Tensor | None = None) -> FrameWithBackground:
    """``frame`` with its ``background``; a registered frame's pixels outside what it covers of
    its reference (a repeated border) are the background's, and the background's pixels that
    no frame behind it ``seen`` are the frame's (a pan's newly seen strip), so that nothing
    shows where nothing is known."""
    pixels, known = frame.image, None
    if frame.registered is not None:
        if pixels.dtype != background.dtype:  # an 8-bit frame over a float background image
            pixels, background = as_float(pixels), as_float(background)
        known = frame.registered.covered
        if seen is not None:
            background = torch.where(seen, background, pixels)
            known = known & seen
        pixels = torch.where(frame.registered.covered, pixels, background)
    return FrameWithBackground(frame.index, pixels, background, frame.registered, known)


def running_median(frames: Iterable[Frame], window: int) -> Iterator[FrameWithBackground]:
    """Pair each frame with the median of the ``window`` frames before it (see module docstring).

    A moving camera's frames are taken a reference (a segment) at a time: a new reference's
    frames start a background of their own, and a frame that did not register is no part of
    any (it shows nothing of the reference's scene).
    """
    if window < 1:
        raise ConfigError(f"video.background_window must be at least 1, got {window}")
    stream = iter(frames)
    head = list(islice(stream, 2))
    if len(head) < 2:
        raise SfbError("a running-median background needs at least 2 frames; give a background image instead")
    carried: list[Frame] = []
    for _, group in groupby(_handed_on(head, stream), key=segment_of):
        last: deque[Frame] = deque(maxlen=window)
        yield from _running_median(_kept(group, last), window, carried)
        # A camera that pans on to a new reference: its first frames' background starts from
        # the last frames before it, drawn there, not from a few frames of its own (in which a
        # slow object leaves a ghost).
        carried = [moved for moved in map(onto_next, last) if moved is not None]


def _handed_on(head: list[Frame], stream: Iterator[Frame]) -> Iterator[Frame]:
    """The frames of ``head`` (emptied as they pass), then ``stream``'s: no list of the clip's
    first frames outlives them (``chain`` keeps its arguments: 4K frames are 25 MB each)."""
    head.reverse()
    while head:
        yield head.pop()
    yield from stream


def _kept(frames: Iterable[Frame], last: deque[Frame]) -> Iterator[Frame]:
    """``frames``, keeping the usable ones in ``last`` as they pass."""
    for frame in frames:
        if usable(frame):
            last.append(frame)
        yield frame


def _running_median(frames: Iterable[Frame], window: int, carried: list[Frame]) -> Iterator[FrameWithBackground]:
    stream = iter(frames)
    if len(carried) < window:
        head = list(islice(stream, window + 1))
        seen = carried + [f for f in head if usable(f)]
        for frame in head[:window]:
            others = [f for f in seen if f is not frame]
            # A reference seen by one frame only has nothing to compare with: no difference.
            background = _median([f.image for f in others], [_cover(f) for f in others]) if others else frame.image
            yield _paired(frame, background, _seen(others))
        previous = deque(carried + [f for f in head[:window] if usable(f)], maxlen=window)
        # The first frames leave as the window moves on, not kept to the clip's end by these.
        rest, head, seen, others = head[window:], [], [], []
    else:
        rest, previous = [], deque(carried, maxlen=window)
    for frame in _handed_on(rest, stream):
        known = list(previous)
        background = _median([f.image for f in known], [_cover(f) for f in known]) if known else frame.image
        yield _paired(frame, background, _seen(known))
        if usable(frame):
            previous.append(frame)


@timed("background")
def global_median(
    path: Path, samples: int, frame_count: int | None, motion: CameraMotion | None = None
) -> torch.Tensor:
    """(3, H, W) float32 median of up to ``samples`` frames spread evenly over the clip at
    ``path`` (registered by ``motion`` when the camera moves)."""
    if samples < 1:
        raise ConfigError(f"video.global_samples must be at least 1, got {samples}")
    if frame_count is None:
        frame_count = sum(1 for _ in read_frames(path))
    step = max(1, frame_count // samples)
    # Deep sources are quantised to 8 bits here: 25 float frames of 4K would take 2.5 GB.
    sampled = (f for f in read_frames(path) if f.index % step == 0)
    kept = [f for f in registered(sampled, motion) if usable(f)][:samples]
    if not kept:
        raise SfbError(
            f"{path}: no frame registered with the first for a global background; use video.background=running"
        )
    return as_float(_median([_quantised(f.image) for f in kept], [_cover(f) for f in kept]))


def _quantised(image: torch.Tensor) -> torch.Tensor:
    return image if image.dtype == torch.uint8 else image.mul(255).round_().to(torch.uint8)


def fixed_background(
    frames: Iterable[Frame], background: torch.Tensor, shown: torch.Tensor | None = None
) -> Iterator[FrameWithBackground]:
    """Pair every frame with one given background image, of which only the (H, W) bool pixels
    ``shown`` are known (None: all; see :func:`sfb_video.stages.register.onto_canvas`)."""
    for frame in frames:
        if frame.image.shape != background.shape:
            raise SfbError(
                f"the background is {background.shape[2]}x{background.shape[1]} but the frames are "
                f"{frame.image.shape[2]}x{frame.image.shape[1]}"
            )
        yield _paired(frame, background, shown)


def frames_read(frames: range | None, config: VideoConfig) -> range | None:
    """The frames a run over ``frames`` (all when None) reads: a running median's range takes
    the frames around it too, as in a run over the whole clip (a short range alone has too few
    frames for a median without the object); a global median reads the whole clip."""
    if config.background == "global":
        return None
    if frames is None or config.background != "running":
        return frames
    window = config.background_window
    return range(max(0, frames.start - window), max(frames.stop, frames.start + window + 1))


def with_backgrounds(
    path: Path,
    config: VideoConfig,
    frame_count: int | None,
    frames: range | None = None,
    background: Path | None = None,
    motion: CameraMotion | None = None,
) -> Generator[FrameWithBackground, None, None]:
    """The frames of ``path`` (those in ``frames`` when given) with their backgrounds; close it
    to let go of the frames it holds when stopping early.

    Args:
        background: a background image; without it ``config.background`` says how to estimate one.
        motion: a moving camera's registrations (:func:`sfb_video.stages.register.camera_motion`,
            over :func:`frames_read`): the frames are brought into their reference's
            coordinates first, and those that did not register are left out.
    """
    stream = registered(read_frames(path, frames), motion)
    if motion is not None and motion.references > 1 and background is not None:
        raise SfbError("the camera pans beyond its first view: a background image shows one view; leave it out")
    if background is not None:
        return timed_iter("background", fixed_background(stream, *onto_canvas(read_image(background), motion)))
    if config.background == "running":
        if frames is None:
            return timed_iter("background", running_median(stream, config.background_window))
        wide = registered(read_frames(path, frames_read(frames, config)), motion)
        ranged = (f for f in running_median(wide, config.background_window) if f.index in frames)
        return timed_iter("background", ranged)
    if config.background == "global":
        if motion is not None and motion.references > 1:
            raise SfbError("the camera pans beyond its first view: video.background=global needs one view; use running")
        return timed_iter(
            "background", fixed_background(stream, global_median(path, config.global_samples, frame_count, motion))
        )
    raise ConfigError(f"video.background must be 'running' or 'global', got {config.background!r}")
