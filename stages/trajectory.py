"""The trajectory's rows (``trajectory.csv``): per sub-frame of a fitted frame, and between a
joint window's exposures, the time, image and 3D position, speed, orientation and spin."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from sfb_video.atomic import atomic_write_bytes
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.rotation import matrix_to_axis_angle
from sfb_video.model.formation import exposure_times
from sfb_video.model.trajectory import Trajectory
from sfb_video.registration import to_frame
from sfb_video.results import FrameResult


def trajectory_rows(
    result: FrameResult, camera: PinholeCamera, n: int, fps: float, exposure_fraction: float, diameter: float | None
) -> Iterator[dict[str, float | int | str]]:
    """One CSV row per sub-frame of a fitted frame, at the sub-frame's mid-time
    (``in_exposure`` 1).

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
    times = (result.index + taus * exposure_fraction) / fps
    yield from _rows(result.index, 1, times, uv, positions, axis_angles, [speed] * n, spin, diameter)


def gap_rows(
    trajectory: Trajectory, index: int, camera: PinholeCamera, n: int, fps: float, diameter: float | None
) -> Iterator[dict[str, float | int | str]]:
    """``n`` CSV rows (``in_exposure`` 0) on a joint trajectory between the end of frame
    ``index``'s exposure and the start of the next, evenly spaced in time."""
    e = trajectory.exposure_fraction
    k = torch.arange(n, dtype=torch.float32)
    t = trajectory.time(index) + e + (k + 0.5) / n * (1 - e)
    positions, rotations = trajectory.positions(t), trajectory.rotations(t)
    uv, _ = camera.project(positions)
    speed = (trajectory.speed(t) * fps).tolist()
    spin = math.degrees(float(trajectory.spin.norm())) * fps
    axis_angles = torch.rad2deg(matrix_to_axis_angle(rotations))
    times = (t + trajectory.first_frame) / fps
    yield from _rows(index, 0, times, uv, positions, axis_angles, speed, spin, diameter)


def _rows(
    index: int,
    in_exposure: int,
    times: torch.Tensor,
    uv: torch.Tensor,
    positions: torch.Tensor,
    axis_angles: torch.Tensor,
    speeds: list[float],
    spin: float,
    diameter: float | None,
) -> Iterator[dict[str, float | int | str]]:
    for k in range(times.shape[0]):
        row: dict[str, float | int | str] = {
            "frame": index,
            "subframe": k,
            "in_exposure": in_exposure,
            "time_s": float(times[k]),
            "u_px": float(uv[k, 0]),
            "v_px": float(uv[k, 1]),
            "x": float(positions[k, 0]),
            "y": float(positions[k, 1]),
            "z": float(positions[k, 2]),
            "speed_sizes_per_s": speeds[k],
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
                speed_m_per_s=speeds[k] * diameter,
                speed_km_per_h=speeds[k] * diameter * 3.6,
            )
        yield row


def to_frame_pixels(rows: list[dict[str, float | int | str]], to_canvas: np.ndarray) -> None:
    """Move the rows' image positions from the canvas's pixels into the frame's own (the 3D
    positions stay in the reference camera)."""
    uv = torch.tensor([[float(r["u_px"]), float(r["v_px"])] for r in rows], dtype=torch.float64)
    for row, (u, v) in zip(rows, to_frame(uv, to_canvas).tolist(), strict=True):
        row["u_px"], row["v_px"] = u, v


def write_csv(path: Path, rows: list[dict[str, float | int | str]]) -> None:
    """Write ``rows`` (dicts sharing keys) as CSV, atomically; floats with 6 significant digits."""
    buffer = io.StringIO()
    names = list(rows[0]) if rows else ["frame"]
    writer = csv.DictWriter(buffer, fieldnames=names, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: f"{v:.6g}" if isinstance(v, float) else v for k, v in row.items()})
    atomic_write_bytes(path, buffer.getvalue().encode())
