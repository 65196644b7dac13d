"""The built-in demo: a textured prototype tumbling through one exposure over a photo.

It exercises the whole forward path (prototype, pose over the exposure, renderer, formation
model) and shows what the fitter will later invert: the blurred frame and its sharp sub-frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from sfb_video.config import Config
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.geometry.rotation import axis_angle_to_matrix, exposure_rotations
from sfb_video.model.formation import composite, exposure_times, subframes
from sfb_video.render import MeshRenderer
from sfb_video.synth.backgrounds import make_background


@dataclass(frozen=True)
class DemoResult:
    """The demo's images, all (3, H, W) in [0, 1] except ``subframes`` (N, 3, H, W)."""

    blurred: torch.Tensor
    background: torch.Tensor
    subframes: torch.Tensor


def demo_texture(size: int) -> torch.Tensor:
    """(3, size, size) a colourful checker with a stripe, so rotation is visible."""
    y, x = torch.meshgrid(torch.linspace(0, 1, size), torch.linspace(0, 1, size), indexing="ij")
    checker = ((x * 6).floor() + (y * 3).floor()) % 2
    red = torch.stack((torch.full_like(x, 0.9), torch.full_like(x, 0.2), torch.full_like(x, 0.1)))
    yellow = torch.stack((torch.full_like(x, 0.95), torch.full_like(x, 0.85), torch.full_like(x, 0.2)))
    texture = torch.where(checker.bool(), red, yellow)
    stripe = ((y - 0.5).abs() < 0.06).float()
    return texture * (1 - stripe) + 0.1 * stripe


def run_demo(config: Config, device: torch.device) -> DemoResult:
    """Render the demo scene described by ``config.demo`` through ``config.camera``."""
    demo = config.demo
    camera = PinholeCamera.from_fov(demo.width, demo.height, config.camera.fov_y_deg)
    verts, topology = load_prototype(demo.prototype)
    steps = demo.subframes * max(1, math.ceil(config.render.time_steps / demo.subframes))
    taus = exposure_times(steps, device)
    travel = torch.tensor(demo.travel, device=device)
    start = torch.tensor([0.0, 0.0, demo.depth], device=device) - travel / 2
    rot0 = axis_angle_to_matrix(torch.tensor([0.4, 0.0, 0.3], device=device))
    omega = torch.deg2rad(torch.tensor(demo.rotation_deg, device=device))
    rotations = exposure_rotations(rot0, omega, taus)
    posed = pose_vertices(verts.to(device), rotations, start + taus[:, None] * travel)
    renderer = MeshRenderer(camera, config.render)
    photo, _ = make_background(np.random.default_rng(0), demo.width, demo.height, "coffee", (1.0, 1.0))
    background = torch.from_numpy(photo).permute(2, 0, 1).float().div(255).to(device)
    with torch.no_grad():
        out = renderer(posed, topology.to(device), demo_texture(demo.texture_size).to(device))
        return DemoResult(
            blurred=composite(out.rgb, out.alpha, background).cpu(),
            background=background.cpu(),
            subframes=subframes(out.rgb, out.alpha, background, demo.subframes).cpu(),
        )
