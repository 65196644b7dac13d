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


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """(*, 4) WXYZ quaternions (normalised here) -> (*, 3, 3) rotation matrices."""
    return kc.quaternion_to_rotation_matrix(kc.normalize_quaternion(q))


def axis_angle_to_matrix(omega: torch.Tensor) -> torch.Tensor:
    """(*, 3) axis-angle vectors -> (*, 3, 3) rotation matrices (exact also at angle 0)."""
    shape = omega.shape[:-1]
    return kc.axis_angle_to_rotation_matrix(omega.reshape(-1, 3)).reshape(*shape, 3, 3)


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
    cos = ((rel.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1.0, 1.0)
    return torch.rad2deg(torch.arccos(cos))


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
