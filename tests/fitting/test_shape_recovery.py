"""The window fit recovers the shape the streaks show: a short-exposure pen long, a box boxy.

Generated clips whose truth is known; the seeds are grey spheres on the true streaks (what the
single-frame fits hand over, in shape), so the shape must come from the window's own trial.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sfb_video.config import load_config
from sfb_video.fitting.path import Seed
from sfb_video.fitting.window import JointResult, fit_window
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import box_fill
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.geometry.rotation import axis_angle_to_matrix
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.synth import ClipSpec, SyntheticClip, generate_clip
from tests.fitting.clips import window_frames

CONFIG = load_config(
    "fast", ["joint.iterations=150", "render.time_steps=8", "joint.prototypes=[sphere,capsule,box,disc,torus]"]
)


def _fit(spec: ClipSpec) -> tuple[SyntheticClip, JointResult]:
    clip = generate_clip(spec)
    vertices, topology = load_prototype("sphere")
    grey = torch.full((3, CONFIG.fit.texture_size, CONFIG.fit.texture_size), 0.5)
    frames, seeds = window_frames(clip, CONFIG.crop), []
    for truth in clip.truth:
        x0, dx = (torch.tensor(v, dtype=torch.float32) for v in (truth.motion.x0, truth.motion.dx))
        seeds.append(
            Seed(
                truth.index,
                ObjectState(vertices, topology, grey, Motion(x0, dx, torch.eye(3), torch.zeros(3))),
                "sphere",
                0.1,
            )
        )
    config = CONFIG
    args = (config.fit, config.joint, config.render, spec.exposure_fraction, config.joint.prototypes)
    result = fit_window(frames, seeds, clip.camera, *args)
    return clip, result


def _image_length(vertices: np.ndarray, rotation: np.ndarray, position: np.ndarray, camera: PinholeCamera) -> float:
    """The longest extent in pixels of ``vertices`` (V, 3) posed by ``rotation`` and ``position``."""
    posed = torch.as_tensor(np.asarray(vertices) @ rotation.T + position, dtype=torch.float32)
    uv, _ = camera.project(posed)
    centred = (uv - uv.mean(0)).double()
    axis = torch.linalg.eigh(centred.T @ centred)[1][:, -1]
    along = centred @ axis
    return float(along.max() - along.min())


def _mid_pose(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    rotation = axis_angle_to_matrix(0.5 * torch.as_tensor(motion.omega, dtype=torch.float32))
    rotation = rotation @ torch.as_tensor(motion.rot0, dtype=torch.float32)
    return rotation.numpy(), (np.asarray(motion.x0) + 0.5 * np.asarray(motion.dx)).astype(np.float32)


@pytest.fixture(scope="module")
def pen() -> tuple[SyntheticClip, JointResult]:
    # A short exposure: the pen, 5 diameters long, moves 0.6 of its length while the shutter is
    # open, so only a long object moving a little explains the streak.
    spec = ClipSpec(
        num_frames=4,
        exposure_fraction=0.35,
        num_subframes=4,
        sub_exposures=16,
        shape="pen",
        texture_style="patches",
        size_px_range=(44.0, 48.0),
        speed_range=(0.6, 0.7),
        min_streak=0.5,
        rotation_deg_range=(10.0, 15.0),
        seed=7,
    )
    return _fit(spec)


def test_a_short_exposure_pen_is_recovered_long(pen: tuple[SyntheticClip, JointResult]) -> None:
    clip, result = pen
    for truth in clip.truth[1:3]:
        m = truth.motion
        true = Motion(*(torch.tensor(v, dtype=torch.float32) for v in (m.x0, m.dx, m.rotation, m.omega)))
        true_length = _image_length(clip.scene.mesh.vertices, *_mid_pose(true), clip.camera)
        state = result.state(truth.index)
        length = _image_length(state.vertices.numpy(), *_mid_pose(state.motion), clip.camera)
        assert length == pytest.approx(true_length, rel=0.2), (result.prototype, result.shapes)


@pytest.fixture(scope="module")
def box() -> tuple[SyntheticClip, JointResult]:
    spec = ClipSpec(
        num_frames=4,
        exposure_fraction=0.5,
        num_subframes=4,
        sub_exposures=16,
        shape="box",
        texture_style="patches",
        size_px_range=(36.0, 40.0),
        speed_range=(1.0, 1.2),
        rotation_deg_range=(20.0, 30.0),
        seed=11,
    )
    return _fit(spec)


def test_a_box_is_recovered_with_flat_faces(box: tuple[SyntheticClip, JointResult]) -> None:
    _, result = box
    # box_fill: 1 for a box, 0.52 for a sphere (tests/fitting/test_shapes.py).
    assert box_fill(result.vertices, result.topology.faces) > 0.8, (result.prototype, result.shapes)
