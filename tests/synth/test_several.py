"""Several objects in one clip: a layer composited alone gives its own clip back, the nearer
object is in front, and mirrored, shifted and cut layers keep their truth with their pixels."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sfb_video.crop import mask_box
from sfb_video.synth import ClipSpec, generate_clip
from sfb_video.synth.several import cut, mirrored, several, shifted, take_layer

SPEC = ClipSpec(
    width=96,
    height=64,
    num_frames=3,
    num_subframes=2,
    sub_exposures=8,
    texture_size=16,
    size_px_range=(14.0, 16.0),
    speed_range=(1.0, 1.2),
    seed=3,
)


def test_one_layer_composited_alone_is_its_own_clip() -> None:
    clip = generate_clip(SPEC)
    alone = several(clip.scene.background, clip.camera, [take_layer(clip)], SPEC.noise_sigma, SPEC.seed)
    # Within one 8-bit level: the layer holds the clip's quantised sub-frames, not its floats.
    for k, truth in enumerate(clip.truth):
        assert np.abs(alone.subframes[k].astype(int) - truth.subframes).max() <= 1
        assert np.abs(alone.frames[k].astype(int) - clip.frames[k]).max() <= 1
    assert np.abs(alone.others(1, 0) * 255 - clip.scene.background).max() < 0.5  # nothing else in it


def test_the_nearer_object_is_in_front_whatever_the_order() -> None:
    ball = take_layer(generate_clip(SPEC))
    box = take_layer(generate_clip(dataclasses.replace(SPEC, shape="box", texture_style="checker")))
    near = dataclasses.replace(box, depth=ball.depth - 1.0)
    background = generate_clip(SPEC).scene.background
    camera = generate_clip(SPEC).camera
    for layers in ([ball, near], [near, ball]):
        clip = several(background, camera, layers, 0.0, 0)
        full = near.cover[1] > 0.99  # the box covers these pixels whole: only its light shows
        assert full.any()
        assert np.abs(clip.subframes[1][full].astype(float) / 255 - near.light[1][full]).max() < 1 / 255 + 1e-6


def test_mirrored_shifted_and_cut_layers_keep_their_truth_with_their_pixels() -> None:
    layer = take_layer(generate_clip(SPEC))
    moved = shifted(mirrored(layer), -3, 2)
    for k in range(SPEC.num_frames):
        assert mask_box((moved.cover[k] > 0).any(0)) == moved.boxes[k]
        x, y, w, h = layer.boxes[k]
        assert moved.boxes[k] == (SPEC.width - x - w - 3, y + 2, w, h)
        # The centre moves with the pixels: coverage's centroid and the true centre agree.
        v, u = np.nonzero(moved.cover[k].mean(0) > 0)
        weights = moved.cover[k].mean(0)[v, u]
        centroid = np.array([np.average(u, weights=weights), np.average(v, weights=weights)])
        assert np.linalg.norm(centroid - moved.centres[k].mean(0)) < 1.5
    later = cut(layer, 1, 2)
    assert later.frames == 2 and later.boxes == layer.boxes[1:] and np.array_equal(later.cover[0], layer.cover[1])
    with pytest.raises(ValueError, match="out of the frame"):
        shifted(layer, SPEC.width, 0)
