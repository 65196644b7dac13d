"""The recording's images as AV1 video samples (rerun's ``VideoStream``), one encoder per stream.

A JPEG per image made the recording 1.8 MB a frame at 1920x1080 (a frame logs the input, the
background, the reconstruction and every TSR sub-frame); most of each image repeats the one
before, which a video codec does not store again. AV1, because rerun's native viewer decodes it
itself (H.264 needs an FFmpeg on the PATH there) and every browser's WebCodecs does too.

SVT-AV1 runs in its low-delay structure: each frame goes in and comes out as one sample at once,
in display order, so a sample is logged at its own frame's time; on one thread (``lp=1``), which
keeps its bytes the same run to run (it holds about 50 MB at 1920x1080, 200 MB at 3840x2160).
The colours are converted and tagged as BT.709 (limited range): untagged, the samples were
converted by swscale's BT.601 and read by rerun's decoders as BT.709, shifting saturated
colours.
"""

from __future__ import annotations

import os
from fractions import Fraction

import av
import numpy as np

from sfb_video.errors import SfbError

ENCODER = "libsvtav1"
PRESET = "12"
"""SVT-AV1's fastest preset: 13 ms a 1920x1080 frame on one core, against 10 for a JPEG."""
CRF = 30
"""43 dB PSNR on real clips scaled to 1080p, at 3 KB a frame after the first (a JPEG at quality
90: 50 dB, 96 KB)."""
KEYFRAME_INTERVAL = 60
"""Samples between keyframes: the viewer decodes from the last keyframe before the time shown."""
PARAMS = f"pred-struct=1:lp=1:keyint={KEYFRAME_INTERVAL}"

# SVT-AV1 prints its configuration to stderr at every encoder's start unless told errors only.
os.environ.setdefault("SVT_LOG", "1")


class VideoEncoder:
    """Encodes one stream's images, each to the AV1 sample that shows it.

    Args:
        width, height: the images' size in pixels.

    Raises:
        SfbError: when this PyAV lacks the SVT-AV1 encoder.
    """

    def __init__(self, width: int, height: int) -> None:
        if ENCODER not in av.codecs_available:
            raise SfbError(f"this PyAV has no {ENCODER} encoder, which the recording needs (pip install -U av)")
        self._context = av.CodecContext.create(ENCODER, "w")
        self._context.width, self._context.height = width, height
        self._context.pix_fmt = "yuv420p"
        self._context.time_base = Fraction(1, 30)  # samples are placed on rerun's timelines, not by this
        # BT.709 primaries, transfer and matrix, limited range, in the sequence header.
        self._context.colorspace = self._context.color_primaries = self._context.color_trc = 1
        self._context.color_range = 1
        self._context.options = {"preset": PRESET, "crf": str(CRF), "svtav1-params": PARAMS}
        self._count = 0

    def encode(self, pixels: np.ndarray) -> tuple[bytes, bool]:
        """The sample of (H, W, 3) uint8 RGB ``pixels``, and whether it is a keyframe.

        Raises:
            SfbError: when the encoder held the frame back instead of returning its sample.
        """
        rgb = av.VideoFrame.from_ndarray(np.ascontiguousarray(pixels), format="rgb24")
        frame = rgb.reformat(format="yuv420p", dst_colorspace="ITU709")
        frame.pts = self._count
        packets = self._context.encode(frame)
        self._count += 1
        if len(packets) != 1:
            raise SfbError(f"the {ENCODER} encoder returned {len(packets)} samples for one image, expected 1")
        return bytes(packets[0]), bool(packets[0].is_keyframe)

    def close(self) -> None:
        """Let the encoder go (it has nothing left to give: every frame came out at once). An
        encoder that never encoded is left alone: flushing would open it."""
        if self._count:
            self._context.encode(None)
