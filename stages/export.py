"""Stage 5, export: saved frame results -> tsr.mp4, trajectory.csv, meshes/, recording.rrd.

Everything here is rendered from the results saved in the run folder and the clip itself, so
``sfb-video export`` can redo it at another TSR factor without fitting again. Every file is
written atomically.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from sfb_video.config import Config
from sfb_video.export import write_glb, write_obj
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.rotation import matrix_to_axis_angle
from sfb_video.imageio import atomic_write_bytes
from sfb_video.model.formation import exposure_times, subframes
from sfb_video.recording import Recorder
from sfb_video.results import FrameResult
from sfb_video.video import VideoWriter
from stages.background import FrameWithBackground
from stages.detect import difference_mask

STEPS_PER_SUBFRAME = 4
"""Poses averaged into each rendered sub-frame: enough for the blur within 1/N of an exposure."""


@dataclass(frozen=True)
class Rendered:
    """One frame rendered from its result, full-frame.

    Attributes:
        reconstruction: (3, H, W) I_hat: the frame with the blurred model inside the crop box.
        subframes: (N, 3, H, W) the N sharp sub-frames.
    """

    reconstruction: torch.Tensor
    subframes: torch.Tensor


def render_frame(
    frame: FrameWithBackground, result: FrameResult, camera: PinholeCamera, n: int, config: Config
) -> Rendered:
    """Render ``result`` into its crop box at native resolution and paste it into the frame.

    Outside the box the input frame is kept (so other movers stay as they were); inside it the
    background with the model composited over it replaces the streak.
    """
    x, y, w, h = result.crop_box
    box_camera = camera.crop(x, y, w, h, w, h)
    patch_bg = frame.background[:, y : y + h, x : x + w]
    taus = exposure_times(n * STEPS_PER_SUBFRAME)
    with torch.no_grad():
        out = result.state.render(box_camera, taus, config.render)
        patches = subframes(out.rgb, out.alpha, patch_bg, n)
    frames = frame.image.expand(n, -1, -1, -1).clone()
    frames[:, :, y : y + h, x : x + w] = patches
    reconstruction = frame.image.clone()
    reconstruction[:, y : y + h, x : x + w] = patches.mean(0)
    return Rendered(reconstruction, frames)


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


def write_meshes(folder: Path, results: dict[int, FrameResult]) -> int | None:
    """``meshes/frame_XXXX.glb`` per fitted frame and ``meshes/best/`` (OBJ+PNG) of the frame with
    the lowest image loss; returns that frame's index (None without fits)."""
    for index, result in results.items():
        write_glb(result.state, folder / "meshes" / f"frame_{index:05d}.glb")
    if not results:
        return None
    best = min(results.values(), key=lambda r: r.losses["image"])
    write_obj(best.state, folder / "meshes" / "best", name="mesh")
    return best.index


def export_video_and_recording(
    folder: Path,
    frames: Iterator[FrameWithBackground],
    results: dict[int, FrameResult],
    detections: dict[int, tuple[int, int, int, int] | None],
    camera: PinholeCamera,
    fps: float,
    n: int,
    config: Config,
    name: str,
) -> int:
    """Stream the clip once: write ``tsr.mp4`` (N sub-frames per fitted frame, the frame N times
    otherwise) and ``recording.rrd``. Returns the number of frames in the video."""
    trajectory: list[np.ndarray] = []
    with (
        VideoWriter(folder / "tsr.mp4", fps * n, camera.width, camera.height) as video,
        Recorder(folder / "recording.rrd", camera, name) as recorder,
    ):
        for frame in frames:
            recorder.log_frame(frame.index, frame.image, frame.background)
            result = results.get(frame.index)
            mask = difference_mask(frame.image, frame.background, config.detect)
            recorder.log_detection(frame.index, detections.get(frame.index), mask)
            if result is None:
                for _ in range(n):
                    video.write(frame.image)
                continue
            rendered = render_frame(frame, result, camera, n, config)
            for sub in rendered.subframes:
                video.write(sub)
            recorder.log_fit(
                frame.index, result.state, rendered.reconstruction, rendered.subframes, result.losses, result.curve
            )
            trajectory.append(result.state.motion.at(exposure_times(n))[1].numpy())
            recorder.log_trajectory(np.concatenate(trajectory))
        return video.frames_written
