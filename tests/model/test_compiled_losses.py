from collections.abc import Callable

import pytest
import torch

from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model import losses
from sfb_video.render import kernels


def _noisy_sphere(dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    verts, topo = load_prototype("sphere")
    generator = torch.Generator().manual_seed(0)
    return (verts + 0.02 * torch.randn(verts.shape, generator=generator)).to(dtype), topo.edges


def _terms(dtype: torch.dtype) -> list[tuple[str, Callable[[torch.Tensor], torch.Tensor], torch.Tensor]]:
    """Each compiled term as a function of its differentiable input, with an input for it."""
    generator = torch.Generator().manual_seed(2)
    texture = torch.rand(3, 16, 16, generator=generator).to(dtype)
    texture[:, :4, :4] = 0.5  # ties, where abs's derivative is taken as 0 by both
    verts, edges = _noisy_sphere(dtype)
    mask = (torch.rand(12, 10, generator=generator) > 0.5).to(dtype)
    alpha = torch.rand(4, 1, 12, 10, generator=generator).to(dtype)
    return [
        ("texture_tv", losses.texture_tv, texture),
        ("laplacian", lambda v: losses.laplacian(v, edges), verts),
        ("difference_loss", lambda a: losses.difference_loss(mask, a), alpha),
    ]


@pytest.mark.parametrize("index", range(3))
def test_the_compiled_term_matches_finite_differences(index: int) -> None:
    _, term, x = _terms(torch.float64)[index]
    x = x + 1e-3 * torch.rand(x.shape, dtype=x.dtype, generator=torch.Generator().manual_seed(3))  # no ties
    assert kernels.serves(x)
    assert torch.autograd.gradcheck(term, (x.requires_grad_(),))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_compiled_terms_match_the_tensor_formulas(dtype: torch.dtype, monkeypatch: pytest.MonkeyPatch) -> None:
    tol = {"rtol": 1e-5, "atol": 1e-7} if dtype == torch.float32 else {"rtol": 1e-10, "atol": 1e-12}
    results: list[list[tuple[torch.Tensor, torch.Tensor]]] = [[], []]
    for compiled in (True, False):
        if not compiled:
            monkeypatch.setattr(kernels, "serves", lambda *tensors: False)
        for _, term, x in _terms(dtype):
            x = x.clone().requires_grad_()
            value = term(x)
            (3 * value).backward()
            results[compiled].append((value.detach(), x.grad))
    for name, (a, b) in zip([t[0] for t in _terms(dtype)], zip(*results, strict=True), strict=True):
        assert torch.allclose(a[0], b[0], **tol), name
        assert torch.allclose(a[1], b[1], **tol), name
