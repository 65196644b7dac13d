"""Renderer gradients against central finite differences, and descent on a silhouette loss."""

import torch

from sfb_video.config import RenderConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.render import MeshRenderer
from tests.render.scenes import seamless_sphere

# A band cut-off far below finite-difference resolution keeps the band's edge from jumping.
SETTINGS = RenderConfig(sigma_inv=1500.0, band_eps=1e-14)


def _scene() -> tuple[MeshRenderer, torch.Tensor, object, torch.Tensor]:
    verts, topo = seamless_sphere(3, 5)
    verts = (verts + torch.tensor([0.05, -0.03, 2.2])).double()[None]
    verts = verts + 0.02 * torch.randn_like(verts)
    return MeshRenderer(PinholeCamera.from_fov(20, 16, 45.0), SETTINGS), verts, topo, torch.rand(3, 6, 6).double()


def test_colour_and_silhouette_gradients_match_finite_differences() -> None:
    renderer, verts, topo, texture = _scene()

    def colour(v: torch.Tensor, tex: torch.Tensor) -> torch.Tensor:
        out = renderer(v, topo, tex)
        return out.rgb * out.alpha

    def silhouette(v: torch.Tensor) -> torch.Tensor:
        return renderer(v, topo, texture).alpha

    verts.requires_grad_()
    texture.requires_grad_()
    assert torch.autograd.gradcheck(colour, (verts, texture), eps=1e-6, atol=1e-4, rtol=1e-3)
    assert torch.autograd.gradcheck(silhouette, (verts,), eps=1e-6, atol=1e-4, rtol=1e-3)


def test_soft_silhouette_has_gradient_outside_the_mesh() -> None:
    renderer, verts, topo, texture = _scene()
    verts.requires_grad_()
    out = renderer(verts, topo, texture)
    outside = (out.face_idx < 0) & (out.alpha[:, 0] > 1e-3)
    assert outside.sum() > 0
    (out.alpha[:, 0][outside]).sum().backward()
    assert verts.grad.abs().sum() > 0


def _soft_iou(alpha: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    inter = (alpha * target).sum()
    return inter / (alpha + target - alpha * target).sum()


def test_descent_on_soft_iou_reaches_a_target_it_does_not_overlap() -> None:
    cam = PinholeCamera.from_fov(80, 60, 45.0)
    verts, topo = load_prototype("sphere")
    texture = torch.rand(3, 4, 4)
    target_pos = torch.tensor([0.55, 0.2, 3.0])
    sharp = MeshRenderer(cam)
    with torch.no_grad():
        target = (sharp(verts[None] + target_pos, topo, texture).face_idx >= 0).float()[:, None]
        start = (sharp(verts[None] + torch.tensor([-0.4, -0.1, 3.3]), topo, texture).face_idx >= 0).float()
    assert (start[:, None] * target).sum() == 0
    pos = torch.tensor([-0.4, -0.1, 3.3], requires_grad=True)
    optim = torch.optim.Adam([pos], lr=0.03)
    steps = 200
    for i in range(steps):
        # Coarse to fine: a wide halo reaches the distant target; at a fixed wide halo the optimum
        # shrinks the object (moves it away), so sharpen to the paper's value as it closes in.
        sigma_inv = 40.0 * (7000.0 / 40.0) ** (i / (steps - 1))
        renderer = MeshRenderer(cam, RenderConfig(sigma_inv=sigma_inv))
        optim.zero_grad()
        loss = 1 - _soft_iou(renderer(verts[None] + pos, topo, texture).alpha, target)
        loss.backward()
        optim.step()
    with torch.no_grad():
        final = (sharp(verts[None] + pos, topo, texture).face_idx >= 0).float()[:, None]
    hard_iou = (final * target).sum() / ((final + target) > 0).sum()
    assert hard_iou > 0.9
    assert torch.linalg.norm(pos.detach() - target_pos) < 0.15
