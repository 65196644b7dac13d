"""The hard rasteriser: texture mapping, perspective, depth order, coverage, grouping."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from sfb_video.errors import PoseError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.synth.raster import pose_points, rasterize
from sfb_video.synth.shapes import make_shape

SQUARE_FACES = torch.tensor([[0, 1, 2], [0, 2, 3]])
SQUARE_UVS = torch.tensor([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def _square(corners: list[list[float]]) -> torch.Tensor:
    """(1, 4, 3) points of a quad with corners top-left, top-right, bottom-right, bottom-left."""
    return torch.tensor([corners], dtype=torch.float64)


def _block_texture(rng: np.random.Generator, size: int, block: int) -> np.ndarray:
    blocks = rng.integers(0, 256, (size // block, size // block, 3), dtype=np.uint8)
    return np.repeat(np.repeat(blocks, block, 0), block, 1)


def test_face_on_square_reproduces_its_texture_with_exact_coverage() -> None:
    # f = 64 at depth 2 maps the square [-1, 1]^2 onto exactly 64 x 64 pixels: pixel edges
    # 7.5 .. 71.5, so pixel (8 + i, 8 + j) sees texel (i, j) at its centre.
    cam = PinholeCamera(64.0, 64.0, 39.5, 39.5, 80, 80)
    texture = _block_texture(np.random.default_rng(0), 64, 8)
    points = _square([[-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]])
    out = rasterize(points, SQUARE_FACES, SQUARE_UVS[SQUARE_FACES], texture, cam, 2, cull_backfaces=False)
    cov = out.coverage[0]
    assert np.all(cov[8:72, 8:72] == 1.0)
    cov_outside = cov.copy()
    cov_outside[8:72, 8:72] = 0
    assert np.all(cov_outside == 0)
    rendered = out.premultiplied[0, 8:72, 8:72]
    expected = texture / 255.0
    # Bilinear lookups mix neighbours only across block borders; inside blocks it is exact, and
    # the image is neither flipped nor shifted (an asymmetric random texture would show it).
    inner = np.zeros((64, 64), bool)
    for k in range(8):
        inner[k * 8 + 1 : k * 8 + 7] = True
    inner = inner & inner.T
    np.testing.assert_allclose(rendered[inner], expected[inner], atol=1e-6)  # float32 texels
    assert np.abs(rendered - expected).mean() < 0.02


def test_texture_lookup_is_perspective_correct() -> None:
    # A quad receding to the right: its texture's middle (u = 1/2) is the 3D midpoint (0, y, 3),
    # which projects onto column cx, while affine screen interpolation would put it 8 px left.
    cam = PinholeCamera(64.0, 64.0, 39.5, 39.5, 80, 80)
    texture = np.zeros((4, 4, 3), np.uint8)
    texture[:, :2, 0] = 255
    texture[:, 2:, 2] = 255
    points = _square([[-1, -1, 2], [1, -1, 4], [1, 1, 4], [-1, 1, 2]])
    out = rasterize(points, SQUARE_FACES, SQUARE_UVS[SQUARE_FACES], texture, cam, 4, cull_backfaces=False)
    row = out.premultiplied[0, 40]
    red_cols = np.nonzero((row[:, 0] > 0.5) & (out.coverage[0, 40] == 1))[0]
    blue_cols = np.nonzero(row[:, 2] > 0.5)[0]
    assert red_cols.max() + 1 == blue_cols.min()
    boundary = red_cols.max() + 0.5
    assert boundary == pytest.approx(cam.cx, abs=1.0)


@pytest.mark.parametrize("near_first", [True, False])
def test_nearer_surface_wins_whatever_the_face_order(near_first: bool) -> None:
    cam = PinholeCamera(40.0, 40.0, 19.5, 19.5, 40, 40)
    near = [[-1, -1, 2], [0, -1, 2], [0, 1, 2], [-1, 1, 2]]  # columns 0 .. 19
    far = [[-0.5, -2, 3], [2, -2, 3], [2, 2, 3], [-0.5, 2, 3]]  # columns 13 .. 39
    quads = [near, far] if near_first else [far, near]
    points = torch.tensor([quads[0] + quads[1]], dtype=torch.float64)
    faces = torch.cat((SQUARE_FACES, SQUARE_FACES + 4))
    texture = np.zeros((2, 2, 3), np.uint8)
    texture[:, 0, 0] = 255  # left half red
    texture[:, 1, 2] = 255  # right half blue
    near_uv = torch.tensor([[0.0, 0.0], [0.25, 0.0], [0.25, 1.0], [0.0, 1.0]])  # red part
    far_uv = torch.tensor([[0.75, 0.0], [1.0, 0.0], [1.0, 1.0], [0.75, 1.0]])  # blue part
    uvs = torch.cat((near_uv, far_uv) if near_first else (far_uv, near_uv))
    out = rasterize(points, faces, uvs[faces], texture, cam, 2, cull_backfaces=False)
    img = out.premultiplied[0]
    np.testing.assert_allclose(img[19, 16], [1.0, 0.0, 0.0])  # overlap: the near red quad
    np.testing.assert_allclose(img[19, 30], [0.0, 0.0, 1.0])  # only the far quad reaches here
    np.testing.assert_allclose(out.coverage[0, 19, :], 1.0)


def test_sphere_silhouette_matches_the_projection_of_its_centre() -> None:
    mesh = make_shape("ball", np.random.default_rng(0), 16, "checker")
    cam = PinholeCamera(100.0, 100.0, 49.5, 39.5, 100, 80)
    centres = torch.tensor([[0.0, 0.0, 5.0], [1.0, 0.5, 5.0]], dtype=torch.float64)
    points = pose_points(mesh.vertices, torch.eye(3).expand(2, 3, 3), centres)
    out = rasterize(points, mesh.topology.faces, mesh.topology.face_uv_coords(), mesh.texture, cam, 4)
    uv, _ = cam.project(centres)
    rows, cols = np.mgrid[0:80, 0:100]
    for k in range(2):
        cov = out.coverage[k]
        area = cov.sum()
        centroid = np.array([(cov * cols).sum(), (cov * rows).sum()]) / area
        # A sphere off the axis projects to an ellipse whose centre lies ~f x r^2 / z^3 outwards.
        tol = 0.05 if k == 0 else 0.3
        np.testing.assert_allclose(centroid, uv[k].numpy(), atol=tol)
        radius = 100 * 0.5 / math.sqrt(5.0**2 - 0.5**2)  # silhouette of the sphere on the axis
        assert area == pytest.approx(math.pi * radius**2, rel=0.03)


def test_groups_average_their_views_and_culling_does_not_change_a_closed_mesh() -> None:
    mesh = make_shape("box", np.random.default_rng(1), 32, "patches")
    cam = PinholeCamera(60.0, 60.0, 31.5, 23.5, 64, 48)
    rot = torch.linalg.matrix_exp(
        torch.tensor([[0, -1, 0.5], [1, 0, -0.2], [-0.5, 0.2, 0]]) * torch.arange(4.0)[:, None, None] / 3
    )
    trans = torch.tensor([[-0.6, 0, 3], [-0.2, 0.1, 3], [0.2, 0.2, 3.2], [0.6, 0.3, 3.4]])
    points = pose_points(mesh.vertices, rot, trans)
    args = (mesh.topology.faces, mesh.topology.face_uv_coords(), mesh.texture, cam, 2)
    single = rasterize(points, *args)
    grouped = rasterize(points, *args, groups=np.array([0, 0, 1, 1]))
    np.testing.assert_allclose(grouped.coverage, single.coverage.reshape(2, 2, 48, 64).mean(1), atol=1e-12)
    np.testing.assert_allclose(grouped.premultiplied, single.premultiplied.reshape(2, 2, 48, 64, 3).mean(1), atol=1e-12)
    uncul = rasterize(points, *args, cull_backfaces=False)
    np.testing.assert_allclose(uncul.premultiplied, single.premultiplied, atol=1e-12)
    np.testing.assert_array_equal(uncul.coverage, single.coverage)
    assert set(np.unique(single.coverage * 4)) <= set(range(5))  # 2 x 2 samples per pixel


def test_geometry_behind_the_camera_is_refused() -> None:
    points = _square([[-1, -1, -2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]])
    cam = PinholeCamera(10.0, 10.0, 4.5, 4.5, 10, 10)
    with pytest.raises(PoseError):
        rasterize(points, SQUARE_FACES, SQUARE_UVS[SQUARE_FACES], np.zeros((2, 2, 3), np.uint8), cam)
