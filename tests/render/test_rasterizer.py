import math

import pytest
import torch

from sfb_video.config import RenderConfig
from sfb_video.errors import MeshError, PoseError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.render import MeshRenderer, rasterize
from sfb_video.render.reference import rasterize_reference
from tests.render.scenes import quad_filling_image, seamless_sphere


def test_sphere_silhouette_matches_the_projected_disc(device: torch.device) -> None:
    cam = PinholeCamera.from_fov(200, 200, 40.0)
    verts, topo = load_prototype("sphere")
    distance = 2.0
    out = MeshRenderer(cam)(
        verts[None].to(device) + torch.tensor([0.0, 0.0, distance], device=device),
        topo,
        torch.rand(3, 4, 4, device=device),
    )
    area = (out.face_idx >= 0).sum().item()
    # A sphere of radius R at distance d subtends a cone of half-angle asin(R / d).
    radius_px = cam.fx * math.tan(math.asin(0.5 / distance))
    assert area == pytest.approx(math.pi * radius_px**2, rel=0.01)
    assert bool(((out.alpha[:, 0] == 1) == (out.face_idx >= 0)).all())


def test_flat_quad_reproduces_its_texture(device: torch.device) -> None:
    cam = PinholeCamera.from_fov(24, 16, 50.0)
    verts, topo = quad_filling_image(cam, depth=3.0)
    texture = torch.rand(3, 16, 24, device=device)
    out = MeshRenderer(cam)(verts[None].to(device), topo, texture)
    # Pixel centres land on texel centres, where bilinear sampling returns the texel itself.
    assert torch.allclose(out.rgb[0], texture, atol=1e-4)
    assert torch.allclose(out.depth, torch.full_like(out.depth, 3.0), atol=1e-4)


@pytest.mark.parametrize("near_first", [True, False])
def test_nearer_triangle_wins_whatever_the_face_order(near_first: bool) -> None:
    cam = PinholeCamera.from_fov(32, 32, 60.0)
    near = torch.tensor([[-1.0, -1.0, 2.0], [1.0, -1.0, 2.0], [0.0, 1.0, 2.0]])
    far = torch.tensor([[-1.0, 1.0, 4.0], [1.0, 1.0, 4.0], [0.0, -1.0, 4.0]])
    verts = torch.cat((near, far) if near_first else (far, near))
    faces = torch.tensor([[0, 1, 2], [3, 4, 5]])
    topo = MeshTopology.build(faces, torch.rand(6, 2), faces)
    frags = rasterize(verts[None], topo, cam, RenderConfig())
    near_face = 0 if near_first else 1
    centre = frags.face_idx[0, 16, 16].item()
    assert centre == near_face
    assert frags.zbuf[0, 16, 16].item() == pytest.approx(2.0, abs=1e-4)
    # Where only the far triangle covers, the far one shows, at its own depth.
    only_far = (frags.zbuf[0] > 3.0) & torch.isfinite(frags.zbuf[0])
    assert only_far.any()
    assert bool((frags.face_idx[0][only_far] == 1 - near_face).all())


def _render_both(verts: torch.Tensor, topo: MeshTopology, texture: torch.Tensor, settings: RenderConfig):
    cam = PinholeCamera.from_fov(36, 28, 45.0)
    results = []
    for rasterizer in (rasterize, rasterize_reference):
        v = verts.clone().requires_grad_()
        tex = texture.clone().requires_grad_()
        out = MeshRenderer(cam, settings, rasterizer)(v, topo, tex)
        weights = torch.rand(out.rgb.shape, generator=torch.Generator().manual_seed(1), dtype=verts.dtype)
        loss = (out.rgb * weights).sum() + 3 * (out.alpha * weights[:, :1]).sum()
        loss.backward()
        results.append((out, v.grad, tex.grad))
    return results


def test_fast_rasteriser_matches_the_reference_in_values_and_gradients() -> None:
    verts, topo = seamless_sphere()
    poses = torch.tensor([[0.1, 0.05, 2.5], [0.35, -0.1, 2.8]])
    verts = (verts[None] + poses[:, None]).double()
    verts = verts + 0.03 * torch.randn_like(verts)
    (fast, g_fast, t_fast), (ref, g_ref, t_ref) = _render_both(
        verts, topo, torch.rand(3, 8, 8).double(), RenderConfig(sigma_inv=2000.0)
    )
    assert torch.equal(fast.face_idx, ref.face_idx)
    assert torch.allclose(fast.rgb, ref.rgb, atol=1e-10)
    assert torch.allclose(fast.alpha, ref.alpha, atol=1e-10)
    assert torch.allclose(g_fast, g_ref, atol=1e-8)
    assert torch.allclose(t_fast, t_ref, atol=1e-8)
    assert g_fast.abs().max() > 1.0  # the comparison is not between two zeros


def test_band_colour_continues_the_surface() -> None:
    # With a uniform texture, rgb * alpha must fade the surface colour, not darken the outline.
    verts, topo = load_prototype("sphere")
    cam = PinholeCamera.from_fov(64, 48, 45.0)
    out = MeshRenderer(cam)(verts[None] + torch.tensor([0.0, 0.0, 2.5]), topo, torch.full((3, 4, 4), 0.7))
    band = (out.alpha > 0) & (out.alpha < 1)
    assert band.sum() > 20
    assert torch.allclose(out.rgb[band.expand_as(out.rgb)], torch.tensor(0.7), atol=1e-5)


@pytest.mark.parametrize(
    ("mutate", "error", "message"),
    [
        (lambda v, f: (v.index_put((torch.tensor([0]),), torch.tensor(float("nan"))), f), MeshError, "NaN"),
        (lambda v, f: (v, f.index_put((torch.tensor([0]),), torch.tensor(10_000))), MeshError, "out of range"),
        (lambda v, f: (v - torch.tensor([0.0, 0.0, 4.0]), f), PoseError, "behind the camera"),
    ],
)
def test_bad_meshes_and_poses_raise_clear_value_errors(mutate, error, message) -> None:
    verts, topo = load_prototype("sphere")
    verts = verts + torch.tensor([0.0, 0.0, 3.0])
    verts, faces = mutate(verts.clone(), topo.faces.clone())
    topo = MeshTopology(faces, topo.uvs, topo.face_uvs, topo.edges, topo.edge_faces, topo.edge_slots)
    with pytest.raises(error, match=message) as info:
        MeshRenderer(PinholeCamera.from_fov(32, 24, 45.0))(verts[None], topo, torch.rand(3, 4, 4))
    assert isinstance(info.value, ValueError)


def test_bad_texture_is_rejected() -> None:
    verts, topo = load_prototype("sphere")
    with pytest.raises(ValueError, match="texture"):
        MeshRenderer(PinholeCamera.from_fov(32, 24, 45.0))(verts[None] + 3, topo, torch.rand(4, 4))


def test_sliver_far_from_the_origin_gives_finite_weights_and_gradients() -> None:
    # Captured from a fit: a sliver face ~170 px from the pixel origin, whose barycentric planes
    # in absolute pixel coordinates cancelled to infinite weights (and crashed grid_sample).
    cam = PinholeCamera.from_fov(320, 240, 45.0)
    uv = torch.tensor([[171.0561, 125.9175], [171.2083, 125.6908], [170.6598, 126.5041]])
    verts = cam.unproject(uv, torch.tensor([7.1955, 7.1447, 7.1701]))[None].requires_grad_()
    faces = torch.tensor([[0, 1, 2]])
    topo = MeshTopology.build(faces, torch.rand(3, 2), faces)
    frags = rasterize(verts, topo, cam, RenderConfig())
    assert bool(frags.inside.any())
    assert bool(torch.isfinite(frags.bary).all())
    assert bool(((frags.bary[frags.inside] > -1e-3) & (frags.bary[frags.inside] < 1 + 1e-3)).all())
    (frags.bary.sum() + frags.dist2.sum()).backward()
    assert bool(torch.isfinite(verts.grad).all())
