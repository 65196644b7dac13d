"""The compiled differentiable half of the renderer (sfb_video/render/fused.py) against the
tensor version, the reference's twin: the same values and gradients, for the renders, the
blurred image composited from them and the region they sweep."""

from __future__ import annotations

import pytest
import torch

from sfb_video.config import RenderConfig
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model.formation import blend
from sfb_video.render import MeshRenderer, fused, kernels, rasterize
from sfb_video.render.shader import shade

# float64: rounding apart, the same numbers; float32 (the fitter's): within float32's rounding.
TOLERANCE = {torch.float64: (1e-12, 1e-9), torch.float32: (1e-5, 2e-5)}


def _scene(dtype: torch.dtype, prototype: str) -> tuple[torch.Tensor, object, torch.Tensor, torch.Tensor]:
    torch.manual_seed(0)
    verts, topo = load_prototype(prototype)
    poses = torch.tensor([[0.1, 0.05, 2.5], [0.35, -0.1, 2.8], [0.5, 0.2, 2.6]])
    verts = (verts[None] + poses[:, None]).to(dtype)
    verts = verts + 0.03 * torch.randn_like(verts)
    return verts, topo, torch.rand(3, 8, 8, dtype=dtype), torch.rand(3, 48, 64, dtype=dtype)


def _run(blur: bool, compiled: bool, dtype: torch.dtype, prototype: str) -> list[torch.Tensor]:
    verts, topo, texture, background = _scene(dtype, prototype)
    camera, settings = PinholeCamera.from_fov(64, 48, 45.0), RenderConfig(sigma_inv=2000.0)
    v, tex = verts.clone().requires_grad_(), texture.clone().requires_grad_()
    weights = torch.rand(3, 3, 48, 64, generator=torch.Generator().manual_seed(1), dtype=dtype)
    if compiled:
        renderer = MeshRenderer(camera, settings)
        assert renderer._compiled(v, tex)
        if blur:
            image, alpha = renderer.blurred(v, topo, tex, background)
        else:
            out = renderer(v, topo, tex)
            image, alpha = out.rgb, out.alpha
    else:
        out = shade(rasterize(v, topo, camera, settings), topo, tex, settings.sigma_inv)
        image, alpha = (blend(out.rgb, out.alpha, background), out.alpha) if blur else (out.rgb, out.alpha)
    loss = (image * (weights[0] if blur else weights)).sum() + 3 * (alpha * weights[:, :1]).sum()
    loss.backward()
    return [image.detach(), alpha.detach(), v.grad, tex.grad]


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("blur", [False, True])
@pytest.mark.parametrize("prototype", ["sphere", "torus"])
def test_compiled_passes_match_the_tensor_version(dtype: torch.dtype, blur: bool, prototype: str) -> None:
    compiled, tensor = _run(blur, True, dtype, prototype), _run(blur, False, dtype, prototype)
    value_tol, grad_tol = TOLERANCE[dtype]
    for name, a, b in zip(("image", "alpha", "vertex grad", "texture grad"), compiled, tensor, strict=True):
        scale = float(b.abs().max())
        assert scale > 0.1, name  # the comparison is not between two zeros
        tol = value_tol if name in ("image", "alpha") else grad_tol
        assert float((a - b).abs().max()) <= tol * max(scale, 1.0), name


def test_compiled_swept_region_matches_the_product_in_values_and_gradients() -> None:
    alpha = torch.rand(5, 6, 7, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    alpha[1, 2, 3] = 1.0  # inside the silhouette: a product with a zero factor
    alpha[:, 0, 0] = 0.0  # untouched by the object
    assert fused.available(alpha, alpha)
    a, b = alpha.clone().requires_grad_(), alpha.clone().requires_grad_()
    weights = torch.rand(6, 7, dtype=torch.float64)
    (fused.swept(a) * weights).sum().backward()
    ((1 - (1 - b).prod(0)) * weights).sum().backward()
    assert torch.allclose(fused.swept(alpha), 1 - (1 - alpha).prod(0), atol=1e-14)
    assert torch.allclose(a.grad, b.grad, atol=1e-14)
    assert torch.autograd.gradcheck(fused.swept, (alpha[:, 1:, 1:].clone().requires_grad_(),))


@pytest.mark.skipif(kernels.njit is None, reason="numba is not installed")
def test_the_passes_give_the_same_bits_on_one_thread_and_on_several() -> None:
    import numba

    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = _run(True, True, torch.float32, "torus")
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        several = _run(True, True, torch.float32, "torus")
    finally:
        numba.set_num_threads(threads)
    for a, b in zip(one, several, strict=True):
        assert torch.equal(a, b)
