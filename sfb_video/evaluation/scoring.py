"""Scoring a recovered object against the truth: the one path that the benchmark runner, the
synthetic tests, the fit benchmark and the demo all take.

Image measures follow the FMO deblurring benchmark (``sfb_video.metrics``): the estimate's
sub-frames on the tight box against the true ones, TIoU from the projected centres, the time
direction flipped where the benchmark would. Where the truth has 3D (generated clips), the
motion is compared at the sub-frames' mid-times, the rotation made during the exposure by its
angle, and the meshes posed at the start of the exposure.
"""

from __future__ import annotations

import numpy as np
import torch

from sfb_video import metrics
from sfb_video.config import RenderConfig
from sfb_video.crop import Box
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.rotation import axis_angle_to_matrix
from sfb_video.model.formation import exposure_times
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.synth.shapes import TexturedMesh
from sfb_video.synth.trajectory import FrameMotion


def render_estimate(
    state: ObjectState, camera: PinholeCamera, box: Box, background: np.ndarray, n: int, settings: RenderConfig
) -> np.ndarray:
    """(N, h, w, 3) float64: the ``n`` sub-frames ``state`` renders on ``box`` of the full-frame
    ``camera``, over the (H, W, 3) ``background`` in [0, 1], or the (n, H, W, 3) one of each
    sub-frame (other objects behind or beside it): what a method hands the benchmark."""
    x, y, w, h = box
    patch = np.ascontiguousarray(background[..., y : y + h, x : x + w, :])
    patch = torch.from_numpy(patch).movedim(-1, -3).float()
    rendered = state.render_subframes(camera.crop(x, y, w, h, w, h), patch, n, settings)
    return rendered.permute(0, 2, 3, 1).numpy().astype(np.float64)


def motion_errors(motion: Motion, truth: FrameMotion, n: int) -> dict[str, float]:
    """3D errors of ``motion`` against the truth at ``n`` sub-frame mid-times.

    Returns:
        translation_err (object sizes) and rotation_err_deg.
    """
    taus = exposure_times(n)
    _, positions = motion.at(taus)
    true_positions = truth.x0[None] + taus.numpy()[:, None].astype(np.float64) * truth.dx[None]
    est_delta = axis_angle_to_matrix(motion.omega.double()).numpy()
    true_delta = axis_angle_to_matrix(torch.from_numpy(truth.omega)).numpy()
    return {
        "translation_err": metrics.translation_error(positions.numpy(), true_positions),
        "rotation_err_deg": metrics.rotation_error_deg(est_delta, true_delta),
    }


def shape_error(state: ObjectState, motion: Motion, truth: FrameMotion, mesh: TexturedMesh) -> float:
    """The paper's mesh distance between ``state``'s mesh and the truth, both posed at the start."""
    vertices = (state.vertices.double() @ motion.rot0.double().T).numpy()
    true_vertices = mesh.vertices.double().numpy() @ truth.rotation.T
    return metrics.mesh_distance(vertices, state.topology.faces.numpy(), true_vertices, mesh.topology.faces.numpy())


def score_estimate(
    state: ObjectState,
    estimate: np.ndarray,
    truth: np.ndarray,
    camera: PinholeCamera,
    true_centres: np.ndarray,
    radius: float,
    truth_3d: tuple[FrameMotion, TexturedMesh] | None = None,
    may_flip: bool = True,
) -> tuple[dict[str, float], bool]:
    """Benchmark measures of one frame's estimate, and 3D errors when the truth has them.

    Args:
        state: the recovered object (its motion gives the estimate's centres).
        estimate, truth: (N, h, w, 3) sub-frames on the tight box, in [0, 1].
        camera: the full-frame camera.
        true_centres: (N, 2) true centres in pixels; radius: the true radius in pixels.
        truth_3d: the true motion and mesh of a generated frame.
        may_flip: reverse the estimate in time where the benchmark would (a video whose
            direction the pipeline resolves is scored without).

    Returns:
        tiou, psnr, ssim (and translation_err, rotation_err_deg, mesh_err with ``truth_3d``),
        and whether the estimate was reversed.
    """
    n = len(true_centres)
    centres = camera.project(state.motion.at(exposure_times(n))[1])[0].numpy()
    scores, flipped = metrics.benchmark_scores(estimate, truth, centres, true_centres, radius, may_flip)
    if truth_3d is not None:
        true_motion, mesh = truth_3d
        motion = state.motion.reversed() if flipped else state.motion
        scores |= motion_errors(motion, true_motion, n)
        scores["mesh_err"] = shape_error(state, motion, true_motion, mesh)
    return scores, flipped
