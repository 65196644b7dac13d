"""Writing a fitted object to disk: textured meshes (OBJ + MTL + PNG, GLB) and its motion.

Every file is written atomically. Meshes are exported at unit scale in the object's own frame
(its pose lives in the motion record), with per-corner UVs split into per-vertex UVs as mesh
formats require, and v flipped to their bottom-left texture origin.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import torch
import trimesh
from PIL import Image

from sfb_video.atomic import atomic_write_bytes, write_json
from sfb_video.config import RenderConfig
from sfb_video.crop import Crop
from sfb_video.fitting.frame import FitResult
from sfb_video.geometry.rotation import matrix_to_axis_angle
from sfb_video.imageio import to_uint8, write_image
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState


def to_trimesh(state: ObjectState) -> trimesh.Trimesh:
    """The textured mesh of ``state`` as a trimesh (one vertex per distinct vertex/UV pair)."""
    faces = state.topology.faces.cpu().reshape(-1).long()
    face_uvs = state.topology.face_uvs.cpu().reshape(-1).long()
    # One key per (vertex, UV) pair, ordered as the pairs are: a unique of numbers, not of rows
    # (torch's unique over a dimension took 23 ms a mesh, a frame's export writes one per object).
    count = state.topology.uvs.shape[0]
    unique, inverse = torch.unique(faces * count + face_uvs, return_inverse=True)
    vertices = state.vertices.detach().cpu()[unique // count].numpy()
    uv = state.topology.uvs.cpu()[unique % count].numpy().copy()
    uv[:, 1] = 1 - uv[:, 1]
    image = Image.fromarray(to_uint8(state.texture))
    visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
    return trimesh.Trimesh(vertices, inverse.reshape(-1, 3).numpy(), visual=visual, process=False)


def write_obj(state: ObjectState, folder: Path, name: str = "mesh") -> None:
    """Write ``name``.obj, ``name``.mtl and ``name``.png into ``folder``."""
    text, files = trimesh.exchange.obj.export_obj(
        to_trimesh(state), include_texture=True, return_texture=True, mtl_name=f"{name}.mtl"
    )
    # trimesh names the texture material_0.png; rename it so several meshes can share a folder.
    texture_name = next(k for k in files if k.endswith(".png"))
    mtl = files[f"{name}.mtl"].decode().replace(texture_name, f"{name}.png")
    atomic_write_bytes(folder / f"{name}.png", files[texture_name])
    atomic_write_bytes(folder / f"{name}.mtl", mtl.encode())
    atomic_write_bytes(folder / f"{name}.obj", text.encode())


def write_glb(state: ObjectState, path: Path) -> None:
    """Write the textured mesh as a binary glTF file."""
    atomic_write_bytes(path, to_trimesh(state).export(file_type="glb"))


def motion_record(motion: Motion) -> dict[str, Any]:
    """The motion as JSON-ready data: camera coordinates in object sizes, angles in degrees."""
    omega = motion.omega.detach().cpu()
    return {
        "x0": motion.x0.tolist(),
        "dx": motion.dx.tolist(),
        "x1": (motion.x0 + motion.dx).tolist(),
        "rotation0_axis_angle_deg": torch.rad2deg(matrix_to_axis_angle(motion.rot0.cpu())).tolist(),
        "rotation_axis_angle_deg": torch.rad2deg(omega).tolist(),
        "rotation_angle_deg": math.degrees(float(omega.norm())),
        "travel_object_sizes": float(motion.dx.norm()),
    }


def write_fit(
    folder: Path, fit: FitResult, crop: Crop, tsr: int, render_config: RenderConfig, masks: torch.Tensor | None
) -> None:
    """Everything a single-frame fit produced, into ``folder``.

    Files: reconstruction.png (input | I_hat | 4x residual, in the crop), tsr.png (``tsr``
    sub-frames over the background), masks.png (the (N, h, w) sub-frame ``masks`` the fit used,
    when it used any), mesh.obj/.mtl/.png and mesh.glb, fit.json (prototype, losses, masks,
    motion, boxes, camera, timing) and loss_curve.csv.
    """
    residual = (crop.image - fit.reconstruction).abs().mul(4).clamp(0, 1)
    write_image(folder / "reconstruction.png", torch.cat((crop.image, fit.reconstruction, residual), dim=2))
    subframes = fit.state.render_subframes(crop.camera, crop.background, tsr, render_config)
    write_image(folder / "tsr.png", torch.cat(list(subframes), dim=2))
    if masks is not None:
        write_image(folder / "masks.png", torch.cat(list(masks), dim=1).expand(3, -1, -1))
    write_obj(fit.state, folder)
    write_glb(fit.state, folder / "mesh.glb")
    write_json(
        folder / "fit.json",
        {
            "prototype": fit.prototype,
            "losses": fit.losses,
            "iterations": fit.iterations,
            "seconds": fit.seconds,
            "masks": "diff" if masks is None else "defmo",
            "crop_box": list(crop.box),
            "crop_size": list(crop.image.shape[1:][::-1]),
            "crop_camera": dataclasses.asdict(crop.camera),
            "motion": motion_record(fit.state.motion),
        },
    )
    names = list(fit.curves[fit.prototype][0])
    lines = ["prototype,step," + ",".join(names)]
    for proto, curve in fit.curves.items():
        lines += [f"{proto},{i}," + ",".join(f"{r[n]:.6g}" for n in names) for i, r in enumerate(curve)]
    atomic_write_bytes(folder / "loss_curve.csv", ("\n".join(lines) + "\n").encode())
