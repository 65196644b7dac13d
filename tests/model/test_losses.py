import pytest
import torch

from sfb_video.geometry.mesh import MeshTopology
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model import losses


def test_soft_iou_of_binary_masks_is_the_iou() -> None:
    a = torch.zeros(4, 4)
    b = torch.zeros(4, 4)
    a[:2] = 1  # 8 pixels
    b[1:3] = 1  # 8 pixels, 4 shared
    assert losses.soft_iou(a, b).item() == pytest.approx(4 / 12)


def test_image_loss_is_normalised_by_the_region_of_interest() -> None:
    image, rendered = torch.zeros(3, 10, 10), torch.zeros(3, 10, 10)
    rendered[:, :2, :5] = 0.5  # error 0.5 on 10 pixels
    roi = torch.zeros(10, 10)
    roi[:2, :5] = 1
    assert losses.image_loss(image, rendered, roi).item() == pytest.approx(0.5)
    assert losses.image_loss(image, rendered).item() == pytest.approx(0.05)


def test_difference_loss_uses_the_swept_region_not_the_mean() -> None:
    # An object in two places over the exposure sweeps both; D marks both: a perfect fit.
    alpha = torch.zeros(2, 1, 4, 8)
    alpha[0, 0, :, :4] = 1
    alpha[1, 0, :, 4:] = 1
    diff = torch.ones(4, 8)
    assert losses.difference_loss(diff, alpha).item() == pytest.approx(0.0, abs=1e-6)


def test_silhouette_loss_groups_time_steps_into_subframes() -> None:
    alpha = torch.zeros(4, 1, 2, 2)
    alpha[:2, 0, 0] = 1
    alpha[2:, 0, 1] = 1
    masks = torch.zeros(2, 2, 2)
    masks[0, 0] = 1
    masks[1, 1] = 1
    assert losses.silhouette_loss(masks, alpha).item() == pytest.approx(0.0, abs=1e-6)
    assert losses.silhouette_loss(masks.flip(0), alpha).item() == pytest.approx(1.0)


def test_texture_tv() -> None:
    assert losses.texture_tv(torch.full((3, 5, 5), 0.3)).item() == 0
    stripes = torch.zeros(3, 4, 4)
    stripes[:, :, ::2] = 1
    assert losses.texture_tv(stripes).item() == pytest.approx(1.0)


def test_laplacian_grows_by_the_hand_computed_amount_for_a_bump() -> None:
    ys, xs = torch.meshgrid(torch.arange(5.0), torch.arange(5.0), indexing="ij")
    verts = torch.stack((xs, ys, torch.zeros_like(xs)), -1).reshape(-1, 3)
    quads = [(r * 5 + c, r * 5 + c + 1, (r + 1) * 5 + c) for r in range(4) for c in range(4)]
    quads += [(r * 5 + c + 1, (r + 1) * 5 + c + 1, (r + 1) * 5 + c) for r in range(4) for c in range(4)]
    faces = torch.tensor(quads)
    topo = MeshTopology.build(faces, torch.rand(25, 2), faces)
    flat = losses.laplacian(verts, topo.edges)
    bumped = verts.clone()
    bumped[12, 2] = 1.0  # the centre vertex, whose six neighbours all have six neighbours
    # Its own term gains 1^2, each neighbour's (1/6)^2; the mean is over 25 vertices.
    assert (losses.laplacian(bumped, topo.edges) - flat).item() == pytest.approx((1 + 6 / 36) / 25, rel=1e-5)


def test_laplacian_prefers_the_smooth_prototype() -> None:
    verts, topo = load_prototype("sphere")
    noisy = verts + 0.02 * torch.randn_like(verts)
    assert losses.laplacian(noisy, topo.edges) > 5 * losses.laplacian(verts, topo.edges)
