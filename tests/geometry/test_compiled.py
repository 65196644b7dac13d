import pytest
import torch

from sfb_video.geometry import compiled
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import normalize_vertices
from sfb_video.geometry.rotation import axis_angle_to_matrix

CAMERA = PinholeCamera.from_fov(64, 48, 45.0).crop(5, 3, 40, 30, 80, 60)


def _inputs(dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(0)
    vertices = torch.randn(9, 3, generator=generator, dtype=dtype)
    rotations = axis_angle_to_matrix(torch.randn(4, 3, generator=generator, dtype=dtype))
    translations = torch.randn(4, 3, generator=generator, dtype=dtype) * 0.1 + torch.tensor(
        [0.0, 0.0, 4.0], dtype=dtype
    )
    return vertices, rotations, translations


def _cases(dtype: torch.dtype) -> list[tuple]:
    """(compiled, formula, inputs) for each pass; outputs are flattened into one tensor."""
    vertices, rotations, translations = _inputs(dtype)
    posed = torch.einsum("tij,vj->tvi", rotations, vertices) + translations[:, None]
    flat = lambda pair: torch.cat((pair[0].reshape(-1), pair[1].reshape(-1)))  # noqa: E731
    return [
        (compiled.normalize_vertices, normalize_vertices, (vertices,)),
        (
            compiled.pose_vertices,
            lambda v, r, t: torch.einsum("tij,vj->tvi", r, v) + t[:, None],
            (vertices, rotations, translations),
        ),
        (lambda p: flat(compiled.project(p, CAMERA)), lambda p: flat(CAMERA.project(p)), (posed,)),
    ]


@pytest.mark.parametrize("index", range(3))
def test_the_compiled_pass_matches_finite_differences(index: int) -> None:
    function, _, inputs = _cases(torch.float64)[index]
    assert torch.autograd.gradcheck(function, tuple(x.clone().requires_grad_() for x in inputs))


@pytest.mark.parametrize("index", range(3))
def test_the_compiled_pass_matches_the_formula(index: int) -> None:
    # float32, as a fit runs: values and gradients within float32 rounding of the formula's.
    function, formula, inputs = _cases(torch.float32)[index]
    results = []
    for f in (function, formula):
        leaves = tuple(x.clone().requires_grad_() for x in inputs)
        out = f(*leaves)
        weights = torch.linspace(-1, 1, out.numel()).reshape(out.shape)
        (out * weights).sum().backward()
        results.append((out.detach(), *(x.grad for x in leaves)))
    for a, b in zip(*results, strict=True):
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-5)
