import math

import torch

from sfb_video.geometry import rotation as rot


def test_quaternions_are_scalar_first() -> None:
    # 90 degrees about z in WXYZ order: w = cos(45), z = sin(45).
    q = torch.tensor([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])
    r = rot.quaternion_to_matrix(q)
    assert torch.allclose(r @ torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)
    assert torch.allclose(rot.quaternion_to_matrix(torch.tensor([1.0, 0, 0, 0])), torch.eye(3))


def test_axis_angle_round_trips_through_quaternion_and_matrix() -> None:
    omega = torch.tensor([[0.3, -1.2, 0.5], [0.0, 0.0, 1e-8], [2.0, 1.0, -0.5]])
    assert torch.allclose(rot.quaternion_to_axis_angle(rot.axis_angle_to_quaternion(omega)), omega, atol=1e-5)
    assert torch.allclose(rot.matrix_to_axis_angle(rot.axis_angle_to_matrix(omega)), omega, atol=1e-4)


def test_negated_quaternion_gives_the_short_angle() -> None:
    q = rot.axis_angle_to_quaternion(torch.tensor([0.0, 0.5, 0.0]))
    assert torch.allclose(rot.quaternion_to_axis_angle(-q), torch.tensor([0.0, 0.5, 0.0]), atol=1e-6)


def test_exposure_rotations_interpolate_on_the_geodesic() -> None:
    rot0 = rot.axis_angle_to_matrix(torch.tensor([0.2, 0.1, -0.4]))
    omega = torch.tensor([0.0, math.radians(90), 0.0])
    taus = torch.tensor([0.0, 0.5, 1.0])
    rs = rot.exposure_rotations(rot0, omega, taus)
    assert torch.allclose(rs[0], rot0, atol=1e-6)
    assert torch.allclose(rs[2], rot.axis_angle_to_matrix(omega) @ rot0, atol=1e-6)
    angles = rot.rotation_angle_deg(rot0.expand(3, 3, 3), rs)
    assert torch.allclose(angles, torch.tensor([0.0, 45.0, 90.0]), atol=1e-2)


def test_compact_conversions_match_kornia_in_values_and_gradients() -> None:
    from kornia.geometry import conversions as kc

    omega = torch.tensor([[0.3, -1.2, 0.5], [0.0, 0.0, 0.0], [1e-5, -2e-5, 0.0], [2.0, 1.0, -0.5]], dtype=torch.float64)
    quat = torch.tensor([[0.9, 0.1, -0.3, 0.2], [1.0, 0.0, 0.0, 0.0], [-0.2, 0.5, 0.5, -0.6]], dtype=torch.float64)
    for ours, theirs, x in (
        (rot.axis_angle_to_matrix, kc.axis_angle_to_rotation_matrix, omega),
        (rot.quaternion_to_matrix, lambda q: kc.quaternion_to_rotation_matrix(kc.normalize_quaternion(q)), quat),
    ):
        weights = torch.rand(x.shape[0], 3, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
        grads = []
        for fn in (ours, theirs):
            xx = x.clone().requires_grad_()
            value = fn(xx)
            (value * weights).sum().backward()
            grads.append((value.detach(), xx.grad))
        assert torch.allclose(grads[0][0], grads[1][0], atol=1e-12)
        assert torch.allclose(grads[0][1], grads[1][1], atol=1e-8)
        assert torch.isfinite(grads[0][1]).all()
    assert torch.autograd.gradcheck(rot.axis_angle_to_matrix, (omega.clone().requires_grad_(),))
