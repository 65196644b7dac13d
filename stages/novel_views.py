"""Novel views: a turntable of a fitted mesh, rendered from a saved run.

The mesh of a chosen frame is placed in front of a camera of the clip's field of view, at the
distance where it fills about half the image height, and turned a full revolution about the
image's vertical axis; the views go into ``novel_views/frame_XXXXX.mp4`` and a PNG strip.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from sfb_video.config import CameraConfig, Config, RenderConfig
from sfb_video.errors import SfbError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.pose import pose_vertices
from sfb_video.geometry.rotation import axis_angle_to_matrix
from sfb_video.imageio import write_image
from sfb_video.model.scene import ObjectState
from sfb_video.render import MeshRenderer
from sfb_video.run_folder import NOVEL_VIEWS, ensure_folder, novel_view_path
from sfb_video.stages.run_results import RunResults
from sfb_video.video import OUTPUT_PRESET, VideoWriter

SIZE = (320, 240)
"""Width and height of the turntable images."""
STRIP_VIEWS = 8
"""Views shown side by side in the PNG strip."""


def turntable(
    state: ObjectState, views: int, camera: CameraConfig, render: RenderConfig, background: float = 1.0
) -> torch.Tensor:
    """(views, 3, H, W) the mesh of ``state``, in its start orientation, turned about the vertical.

    Args:
        views: the number of evenly spaced angles over one revolution.
        background: grey level behind the object.
    """
    width, height = SIZE
    pinhole = PinholeCamera.from_fov(width, height, camera.fov_y_deg)
    depth = pinhole.fy / (0.5 * height) * 2 * float(state.vertices.norm(dim=-1).max())
    angles = torch.arange(views) * (2 * math.pi / views)
    axes = torch.stack((torch.zeros(views), angles, torch.zeros(views)), -1)
    rotations = axis_angle_to_matrix(axes) @ state.motion.rot0
    positions = torch.tensor([0.0, 0.0, depth]).expand(views, 3)
    with torch.no_grad():
        out = MeshRenderer(pinhole, render)(
            pose_vertices(state.vertices, rotations, positions), state.topology, state.texture
        )
    return out.rgb * out.alpha + (1 - out.alpha) * background


def write_novel_views(folder: Path, config: Config, frames: list[int], views: int) -> list[Path]:
    """Turntables of the meshes of every object in ``frames`` (the best object when empty);
    returns the videos written."""
    results = RunResults.of_run(folder, config.joint).final()
    if not results:
        raise SfbError(f"{folder} holds no fitted frame to render")
    if views < 2:
        raise SfbError(f"--views must be at least 2, got {views}")
    fitted = sorted({key.index for key in results})
    if not frames:
        keys = [min(results.values(), key=lambda r: r.losses["image"]).key]
    else:
        missing = [f for f in frames if f not in fitted]
        if missing:
            raise SfbError(f"frame {missing[0]} was not fitted; fitted frames: {fitted}")
        keys = sorted(k for k in results if k.index in frames)
    written = []
    for key in keys:
        images = turntable(results[key].state, views, config.camera, config.render)
        ensure_folder(folder / NOVEL_VIEWS)
        path = novel_view_path(folder, key.index, key.track)
        with VideoWriter(path, 24.0, SIZE[0], SIZE[1], preset=OUTPUT_PRESET) as video:
            for image in images:
                video.write(image)
        step = max(1, views // STRIP_VIEWS)
        write_image(path.with_suffix(".png"), torch.cat(list(images[::step][:STRIP_VIEWS]), dim=2))
        written.append(path)
    return written
