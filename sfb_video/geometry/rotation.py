"""Rotations: quaternions, axis-angle vectors and the rotation over one exposure.

Convention:
    Quaternions are (w, x, y, z), scalar first, as in kornia >= 0.7 (older kornia used
    (x, y, z, w): a known trap when reading old code). Axis-angle vectors are axis * angle
    in radians. Matrices act on column vectors: p' = R @ p.

Within one exposure, tau in [0, 1], an object starting at rotation R0 and turning by dR
(axis-angle omega) is at R(tau) = exp(tau * omega) @ R0, about its centre of mass.
"""

from __future__ import annotations

import torch
from kornia.geometry import conversions as kc

# The fitter evaluates these every step, forward and backward: written with as few tensor
# operations as the formulas allow (kornia's took ~500 per fit step, most of a millisecond each
# way), checked against kornia in the tests.


def skew(v: torch.Tensor) -> torch.Tensor:
    """(*, 3) vectors -> (*, 3, 3) cross-product matrices [v]_x, with [v]_x @ p = v x p."""
    x, y, z = v.unbind(-1)
    zero = torch.zeros_like(x)
    return torch.stack((zero, -z, y, z, zero, -x, -y, x, zero), -1).reshape(*v.shape, 3)


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(*, 4) WXYZ quaternions (normalised here) -> (*, 3, 3) rotation matrices:
    R = I + 2 w [v]_x + 2 [v]_x^2 for the unit quaternion (w, v) (exactly I at v = 0, so that
    small rotations keep their precision)."""
    q = q / q.norm(dim=-1, keepdim=True)
    k = skew(q[..., 1:])
    return torch.eye(3, dtype=q.dtype, device=q.device) + 2 * (q[..., :1, None] * k + k @ k)


def axis_angle_to_matrix(omega: torch.Tensor) -> torch.Tensor:
    """(*, 3) axis-angle vectors -> (*, 3, 3) rotation matrices, by Rodrigues' formula
    R = I + a [w]_x + b [w]_x^2 with a = sin t / t, b = (1 - cos t) / t^2 for the angle t (their
    Taylor series near 0, so that the value and gradient are exact also at angle 0)."""
    angle2 = omega.square().sum(-1)[..., None, None]
    small = angle2 < 1e-6
    safe = torch.where(small, torch.ones_like(angle2), angle2)
    angle = safe.sqrt()
    a = torch.where(small, 1 - angle2 / 6, torch.sin(angle) / angle)
    b = torch.where(small, 0.5 - angle2 / 24, (1 - torch.cos(angle)) / safe)
    k = skew(omega)
    return torch.eye(3, dtype=omega.dtype, device=omega.device) + a * k + b * (k @ k)


def axis_angle_to_quaternion(omega: torch.Tensor) -> torch.Tensor:
    """(*, 3) axis-angle vectors -> (*, 4) WXYZ unit quaternions."""
    return kc.axis_angle_to_quaternion(omega)


def quaternion_to_axis_angle(q: torch.Tensor) -> torch.Tensor:
    """(*, 4) WXYZ quaternions -> (*, 3) axis-angle vectors with angle in [0, pi]."""
    q = kc.normalize_quaternion(q)
    # q and -q are one rotation; the positive-w representative gives the short angle.
    q = torch.where(q[..., :1] < 0, -q, q)
    return kc.quaternion_to_axis_angle(q)


def matrix_to_axis_angle(rot: torch.Tensor) -> torch.Tensor:
    """(*, 3, 3) rotation matrices -> (*, 3) axis-angle vectors."""
    shape = rot.shape[:-2]
    return kc.rotation_matrix_to_axis_angle(rot.reshape(-1, 3, 3)).reshape(*shape, 3)


def rotation_angle_deg(rot_a: torch.Tensor, rot_b: torch.Tensor) -> torch.Tensor:
    """Angle in degrees of the rotation taking ``rot_a`` to ``rot_b``, both (*, 3, 3)."""
    rel = rot_b @ rot_a.transpose(-1, -2)
    # atan2 of the sine (from the antisymmetric part) and the cosine (from the trace): arccos of
    # the cosine alone loses small angles to rounding (a float32 matrix against itself: 0.03 deg).
    cos = (rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
    anti = rel - rel.transpose(-1, -2)
    sin = torch.stack((anti[..., 2, 1], anti[..., 0, 2], anti[..., 1, 0]), -1).norm(dim=-1) / 2
    return torch.rad2deg(torch.atan2(sin, cos))


def exposure_rotations(rot0: torch.Tensor, omega: torch.Tensor, taus: torch.Tensor) -> torch.Tensor:
    """Rotations R(tau) = exp(tau * omega) @ R0 at the exposure times ``taus``.

    Args:
        rot0: (3, 3) rotation at the start of the exposure.
        omega: (3,) axis-angle of the rotation made during the whole exposure.
        taus: (T,) times in [0, 1].

    Returns:
        (T, 3, 3) rotations.
    """
    return axis_angle_to_matrix(taus[:, None] * omega[None, :]) @ rot0
