"""Stage 5, export: saved frame results -> tsr.mp4, trajectory.csv, meshes/, recording.rrd.

Everything here is rendered from the results saved in the run folder and the clip itself, so
``sfb-video export`` can redo it at another TSR factor without fitting again. The clip is
streamed once and each result loaded only for its frame. Every file is written atomically.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from sfb_video.atomic import atomic_write_bytes
from sfb_video.config import Config
from sfb_video.crop import Box
from sfb_video.export import motion_record, write_glb, write_obj
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.rotation import matrix_to_axis_angle
from sfb_video.imageio import as_float
from sfb_video.model.formation import exposure_times
from sfb_video.recording import Recorder
from sfb_video.results import FrameResult, load_result
from sfb_video.run_folder import BEST_MESH, MESHES, RECORDING, TSR_VIDEO, ensure_folder, frame_path, mesh_path
from sfb_video.video import VideoWriter
from stages.background import FrameWithBackground
from stages.detect import difference_mask


class Pasted(Sequence[torch.Tensor]):
    """Full frames, each the input frame with one patch pasted into a box; made one at a time
    when asked for, so that N sub-frames of a large frame are never all in memory.

    Args:
        frame: (3, H, W) the input frame, uint8 or float32 in [0, 1]; the frames come out in
            its dtype (uint8 keeps a 4K frame at 25 MB).
        patches: (N, 3, h, w) float32 in [0, 1], what replaces the box in each frame.
        box: (x, y, w, h) where.
    """

    def __init__(self, frame: torch.Tensor, patches: torch.Tensor, box: Box) -> None:
        if frame.dtype == torch.uint8:
            patches = patches.mul(255).clamp_(0, 255).round_().to(torch.uint8)
        self.frame, self.patches, self.box = frame, patches, box

    def __len__(self) -> int:
        return self.patches.shape[0]

    def __getitem__(self, k: int) -> torch.Tensor:  # type: ignore[override]
        if not -len(self) <= k < len(self):
            raise IndexError(k)
        x, y, w, h = self.box
        full = self.frame.clone()
        full[:, y : y + h, x : x + w] = self.patches[k]
        return full


@dataclass(frozen=True)
class Rendered:
    """One frame rendered from its result, full-frame.

    Attributes:
        reconstruction: (3, H, W) I_hat: the frame with the blurred model inside the crop box.
        subframes: N full frames (3, H, W), the sharp sub-frames, made one at a time.
        Both in the dtype the frame is kept in (uint8 or float32, :func:`as_float`).
    """

    reconstruction: torch.Tensor
    subframes: Pasted


def _resize(images: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """(..., 3, h, w) images resized to ``size`` (width, height), bilinear with antialiasing."""
    if images.shape[-2:] == (size[1], size[0]):
        return images
    batch = images.reshape(-1, *images.shape[-3:])
    out = F.interpolate(batch, size=(size[1], size[0]), mode="bilinear", antialias=True, align_corners=False)
    return out.reshape(*images.shape[:-2], size[1], size[0])


def render_frame(
    frame: FrameWithBackground, result: FrameResult, camera: PinholeCamera, n: int, config: Config
) -> Rendered:
    """Render ``result`` into its crop box and paste it into the frame.

    Outside the box the input frame is kept (so other movers stay as they were); inside it the
    background with the model composited over it replaces the streak. A box wider than
    ``render.export_max_width`` is rendered at that width and the object scaled up onto it.
    """
    x, y, w, h = result.crop_box
    scale = min(1.0, config.render.export_max_width / w)
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    patch_bg = as_float(frame.background_pixels[:, y : y + h, x : x + w])
    small_bg = _resize(patch_bg, size)
    patches = result.state.render_subframes(camera.crop(x, y, w, h, *size), small_bg, n, config.render)
    if size != (w, h):
        # Only the object is scaled up; the background keeps the frame's own pixels.
        patches = patch_bg + _resize(patches - small_bg, (w, h))
    reconstruction = Pasted(frame.pixels, patches.mean(0, keepdim=True), result.crop_box)[0]
    return Rendered(reconstruction, Pasted(frame.pixels, patches, result.crop_box))


def trajectory_rows(
    result: FrameResult, camera: PinholeCamera, n: int, fps: float, exposure_fraction: float, diameter: float | None
) -> Iterator[dict[str, float | int | str]]:
    """One CSV row per sub-frame of a fitted frame, at the sub-frame's mid-time.

    Positions are in the camera frame (x right, y down, z forward) in object sizes, and in metres
    when the object's ``diameter`` (metres) is known; the rotation is the object's orientation as
    an axis-angle vector in degrees.
    """
    motion = result.state.motion
    taus = exposure_times(n)
    rotations, positions = motion.at(taus)
    uv, _ = camera.project(positions)
    exposure_s = exposure_fraction / fps
    speed = float(motion.dx.norm()) / exposure_s
    spin = math.degrees(float(motion.omega.norm())) / exposure_s
    axis_angles = torch.rad2deg(matrix_to_axis_angle(rotations))
    for k in range(n):
        row: dict[str, float | int | str] = {
            "frame": result.index,
            "subframe": k,
            "time_s": (result.index + float(taus[k]) * exposure_fraction) / fps,
            "u_px": float(uv[k, 0]),
            "v_px": float(uv[k, 1]),
            "x": float(positions[k, 0]),
            "y": float(positions[k, 1]),
            "z": float(positions[k, 2]),
            "speed_sizes_per_s": speed,
            "rot_x_deg": float(axis_angles[k, 0]),
            "rot_y_deg": float(axis_angles[k, 1]),
            "rot_z_deg": float(axis_angles[k, 2]),
            "spin_deg_per_s": spin,
        }
        if diameter is not None:
            row.update(
                x_m=row["x"] * diameter,
                y_m=row["y"] * diameter,
                z_m=row["z"] * diameter,
                speed_m_per_s=speed * diameter,
                speed_km_per_h=speed * diameter * 3.6,
            )
        yield row


def write_csv(path: Path, rows: list[dict[str, float | int | str]]) -> None:
    """Write ``rows`` (dicts sharing keys) as CSV, atomically; floats with 6 significant digits."""
    buffer = io.StringIO()
    names = list(rows[0]) if rows else ["frame"]
    writer = csv.DictWriter(buffer, fieldnames=names, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: f"{v:.6g}" if isinstance(v, float) else v for k, v in row.items()})
    atomic_write_bytes(path, buffer.getvalue().encode())


@dataclass
class Exported:
    """What streaming the clip through the exports gathered.

    Attributes:
        video_frames: frames written to ``tsr.mp4``.
        rows: trajectory rows (:func:`trajectory_rows`) of every fitted frame.
        fits: per fitted frame, what ``summary.json`` reports of it.
        best: the fitted frame with the lowest image loss, or None.
    """

    video_frames: int = 0
    rows: list[dict[str, float | int | str]] = field(default_factory=list)
    fits: dict[int, dict[str, Any]] = field(default_factory=dict)
    best: int | None = None


def _mask_order(result: FrameResult) -> str | None:
    """Whether a fit's sub-frame masks kept their own order ("as given") or were "reversed" to
    join the track (which wins over DeFMO's order: one blurred image cannot fix it); None
    without sub-frame masks."""
    if result.masks is None:
        return None
    return "reversed" if result.masks_reversed else "as given"


def _fit_record(result: FrameResult, speed: float, diameter: float | None) -> dict[str, Any]:
    record: dict[str, Any] = {
        "start": result.start,
        "prototype": result.prototype,
        "losses": result.losses,
        "iterations": len(result.curve),
        "seconds": result.seconds,
        "masks": result.mask_source,
        "speed_sizes_per_s": speed,
        "motion": motion_record(result.state.motion),
    }
    order = _mask_order(result)
    if order is not None:
        record["masks_order"] = order
    if diameter is not None:
        record["speed_km_per_h"] = speed * diameter * 3.6
    return record


def export_frames(
    folder: Path,
    frames: Iterator[FrameWithBackground],
    detections: dict[int, tuple[int, int, int, int] | None],
    camera: PinholeCamera,
    fps: float,
    n: int,
    config: Config,
    name: str,
    diameter: float | None,
) -> Exported:
    """Stream the clip once and write ``tsr.mp4`` (N sub-frames per fitted frame, the frame N
    times otherwise), ``recording.rrd`` and ``meshes/frame_XXXXX.glb``, loading each frame's
    saved result only while it is needed, so memory does not grow with the clip."""
    done = Exported()
    trajectory: list[np.ndarray] = []
    best_loss = math.inf
    ensure_folder(folder / MESHES)
    with (
        VideoWriter(folder / TSR_VIDEO, fps * n, camera.width, camera.height) as video,
        Recorder(folder / RECORDING, camera, name) as recorder,
    ):
        for frame in frames:
            recorder.log_frame(frame.index, frame.pixels, frame.background_pixels)
            mask = difference_mask(frame.pixels, frame.background_pixels, config.detect)
            recorder.log_detection(frame.index, detections.get(frame.index), mask)
            path = frame_path(folder, frame.index)
            if not path.is_file():
                for _ in range(n):
                    video.write(frame.pixels)
                continue
            result = load_result(path)
            rendered = render_frame(frame, result, camera, n, config)
            for sub in rendered.subframes:
                video.write(sub)
            recorder.log_fit(
                frame.index, result.state, rendered.reconstruction, rendered.subframes, result.losses, result.curve
            )
            order = _mask_order(result)
            source = result.mask_source if order is None else f"{result.mask_source}, order {order}"
            recorder.log_masks(frame.index, source, result.crop_box, result.masks, n)
            trajectory.append(result.state.motion.at(exposure_times(n))[1].numpy())
            recorder.log_trajectory(np.concatenate(trajectory))
            write_glb(result.state, mesh_path(folder, frame.index))
            rows = list(trajectory_rows(result, camera, n, fps, config.video.exposure_fraction, diameter))
            done.rows += rows
            done.fits[frame.index] = _fit_record(result, float(rows[0]["speed_sizes_per_s"]), diameter)
            if result.losses["image"] < best_loss:
                best_loss, done.best = result.losses["image"], frame.index
        done.video_frames = video.frames_written
    if done.best is not None:
        write_obj(load_result(frame_path(folder, done.best)).state, ensure_folder(folder / BEST_MESH), name="mesh")
    return done
