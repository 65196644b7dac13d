"""The synthetic shapes are closed, outward, unit-scale, textured and have the intended form."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sfb_video.errors import SfbError
from sfb_video.geometry.mesh import signed_volume
from sfb_video.synth.shapes import SHAPE_NAMES, make_shape
from sfb_video.synth.textures import TEXTURE_STYLES, procedural_texture

# Euler characteristic V - E + F = 2 - 2 * genus: the ring and the key have one hole.
GENUS = {"ball": 0, "box": 0, "pen": 0, "ring": 1, "key": 1, "disc": 0}


def _principal_extents(vertices: torch.Tensor) -> np.ndarray:
    """Extents of the vertices along their principal axes, largest first."""
    v = vertices.double().numpy()
    _, _, axes = np.linalg.svd(v - v.mean(0), full_matrices=False)
    proj = v @ axes.T
    return np.sort(proj.max(0) - proj.min(0))[::-1]


@pytest.mark.parametrize("name", SHAPE_NAMES)
def test_shape_is_closed_outward_unit_scale_with_valid_uvs(name: str) -> None:
    mesh = make_shape(name, np.random.default_rng(0), 64, "random")
    v, topo = mesh.vertices, mesh.topology
    assert v.dtype == torch.float32 and v.shape[1] == 3
    assert topo.is_closed()
    assert float(signed_volume(v.double(), topo.faces)) > 0
    assert torch.allclose(v.mean(0), torch.zeros(3), atol=1e-5)
    assert float(v.square().sum(-1).mean().sqrt()) == pytest.approx(0.5, rel=1e-4)
    assert float(topo.uvs.min()) >= 0 and float(topo.uvs.max()) <= 1
    euler = v.shape[0] - topo.edges.shape[0] + topo.num_faces
    assert euler == 2 - 2 * GENUS[name]
    assert mesh.texture.shape == (64, 64, 3) and mesh.texture.dtype == np.uint8
    # Every face's UV triangle stays inside one seam-free patch (no wrap across the texture).
    fuv = topo.face_uv_coords()
    assert float((fuv.amax(1) - fuv.amin(1)).max()) < 0.5


def test_shape_proportions() -> None:
    rng = np.random.default_rng(0)
    box = _principal_extents(make_shape("box", rng, 16, "checker").vertices)
    assert box[0] / box[1] == pytest.approx(1 / 0.62, rel=1e-3)
    assert box[1] / box[2] == pytest.approx(0.62 / 0.4, rel=1e-3)
    pen = _principal_extents(make_shape("pen", rng, 16, "stripes").vertices)
    assert pen[0] / pen[1] == pytest.approx(5.0, rel=0.02)
    key = _principal_extents(make_shape("key", rng, 16, "patches").vertices)
    assert key[2] / key[0] < 0.05  # a flat plate
    ball = _principal_extents(make_shape("ball", rng, 16, "mixed").vertices)
    assert ball.max() / ball.min() == pytest.approx(1.0, abs=0.01)


def test_texture_is_deterministic_by_seed_and_styles_differ() -> None:
    for style in TEXTURE_STYLES:
        a = procedural_texture(np.random.default_rng(7), 32, style)
        b = procedural_texture(np.random.default_rng(7), 32, style)
        c = procedural_texture(np.random.default_rng(8), 32, style)
        np.testing.assert_array_equal(a, b)
        assert not np.array_equal(a, c)
        assert a.std() > 20  # real contrast, not a flat colour


def test_unknown_names_raise() -> None:
    with pytest.raises(SfbError, match="unknown shape"):
        make_shape("teapot", np.random.default_rng(0), 16, "random")
    with pytest.raises(SfbError, match="unknown texture style"):
        procedural_texture(np.random.default_rng(0), 16, "plaid")
