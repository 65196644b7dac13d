"""Streaming video input and H.264 output for the video pipeline, through PyAV.

:class:`VideoReader` decodes a clip one frame at a time as (3, H, W) float32 RGB tensors in [0, 1]
(grayscale as three equal channels, high-bit-depth sources at 16-bit precision), so a long clip is
never held in memory. :class:`VideoWriter` encodes frames to an H.264 ``.mp4`` written atomically,
like :mod:`sfb_video.imageio`: the output either is complete or is not there. Every failure a user
can cause (missing, corrupt or empty files, unwritable folders) is an :class:`SfbError` naming the file.
"""

from __future__ import annotations

import contextlib
import functools
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from types import TracebackType

import av
import numpy as np
import torch

from sfb_video.atomic import AtomicOutput, output_error, temporary_sibling
from sfb_video.errors import OutputError, SfbError, check_shape
from sfb_video.imageio import to_uint8

# The frame rate reported when FFmpeg gives none (average, guessed and base rates all unset).
DEFAULT_FPS = 30.0
# x264 holds its lookahead (40 frames) in every frame thread: 1.7 GB for 4K frames. Above 1080p
# one frame of lookahead and one B-frame on two threads keep it near 0.3 GB (0.5 with five and
# three B-frames). The cost, on a 4K run's sub-frames at crf 18: 45.6 dB to them instead of
# 47.4, at 60% of the size; no cost in speed measured on 2 cores.
_LARGE_FRAME = 1920 * 1080
_LARGE_FRAME_OPTIONS = {"rc-lookahead": "1", "bf": "1", "threads": "2"}
# Without cpu-independent, x264's output depended on what the process had freed before encoding
# (some of its CPU-specific routines seem to read memory they never wrote): the same frames in two
# processes decoded up to 3 levels apart in a few blocks, so a generated clip (the demo's, the
# benchmarks') and every score measured on it changed between runs. With it, one file every time.
X264_PARAMS = "cpu-independent=1"

OUTPUT_PRESET = "veryfast"
"""x264's preset for the videos a run writes (tsr.mp4, novel views): 240 frames of 640x480
encode in 0.62 s against 1.5 s with ``medium``, and the file is smaller at the same crf."""


@dataclass(frozen=True)
class VideoInfo:
    """What the container says about a clip's video stream.

    Attributes:
        path: the file.
        width, height: frame size in pixels.
        fps: frames per second, the stream's average rate; :data:`DEFAULT_FPS` (30.0) when FFmpeg
            reports no rate at all. Note that FFmpeg itself reports its guess of 25 for sources
            without timing (raw .h264 streams, still images), so check fps for such inputs.
        frame_count: number of frames, or ``None`` when the container does not record it (e.g.
            Matroska); the reader's count of decoded frames is then the only truth.
    """

    path: Path
    width: int
    height: int
    fps: float
    frame_count: int | None


def _reason(error: BaseException) -> str:
    """FFmpeg's description of an error without its errno and file name (our messages name the file)."""
    return getattr(error, "strerror", None) or str(error) or type(error).__name__


@functools.cache
def _is_deep(pix_fmt: str) -> bool:
    """Whether a pixel format stores more than 8 bits per component (yuv420p10le, gray16le, ...)."""
    return max(c.bits for c in av.VideoFormat(pix_fmt).components) > 8


def _to_tensor(frame: av.VideoFrame, compact: bool = False) -> torch.Tensor:
    """A decoded frame -> (3, H, W) float32 RGB in [0, 1]; > 8-bit sources go through rgb48le to
    keep precision. ``compact``: 8-bit sources stay (3, H, W) uint8 (a quarter of the memory)."""
    if _is_deep(frame.format.name):
        rgb, scale = frame.to_ndarray(format="rgb48le"), 65535.0
    else:
        rgb, scale = frame.to_ndarray(format="rgb24"), 255.0
        if compact:
            return torch.from_numpy(np.ascontiguousarray(rgb.transpose(2, 0, 1)))
    chw = np.ascontiguousarray(rgb.transpose(2, 0, 1), dtype=np.float32)
    chw /= scale
    return torch.from_numpy(chw)


class VideoReader:
    """Decode the first video stream of a file, one frame at a time.

    Opening validates the file (exists, decodable container, has a video stream) and fills
    :attr:`info`; iterating yields frames in order, each a (3, H, W) float32 RGB tensor in [0, 1]
    (with ``compact``, 8-bit sources as (3, H, W) uint8: see :func:`sfb_video.imageio.as_float`). A reader streams
    its frames once: open a new one to read the clip again. Use it as a context manager (or call
    :meth:`close`) to release the file.

    Raises:
        SfbError: at opening, for a missing or undecodable file or one with no video stream;
            while iterating, for a decode error or a stream that yields no frame at all.
    """

    def __init__(self, path: str | Path, compact: bool = False) -> None:
        path = Path(path)
        self._compact = compact
        if not path.is_file():
            raise SfbError(f"not a video file: {path}" if path.exists() else f"video not found: {path}")
        try:
            container = av.open(str(path), metadata_errors="replace")
        except (av.FFmpegError, OSError) as e:
            raise SfbError(f"not a readable video: {path} ({_reason(e)})") from e
        if not container.streams.video:
            container.close()
            raise SfbError(f"no video stream in {path}")
        stream = container.streams.video[0]
        rate = next((r for r in (stream.average_rate, stream.guessed_rate, stream.base_rate) if r and r > 0), None)
        self.info = VideoInfo(
            path=path,
            width=stream.codec_context.width,
            height=stream.codec_context.height,
            fps=float(rate) if rate is not None else DEFAULT_FPS,
            frame_count=stream.frames if stream.frames > 0 else None,
        )
        self._container: av.container.InputContainer | None = container
        self._stream = stream
        self._started = False

    def __iter__(self) -> Iterator[torch.Tensor]:
        """Frames in display order, each (3, H, W) float32 RGB in [0, 1]."""
        if self._container is None:
            raise SfbError(f"the reader of {self.info.path} is closed")
        if self._started:
            raise SfbError(f"{self.info.path} is already being read: open a new VideoReader to read it again")
        self._started = True
        return self._frames(self._container)

    def _frames(self, container: av.container.InputContainer) -> Iterator[torch.Tensor]:
        decoded = container.decode(self._stream)
        count = 0
        while True:
            if self._container is None:
                raise SfbError(f"the reader of {self.info.path} was closed while reading")
            # Only the decoding is guarded: an exception raised by the caller's loop body never reaches here.
            try:
                frame = next(decoded)
            except StopIteration:
                break
            except (av.FFmpegError, OSError) as e:
                raise SfbError(f"cannot decode frame {count} of {self.info.path} ({_reason(e)})") from e
            yield _to_tensor(frame, self._compact)
            count += 1
        if count == 0:
            raise SfbError(f"{self.info.path} has no frames")

    def close(self) -> None:
        """Release the file; safe to call more than once."""
        if self._container is not None:
            self._container.close()
            self._container = None

    def __enter__(self) -> VideoReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


class VideoWriter(AtomicOutput):
    """Encode frames to an H.264 (libx264, yuv420p) ``.mp4``, atomically.

    Frames go to a hidden temporary file in the same folder (:func:`sfb_video.atomic.temporary_sibling`) that
    :meth:`close` renames onto ``path``, so an interrupted run never leaves a half-written ``path``
    and an existing file there is only replaced by a complete one. As a context manager it calls
    :meth:`close` on success and :meth:`abort` on any exception, KeyboardInterrupt included.

    yuv420p needs an even width and height: an odd size is padded by repeating the last column
    and/or row, so the file is then (width + 1) and/or (height + 1) pixels large.

    Args:
        path: the output file; must end in ``.mp4``, in a folder that exists.
        fps: frames per second, stored as a fraction (29.97 as 30000/1001).
        width, height: the size of the frames that :meth:`write` will get.
        crf: x264 constant rate factor, 0 (lossless) to 51; 18 is visually lossless.
        preset: x264's speed preset. ``veryfast`` encodes in 0.4x the time of the default
            ``medium`` at this crf (measured on 640x480 clips): the tool's own outputs use it;
            clips made as inputs keep ``medium``, which is what their fits were measured on.

    Raises:
        SfbError: for invalid arguments or a folder that cannot be written.
    """

    def __init__(
        self, path: str | Path, fps: float, width: int, height: int, crf: int = 18, preset: str = "medium"
    ) -> None:
        path = Path(path)
        if path.suffix.lower() != ".mp4":
            raise SfbError(f"a video output must be an .mp4 file: {path}")
        if not (math.isfinite(fps) and fps > 0):
            raise SfbError(f"fps must be positive, got {fps} for {path}")
        if width <= 0 or height <= 0:
            raise SfbError(f"frame size must be positive, got {width}x{height} for {path}")
        if not 0 <= crf <= 51:
            raise SfbError(f"crf must be in [0, 51], got {crf} for {path}")
        if path.is_dir():
            raise SfbError(f"video output is a folder: {path}")
        self.path = path
        self.width, self.height = width, height
        self.frames_written = 0
        self._container: av.container.OutputContainer | None = None
        # FFmpeg only creates its file at the first frame: creating it here reports an unwritable
        # folder now.
        self._tmp = temporary_sibling(path, ".mp4")
        try:
            self._container = av.open(str(self._tmp), "w", format="mp4")
            self._stream = self._container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
            self._stream.width, self._stream.height = width + width % 2, height + height % 2
            self._stream.pix_fmt = "yuv420p"
            options = {"crf": str(crf), "preset": preset, "x264-params": X264_PARAMS}
            self._stream.options = options | (_LARGE_FRAME_OPTIONS if width * height > _LARGE_FRAME else {})
        except (av.FFmpegError, OSError) as e:
            self.abort()
            raise SfbError(f"cannot start encoding {path} ({_reason(e)})") from e

    def write(self, frame: torch.Tensor | np.ndarray) -> None:
        """Append a frame: a (3, H, W) float tensor in [0, 1] or an (H, W, 3) uint8 RGB array.

        Raises:
            OutputError: the frame cannot be written (a full disk) or encoded; the writer is
                aborted then (its temporary file removed).
        """
        if self._container is None:
            raise SfbError(f"cannot write to {self.path}: the writer is closed")
        if isinstance(frame, torch.Tensor):
            check_shape(frame, (3, self.height, self.width), "video frame")
            rgb = to_uint8(frame)
        elif frame.shape != (self.height, self.width, 3) or frame.dtype != np.uint8:
            raise SfbError(
                f"a video frame array must be ({self.height}, {self.width}, 3) uint8, got {frame.shape} {frame.dtype}"
            )
        else:
            rgb = frame
        if self.width % 2 or self.height % 2:
            rgb = np.pad(rgb, ((0, self.height % 2), (0, self.width % 2), (0, 0)), mode="edge")
        try:
            self._container.mux(self._stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), "rgb24")))
        except (av.FFmpegError, OSError) as e:
            self.abort()
            # A failed write (a full disk: PyAV raises an OSError with its errno) is named as
            # every output's is; anything else is the encoder's.
            if isinstance(e, OSError) and e.errno is not None:
                raise output_error(self.path, e) from None
            raise OutputError(f"cannot encode frame {self.frames_written} of {self.path} ({_reason(e)})") from None
        self.frames_written += 1

    def close(self) -> None:
        """Finish encoding and move the file onto ``path``; safe to call more than once.

        Raises:
            SfbError: if no frame was written (no file is left then) or encoding fails.
            OutputError: the file cannot be finished (a full disk: x264 hands over the frames it
                held, and the index is written last); no file is left then.
        """
        if self._container is None:
            return
        if self.frames_written == 0:
            self.abort()
            raise SfbError(f"no frames were written to {self.path}: not creating an empty video")
        try:
            self._container.mux(self._stream.encode(None))  # flush the frames x264 still holds
            self._container.close()
            self._container = None
            os.replace(self._tmp, self.path)
        except BaseException as e:
            self.abort()
            if isinstance(e, OSError):
                raise output_error(self.path, e) from None
            if isinstance(e, av.FFmpegError):
                raise OutputError(f"cannot finish writing {self.path} ({_reason(e)})") from None
            raise

    def abort(self) -> None:
        """Stop without output: remove the temporary file and leave ``path`` as it was."""
        container, self._container = self._container, None
        if container is not None:
            # The file is deleted anyway: a failure to finish it does not matter.
            with contextlib.suppress(av.FFmpegError, OSError):
                container.close()
        self._tmp.unlink(missing_ok=True)
