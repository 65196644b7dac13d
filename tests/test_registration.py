"""The camera's motion: frames registered to their reference within a pixel of the generated
transforms, a still camera found still, a pan beyond the frame re-anchored, a blank frame failed."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from sfb_video.config import CameraConfig
from sfb_video.registration import corner_shift, register_frames, warp
from sfb_video.synth import ClipSpec, generate_clip
from sfb_video.synth.backgrounds import load_photo
from sfb_video.synth.shake import pan_crops, shake_frames, shake_transforms, true_to_reference

SIZE = (320, 240)


def _tensors(frames: np.ndarray) -> list[tuple[int, torch.Tensor]]:
    return [(k, torch.from_numpy(np.ascontiguousarray(f)).permute(2, 0, 1)) for k, f in enumerate(frames)]


def _error(found: np.ndarray, truth: np.ndarray) -> float:
    """The largest distance (pixels) between where the two transforms put the frame's corners."""
    return corner_shift(found @ np.linalg.inv(truth), SIZE)


@pytest.fixture(scope="module")
def ball_clip() -> np.ndarray:
    spec = ClipSpec(
        shape="ball", seed=3, num_frames=8, background="brick", size_px_range=(20.0, 24.0), speed_range=(1.0, 1.3)
    )
    return generate_clip(spec).frames


@pytest.mark.parametrize("seed", [0, 1])
def test_a_shaken_clip_registers_within_a_pixel_of_its_transforms(ball_clip: np.ndarray, seed: int) -> None:
    # Up to 6 px and 1 degree a frame, a fast ball crossing the view: the ball's pixels must
    # not pull the transform.
    transforms = shake_transforms(len(ball_clip), SIZE, seed, max_shift_px=6.0, max_turn_deg=1.0)
    motion = register_frames(_tensors(shake_frames(ball_clip, transforms)), CameraConfig())
    truth = true_to_reference(transforms)
    assert motion.moving and not motion.failed
    errors = [_error(motion.frames[k].to_reference, truth[k]) for k in range(len(ball_clip))]
    assert max(errors) <= 1.0, errors


def test_a_still_camera_is_still(ball_clip: np.ndarray) -> None:
    motion = register_frames(_tensors(ball_clip), CameraConfig())
    assert not motion.moving
    assert all(corner_shift(r.to_reference, SIZE) < 1.0 for r in motion.frames.values())


def test_a_pan_beyond_the_frame_takes_new_references_each_within_a_pixel() -> None:
    # 12 px a frame across a scene three frames wide: the first view is left after ~13 frames.
    scene = cv2.resize(load_photo("coffee"), (960, 300), interpolation=cv2.INTER_AREA)
    step = (12.0, 1.5)
    frames = pan_crops(scene, SIZE, step, 40)
    motion = register_frames(_tensors(frames), CameraConfig(min_overlap=0.6))
    assert not motion.failed
    starts = {}
    for k, r in sorted(motion.frames.items()):
        starts.setdefault(r.segment, k)
    assert len(starts) >= 3
    for k, r in motion.frames.items():
        # A frame k of the pan sees the scene shifted by k steps; its reference, by its own.
        shift = (k - starts[r.segment]) * np.array(step)
        truth = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]], [0.0, 0.0, 1.0]])
        assert _error(r.to_reference, truth) <= 1.0, (k, r.segment)


def test_a_blank_frame_fails_to_register_and_the_rest_do_not(ball_clip: np.ndarray) -> None:
    transforms = shake_transforms(len(ball_clip), SIZE, 0)
    frames = shake_frames(ball_clip, transforms)
    frames[4] = 255  # a flash
    motion = register_frames(_tensors(frames), CameraConfig())
    assert set(motion.failed) == {4}
    assert "camera registration failed" in motion.failed[4]
    truth = true_to_reference(transforms)
    assert max(_error(motion.frames[k].to_reference, truth[k]) for k in (3, 5, 6)) <= 1.0


def test_warp_brings_a_frame_onto_its_reference(ball_clip: np.ndarray) -> None:
    transforms = shake_transforms(2, SIZE, 5)
    shaken = shake_frames(ball_clip[:1].repeat(2, 0), transforms)
    image = torch.from_numpy(shaken[1]).permute(2, 0, 1)
    back, covered = warp(image, true_to_reference(transforms)[1])
    inside = covered[20:-20, 20:-20]
    diff = (back.float() - torch.from_numpy(shaken[0]).permute(2, 0, 1).float()).abs()[:, 20:-20, 20:-20]
    assert bool(inside.all()) and float(diff.mean()) < 4.0  # interpolation only (8-bit, 0-255)
