"""Renderer speed and memory at the paper's setting, printed as a table.

    python -m benchmarks.render [--repeats 20] [--device cpu]

The scene: a 320x240 crop, T = 8 poses over one exposure, a prototype filling about a third of
the crop, a 100x100 texture. Each row gives median milliseconds per call for the forward pass
and forward + backward, and the split of one forward + backward between the searches (hard
visibility and the band, no gradient), the differentiable part (barycentrics, texture,
silhouette) and the backward pass. On the CPU each case runs twice, in one run: all in tensor
operations (as before numba), and compiled (the searches in ``sfb_video.render.kernels``, the
differentiable part in ``sfb_video.render.fused``, what runs by default). Peak memory is the
process's peak resident set size.

A second table times one whole fit step (render, composite, every loss term, backward, Adam)
of the default preset on a generated 320x240 frame's crop as the pipeline makes it (a ball
about 40 px across, so the crop keeps its native resolution), for a cold start's sphere.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import resource
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import torch

from sfb_video.config import RenderConfig, load_config
from sfb_video.evaluation.synthetic import synthetic_crop
from sfb_video.fitting.engine import deterministic
from sfb_video.fitting.frame import FrameObjective, frame_optimisation
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.geometry.rotation import exposure_rotations
from sfb_video.model.motion import MotionParams, streak_from_mask
from sfb_video.model.shape import ShapeParams
from sfb_video.render import MeshRenderer, fused, kernels
from sfb_video.render.rasterizer import find_pixels, interpolate, pixel_unit, project_checked
from sfb_video.render.shader import shade
from sfb_video.synth import ClipSpec, generate_clip


def _median_ms(fn: Callable[[], object], repeats: int, device: torch.device) -> float:
    times = []
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


@contextmanager
def compiled_passes(compiled: bool) -> Iterator[None]:
    """Render with the compiled passes (where numba serves the tensors) or in tensor operations."""
    available = kernels.available, fused.available
    if not compiled:
        kernels.available, fused.available = (lambda points: False), (lambda uv, texture: False)
    try:
        yield
    finally:
        kernels.available, fused.available = available


def bench_case(prototype: str, time_steps: int, repeats: int, device: torch.device) -> dict[str, float | str]:
    camera = PinholeCamera.from_fov(320, 240, 45.0)
    settings = RenderConfig(time_steps=time_steps)
    verts, topo = load_prototype(prototype)
    verts, topo = verts.to(device), topo.to(device)
    # Distance at which the unit-diameter object's disc covers a third of the crop.
    radius_px = math.sqrt(320 * 240 / 3 / math.pi)
    depth = camera.fy * 0.5 / radius_px
    taus = torch.linspace(0, 1, time_steps, device=device)
    rots = exposure_rotations(torch.eye(3, device=device), torch.tensor([0.3, 1.0, 0.2], device=device), taus)
    trans = torch.tensor([-0.15, 0.0, depth], device=device) + taus[:, None] * torch.tensor(
        [0.3, 0.05, 0.0], device=device
    )
    texture = torch.rand(3, 100, 100, device=device, requires_grad=True)
    offsets = torch.zeros_like(verts, requires_grad=True)
    renderer = MeshRenderer(camera, settings)

    def posed() -> torch.Tensor:
        return pose_vertices(verts + offsets, rots, trans)

    def forward() -> object:
        with torch.no_grad():
            return renderer(posed(), topo, texture)

    def forward_backward() -> None:
        out = renderer(posed(), topo, texture)
        (out.rgb.mean() + out.alpha.mean()).backward()

    forward_backward()  # warm-up: allocator and kernels
    coverage = float((forward().face_idx >= 0).float().mean())
    fwd = _median_ms(forward, repeats, device)
    fwd_bwd = _median_ms(forward_backward, repeats, device)

    def split() -> tuple[float, float, float]:
        start = time.perf_counter()
        uv, depth, topology = project_checked(posed(), topo, camera, settings)
        lists = find_pixels(uv.detach(), depth.detach(), topology, camera, settings)
        mid = time.perf_counter()
        if fused.available(uv, texture):
            unit = pixel_unit(camera)
            rgb, alpha = fused.shade_lists(uv, depth, lists, topology, texture, settings.sigma_inv, unit)
        else:
            out = shade(interpolate(uv, depth, lists, topology, camera), topology, texture, settings.sigma_inv)
            rgb, alpha = out.rgb, out.alpha
        loss = rgb.mean() + alpha.mean()
        end_fwd = time.perf_counter()
        loss.backward()
        end = time.perf_counter()
        return mid - start, end_fwd - mid, end - end_fwd

    parts = [split() for _ in range(repeats)]
    search, shading, backward = (1000 * statistics.median(p[i] for p in parts) for i in range(3))
    return {
        "prototype": prototype,
        "faces": topo.num_faces,
        "T": time_steps,
        "coverage": coverage,
        "fwd": fwd,
        "fwd+bwd": fwd_bwd,
        "search": search,
        "shade": shading,
        "backward": backward,
    }


def bench_fit_step(repeats: int, device: torch.device) -> dict[str, float | str]:
    """Median milliseconds of one fit step of the default preset at the pipeline's crop."""
    config = load_config("default")
    clip = generate_clip(ClipSpec(shape="ball", size_px_range=(38.0, 42.0), speed_range=(2.0, 2.2), seed=3))
    crop = synthetic_crop(clip, 0, config)
    crop = dataclasses.replace(
        crop,
        image=crop.image.to(device),
        background=crop.background.to(device),
        object_mask=crop.object_mask.to(device),
    )
    proto, topology = load_prototype("sphere")
    fit = config.fit
    shape = ShapeParams(proto, topology.to(device), fit.texture_size, fit.deform, fit.learn_texture).to(device)
    motion = MotionParams(crop.camera, fit.size_range, fit.max_size_ratio, fit.max_rotation_deg, fit.init_size)
    motion = motion.to(device)
    motion.start_at_streak(streak_from_mask(crop.object_mask))
    objective = FrameObjective(crop, shape, motion, None, fit, config.render)
    step = frame_optimisation(objective, 10 * repeats + 10, early_stop=False)
    with deterministic(device):  # as fit_frame runs it
        step.run(3, None)  # warm-up
        ms = _median_ms(lambda: step.run(1, None), repeats, device)
    height, width = crop.image.shape[1:]
    return {"crop": f"{width}x{height}", "T": config.render.time_steps, "texture": fit.texture_size, "step": ms}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    args = parser.parse_args()
    device = torch.device(args.device)
    base_mb = _peak_rss_mb()
    cases = [("sphere", 8), ("sphere_large", 8), ("torus", 8), ("sphere", 1)]
    modes = ["tensor", "compiled"] if kernels.available(torch.zeros(1, device=device)) else ["tensor"]
    rows = []
    for name, t in cases:
        for mode in modes:
            with compiled_passes(mode == "compiled"):
                rows.append(bench_case(name, t, args.repeats, device) | {"passes": mode})
    print(
        f"device {device}, torch {torch.__version__}, {torch.get_num_threads()} threads, crop 320x240, texture 100x100"
    )
    print(f"median of {args.repeats} calls, milliseconds; search/shade/backward split one forward+backward\n")
    header = "| prototype | faces | T | coverage | passes | fwd | fwd+bwd | search | shade | backward |"
    print(header)
    print("|---|---:|---:|---:|---|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['prototype']} | {r['faces']} | {r['T']} | {r['coverage']:.2f} | {r['passes']} | {r['fwd']:.1f} | "
            f"{r['fwd+bwd']:.1f} | {r['search']:.1f} | {r['shade']:.1f} | {r['backward']:.1f} |"
        )
    print("\none fit step of the default preset (cold start, sphere), median ms\n")
    print("| crop | T | texture | passes | step |")
    print("|---|---:|---:|---|---:|")
    for mode in modes:
        with compiled_passes(mode == "compiled"):
            r = bench_fit_step(args.repeats, device)
        print(f"| {r['crop']} | {r['T']} | {r['texture']} | {mode} | {r['step']:.1f} |")
    peak = _peak_rss_mb()
    print(f"\npeak resident memory: {peak:.0f} MB for the process, {peak - base_mb:.0f} MB added by rendering")
    if device.type == "cuda":
        print(f"peak CUDA memory: {torch.cuda.max_memory_allocated() / 2**20:.0f} MB")


if __name__ == "__main__":
    main()
