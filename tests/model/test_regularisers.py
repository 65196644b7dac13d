import pytest
import torch

from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model import regularisers


def _noisy_sphere(dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    verts, topo = load_prototype("sphere")
    generator = torch.Generator().manual_seed(0)
    return (verts + 0.02 * torch.randn(verts.shape, generator=generator)).to(dtype), topo.edges


def test_texture_tv_gradient_matches_finite_differences() -> None:
    texture = torch.rand(3, 6, 7, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    assert torch.autograd.gradcheck(regularisers.texture_tv, (texture.requires_grad_(),))


def test_laplacian_gradient_matches_finite_differences() -> None:
    verts, edges = _noisy_sphere(torch.float64)
    assert torch.autograd.gradcheck(lambda v: regularisers.laplacian(v, edges), (verts.requires_grad_(),))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_compiled_passes_match_the_tensor_versions(dtype: torch.dtype) -> None:
    # Including ties (a flat patch), where abs's derivative is taken as 0 by both.
    texture = torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(2)).to(dtype)
    texture[:, :4, :4] = 0.5
    verts, edges = _noisy_sphere(dtype)
    tol = {"rtol": 1e-5, "atol": 1e-7} if dtype == torch.float32 else {"rtol": 1e-10, "atol": 1e-12}
    for compiled, tensors, args in (
        (regularisers.texture_tv, regularisers.texture_tv_tensors, (texture,)),
        (lambda v: regularisers.laplacian(v, edges), lambda v: regularisers.laplacian_tensors(v, edges), (verts,)),
    ):
        results = []
        for function in (compiled, tensors):
            x = args[0].clone().requires_grad_()
            value = function(x)
            (3 * value).backward()
            results.append((value.detach(), x.grad))
        assert torch.allclose(results[0][0], results[1][0], **tol)
        assert torch.allclose(results[0][1], results[1][1], **tol)
