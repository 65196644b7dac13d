"""Small media files the tests build."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np


def write_keyframeless(path: Path) -> Path:
    """An H.264 ``.mkv`` missing its keyframe: the container and stream are valid, but a decoder
    outputs nothing (it waits for a keyframe) and reports no error either. Zero decodable frames
    cannot be made otherwise: FFmpeg writes no file for an encoder that got no frame."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        packets = []
        for i in range(5):
            packets += stream.encode(av.VideoFrame.from_ndarray(np.full((48, 64, 3), 40 * i, np.uint8), "rgb24"))
        packets += stream.encode(None)
        assert packets[0].is_keyframe
        container.mux(packets[1:])
    return path
