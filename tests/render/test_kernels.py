"""The compiled searches find what the tensor version finds, pixel for pixel."""

import math

import pytest
import torch

from sfb_video.config import RenderConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.geometry.rotation import exposure_rotations
from sfb_video.render import kernels, rasterize


@pytest.mark.parametrize("prototype", ["sphere", "torus"])
def test_compiled_searches_match_the_tensor_version(prototype: str, monkeypatch: pytest.MonkeyPatch) -> None:
    if not kernels.available(torch.zeros(1)):
        pytest.skip("numba is not importable")
    camera = PinholeCamera.from_fov(160, 120, 45.0)
    verts, topo = load_prototype(prototype)
    taus = torch.linspace(0, 1, 4)
    rotations = exposure_rotations(torch.eye(3), torch.tensor([0.3, 1.0, 0.2]), taus)
    depth = camera.fy * 0.5 / math.sqrt(160 * 120 / 3 / math.pi)
    positions = torch.tensor([-0.15, 0.0, depth]) + taus[:, None] * torch.tensor([0.3, 0.05, 0.0])
    posed = pose_vertices(verts, rotations, positions)
    compiled = rasterize(posed, topo, camera, RenderConfig(time_steps=4))
    monkeypatch.setattr(kernels, "available", lambda points: False)
    tensor = rasterize(posed, topo, camera, RenderConfig(time_steps=4))
    assert compiled.pix.numel() > 1000  # the scene is not empty
    for name in ("pix", "face", "bary", "inside", "dist2", "zbuf"):
        assert torch.equal(getattr(compiled, name), getattr(tensor, name)), name
