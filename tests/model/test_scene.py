"""Rendering a recovered object: TSR sub-frames are the exposure split in time, and rendering in
batches of poses (which bounds memory at any image size) gives the same images."""

from __future__ import annotations

import dataclasses

import torch

from sfb_video.config import RenderConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model.formation import blend, exposure_times
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState

CAMERA = PinholeCamera.from_fov(64, 48, 45.0)


def _ball() -> ObjectState:
    vertices, topology = load_prototype("sphere")
    motion = Motion(
        torch.tensor([-0.6, 0.0, 5.0]), torch.tensor([1.2, 0.2, 0.0]), torch.eye(3), torch.tensor([0.0, 1.0, 0.0])
    )
    return ObjectState(vertices, topology, torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(0)), motion)


def test_subframes_average_to_the_blurred_exposure() -> None:
    state, background, settings = _ball(), torch.rand(3, 48, 64), RenderConfig(steps_per_subframe=2)
    subs = state.render_subframes(CAMERA, background, 4, settings)
    assert subs.shape == (4, 3, 48, 64)
    whole = state.render_blurred(CAMERA, background, 8, settings)
    assert torch.allclose(subs.mean(0), whole, atol=1e-5)
    # The object moves: the first and last sub-frames differ where it passes.
    assert (subs[0] - subs[-1]).abs().amax() > 0.2


def test_rendering_in_batches_of_poses_changes_nothing() -> None:
    state, background = _ball(), torch.rand(3, 48, 64)
    at_once = state.render_blurred(CAMERA, background, 8, RenderConfig())
    one_by_one = state.render_blurred(CAMERA, background, 8, dataclasses.replace(RenderConfig(), max_batch_pixels=1))
    assert torch.allclose(at_once, one_by_one, atol=1e-6)
    out = state.render(CAMERA, exposure_times(8), RenderConfig())
    assert torch.allclose(at_once, blend(out.rgb, out.alpha, background), atol=1e-6)


def _box_of(mask: torch.Tensor) -> tuple[int, int, int, int]:
    ys, xs = torch.nonzero(mask, as_tuple=True)
    return int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)


def test_image_box_is_the_rendered_silhouettes_box() -> None:
    state = _ball()
    alpha = state.render(CAMERA, torch.linspace(0, 1, 64), RenderConfig()).alpha.amax(0)[0]
    # Pixels whose centres it covers, and at most the ones beside them that it touches.
    x, y, w, h = _box_of(alpha > 0.5)
    bx, by, bw, bh = state.image_box(CAMERA)
    assert x - 1 <= bx <= x and y - 1 <= by <= y
    assert x + w <= bx + bw <= x + w + 1 and y + h <= by + bh <= y + h + 1
    # A box that leaves the image is cut at its edge; one wholly behind the camera is none.
    right = dataclasses.replace(state, motion=dataclasses.replace(state.motion, x0=torch.tensor([1.5, 0.0, 5.0])))
    rx, _, rw, _ = right.image_box(CAMERA)
    assert rx + rw == CAMERA.width and rw < bw
    behind = dataclasses.replace(state, motion=dataclasses.replace(state.motion, x0=torch.tensor([0.0, 0.0, -9.0])))
    assert behind.image_box(CAMERA) is None
