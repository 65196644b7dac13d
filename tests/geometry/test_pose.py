import torch

from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.rotation import axis_angle_to_matrix


def test_pose_matches_the_formula_and_finite_differences() -> None:
    generator = torch.Generator().manual_seed(0)
    vertices = torch.randn(9, 3, generator=generator, dtype=torch.float64)
    rotations = axis_angle_to_matrix(torch.randn(4, 3, generator=generator, dtype=torch.float64))
    translations = torch.randn(4, 3, generator=generator, dtype=torch.float64)
    posed = pose_vertices(vertices, rotations, translations)
    assert torch.allclose(posed[2, 5], rotations[2] @ vertices[5] + translations[2])
    inputs = (vertices.requires_grad_(), rotations.requires_grad_(), translations.requires_grad_())
    assert torch.autograd.gradcheck(pose_vertices, inputs)
