"""The recording's AV1 video streams: one sample per image, in BT.709, a keyframe that decodes
alone every KEYFRAME_INTERVAL samples, the same bytes every time."""

from __future__ import annotations

import av
import numpy as np

from sfb_video.recording.video_stream import KEYFRAME_INTERVAL, VideoEncoder


def _images(count: int) -> list[np.ndarray]:
    """(48, 64, 3) uint8 frames: a saturated red square moving over a smooth gradient."""
    v, u = np.meshgrid(np.linspace(0, 1, 48), np.linspace(0, 1, 64), indexing="ij")
    background = (np.stack((0.2 + 0.6 * u, 0.8 - 0.5 * v, 0.3 + 0.2 * u * v), -1) * 255).astype(np.uint8)
    frames = []
    for i in range(count):
        frame = background.copy()
        frame[16:32, 4 + i % 40 : 20 + i % 40] = (220, 30, 40)
        frames.append(frame)
    return frames


def _decode(samples: list[bytes]) -> list[av.VideoFrame]:
    decoder = av.CodecContext.create("libdav1d", "r")
    frames = [f for sample in samples for f in decoder.decode(av.Packet(sample))]
    return frames + list(decoder.decode(None))


def test_each_image_is_one_sample_and_decodes_to_itself_in_bt709() -> None:
    images = _images(4)
    encoder = VideoEncoder(64, 48)
    samples = [encoder.encode(image) for image in images]
    encoder.close()
    assert [keyframe for _, keyframe in samples] == [True, False, False, False]
    frames = _decode([sample for sample, _ in samples])
    assert len(frames) == 4
    for i, (frame, image) in enumerate(zip(frames, images, strict=True)):
        # Tagged BT.709 (1), limited range (1): rerun's decoders read an untagged sample as BT.709
        # while swscale had converted it as BT.601, shifting the red square's colour.
        assert (frame.colorspace, frame.color_range) == (1, 1)
        rgb = frame.reformat(format="rgb24", src_colorspace="ITU709").to_ndarray()
        assert np.abs(rgb[18:30, :].astype(float) - image[18:30, :]).mean() < 6.0
        square = rgb[20:28, 8 + i % 40 : 16 + i % 40].reshape(-1, 3)
        assert np.abs(square.mean(0) - (220, 30, 40)).max() < 8.0


def test_a_later_keyframe_decodes_alone_and_the_bytes_repeat() -> None:
    # The viewer seeks by decoding from the last keyframe before the time shown: each keyframe
    # must carry its sequence header.
    images = _images(KEYFRAME_INTERVAL + 3)
    runs = []
    for _ in range(2):
        encoder = VideoEncoder(64, 48)
        runs.append([encoder.encode(image) for image in images])
        encoder.close()
    assert runs[0] == runs[1]
    keyframes = [i for i, (_, keyframe) in enumerate(runs[0]) if keyframe]
    assert keyframes[0] == 0 and len(keyframes) >= 2 and keyframes[1] <= KEYFRAME_INTERVAL
    later = _decode([sample for sample, _ in runs[0][keyframes[1] :]])
    assert len(later) == len(images) - keyframes[1]
    first = later[0].reformat(format="rgb24", src_colorspace="ITU709").to_ndarray()
    assert np.abs(first.astype(float) - images[keyframes[1]]).mean() < 6.0
