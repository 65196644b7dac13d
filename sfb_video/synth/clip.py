"""Blurred frames and clips with ground truth, from many hard renders per exposure.

Frame formation (deliberately not the fitter's soft model): K >= ``sub_exposures`` hard,
supersampled renders (more for fast exposures, see ``ClipSpec.max_step_px``) at exposure
times tau_i = (i + 1/2) / K, each composited over the background, I_i = F_i A_i + (1 - A_i) B,
are averaged; Gaussian noise is added, and the result clipped and quantised to 8 bit.
Sub-frame j of N (the TSR target) averages the renders with tau in [j / N, (j + 1) / N], so
the mean of the N sub-frames is the noise-free blurred frame.

Records hold numpy arrays: images as uint8 RGB (as they would be read from a video), masks as
float32 coverage in [0, 1] quantised to steps of 1/255 (so that an 8-bit PNG holds them
exactly), motion in float64. The mesh is torch, as everywhere in ``sfb_video.geometry``.

Randomness: ``np.random.SeedSequence(spec.seed)`` streams with spawn keys (0,) for the shape and
texture, (1,) for the background, (2,) for the trajectory and (3, k) for frame k's noise, so a
frame's noise does not depend on which other frames are rendered.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from sfb_video.crop import mask_box
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.imageio import to_uint8
from sfb_video.synth.backgrounds import make_background
from sfb_video.synth.raster import pose_points, rasterize
from sfb_video.synth.shapes import TexturedMesh, make_shape
from sfb_video.synth.spec import ClipSpec
from sfb_video.synth.trajectory import FrameMotion, Trajectory, sample_trajectory

_SHAPE_STREAM, _BACKGROUND_STREAM, _TRAJECTORY_STREAM, _NOISE_STREAM = 0, 1, 2, 3


def stream_rng(seed: int, *key: int) -> np.random.Generator:
    """The generator of random stream ``key`` of ``seed`` (see the module docstring)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


def mask_from_levels(levels: np.ndarray) -> np.ndarray:
    """8-bit mask levels (0..255) -> float32 coverage; the one formula both ways round-trip."""
    return (levels.astype(np.float64) / 255.0).astype(np.float32)


@dataclass(frozen=True)
class FrameTruth:
    """Ground truth of one frame.

    Attributes:
        index: the frame's index k in the clip.
        present: whether the object is drawn in this frame.
        motion: the exposure's motion (x0, dx, R0, omega); defined also when absent.
        subframes: (N, H, W, 3) uint8 sharp sub-frames over the background (TSR target).
        masks: (N, H, W) float32 mean coverage of each sub-frame interval, in [0, 1].
        bbox: (x, y, w, h) tight box in pixels of every pixel the object touches during the
            exposure (columns x .. x + w - 1, rows y .. y + h - 1); None when absent.
        centres: (N, 2) float64 (u, v) projection of the object's centre at the middle of
            each sub-frame interval, tau = (j + 1/2) / N; None when absent.
        radius_px: radius of the disc whose area is the mean silhouette area over the
            exposure (the mean of the sub-frames' summed coverage); None when absent.
    """

    index: int
    present: bool
    motion: FrameMotion
    subframes: np.ndarray
    masks: np.ndarray
    bbox: tuple[int, int, int, int] | None
    centres: np.ndarray | None
    radius_px: float | None

    @property
    def masks_binary(self) -> np.ndarray:
        """(N, H, W) bool: coverage above one half."""
        return self.masks > 0.5

    @property
    def subframe_taus(self) -> np.ndarray:
        """(N,) exposure times of the sub-frame centres."""
        n = self.subframes.shape[0]
        return (np.arange(n) + 0.5) / n


@dataclass(frozen=True)
class SyntheticScene:
    """Everything about a clip that does not change from frame to frame.

    Attributes:
        spec: what was asked for.
        camera: the full-frame pinhole camera (H x W = spec.height x spec.width).
        mesh: the object, at unit scale in its own frame.
        background: (H, W, 3) uint8 noise-free background.
        background_name: the photo it was cut from.
        trajectory: the object's continuous motion.
    """

    spec: ClipSpec
    camera: PinholeCamera
    mesh: TexturedMesh
    background: np.ndarray
    background_name: str
    trajectory: Trajectory


@dataclass(frozen=True)
class SyntheticClip:
    """A generated clip: its scene, the blurred frames and the per-frame ground truth.

    Attributes:
        scene: camera, mesh, background and trajectory.
        frames: (F, H, W, 3) uint8 blurred, noisy frames.
        truth: F records, one per frame.
    """

    scene: SyntheticScene
    frames: np.ndarray
    truth: tuple[FrameTruth, ...]

    @property
    def spec(self) -> ClipSpec:
        return self.scene.spec

    @property
    def camera(self) -> PinholeCamera:
        return self.scene.camera


def fence_cover(spec: ClipSpec) -> np.ndarray | None:
    """(H, W) float64 coverage of the spec's fence (wires 2 px wide every ``fence_period_px``
    pixels, both ways), or None without a fence."""
    if spec.fence_period_px == 0:
        return None
    rows = (np.arange(spec.height) % spec.fence_period_px) < 2
    cols = (np.arange(spec.width) % spec.fence_period_px) < 2
    return (rows[:, None] | cols[None, :]).astype(np.float64)


FENCE_COLOUR = np.array([70.0, 70.0, 75.0]) / 255
"""The fence's wire colour, a dark grey."""


def _behind_fence(images: np.ndarray, spec: ClipSpec) -> np.ndarray:
    """(..., H, W, 3) images in [0, 1] seen through the spec's fence."""
    cover = fence_cover(spec)
    if cover is None:
        return images
    return images * (1 - cover[..., None]) + FENCE_COLOUR * cover[..., None]


def _stage_background(background: np.ndarray, spec: ClipSpec) -> np.ndarray:
    """The (H, W, 3) uint8 background darkened on the left and brightened on the right half
    (``split_background``), then seen through the fence."""
    image = background.astype(np.float64) / 255
    if spec.split_background:
        half = spec.width // 2
        image[:, :half] *= 0.3
        image[:, half:] = 1 - 0.3 * (1 - image[:, half:])
    return to_uint8(_behind_fence(image, spec))


def _faint(mesh: TexturedMesh, background: np.ndarray, contrast: float) -> TexturedMesh:
    """The mesh with its texture pulled towards the background's mean colour."""
    if contrast == 1:
        return mesh
    mean = background.reshape(-1, 3).mean(0)
    texture = mean + contrast * (mesh.texture.astype(np.float64) - mean)
    return dataclasses.replace(mesh, texture=np.clip(texture.round(), 0, 255).astype(np.uint8))


def make_scene(spec: ClipSpec) -> SyntheticScene:
    """Draw the shape, texture, background and trajectory of ``spec``."""
    camera = PinholeCamera.from_fov(spec.width, spec.height, spec.fov_y_deg)
    mesh = make_shape(spec.shape, stream_rng(spec.seed, _SHAPE_STREAM), spec.texture_size, spec.texture_style)
    background, name = make_background(
        stream_rng(spec.seed, _BACKGROUND_STREAM), spec.width, spec.height, spec.background, spec.background_crop_range
    )
    background = _stage_background(background, spec)
    mesh = _faint(mesh, background, spec.contrast)
    trajectory = sample_trajectory(
        stream_rng(spec.seed, _TRAJECTORY_STREAM), spec, mesh.vertices.double().numpy(), camera
    )
    return SyntheticScene(spec, camera, mesh, background, name, trajectory)


def _project(camera: PinholeCamera, points: np.ndarray) -> np.ndarray:
    """(*, 3) camera-space points -> (*, 2) pixel coordinates (u, v)."""
    z = points[..., 2]
    return np.stack((camera.fx * points[..., 0] / z + camera.cx, camera.fy * points[..., 1] / z + camera.cy), -1)


def exposure_renders(scene: SyntheticScene, index: int) -> int:
    """How many hard renders frame ``index``'s exposure gets (see ``ClipSpec.max_step_px``)."""
    spec, traj = scene.spec, scene.trajectory
    k, n = spec.sub_exposures, spec.num_subframes
    if spec.max_step_px == 0:
        return k
    # The image path of every vertex over the exposure, measured on a fine polyline; the
    # motion is smooth, so spreading renders evenly spreads the steps evenly too.
    probe = traj.exposure_times(index, np.linspace(0.0, 1.0, spec.sub_exposures + 1))
    verts = scene.mesh.vertices.double().numpy()
    points = np.einsum("tij,vj->tvi", traj.rotations(probe), verts) + traj.positions(probe)[:, None]
    path = np.linalg.norm(np.diff(_project(scene.camera, points), axis=0), axis=-1).sum(0).max()
    needed = math.ceil(path / spec.max_step_px / n) * n
    cap = spec.max_sub_exposures // n * n
    return int(min(max(k, needed), max(cap, k)))


def render_exposure(scene: SyntheticScene, index: int) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free sub-frames and coverage of frame ``index``'s exposure.

    Returns:
        subframes: (N, H, W, 3) float64 composited over the background, in [0, 1].
        coverage: (N, H, W) float64 mean coverage per sub-frame interval.
    """
    spec, traj, mesh = scene.spec, scene.trajectory, scene.mesh
    k, n = exposure_renders(scene, index), spec.num_subframes
    times = traj.exposure_times(index, (np.arange(k) + 0.5) / k)
    points = pose_points(
        mesh.vertices, torch.from_numpy(traj.rotations(times)), torch.from_numpy(traj.positions(times))
    )
    raster = rasterize(
        points,
        mesh.topology.faces,
        mesh.topology.face_uv_coords(),
        mesh.texture,
        scene.camera,
        spec.supersample,
        groups=np.arange(k) // (k // n),
    )
    cover = fence_cover(spec)
    coverage = raster.coverage if cover is None else raster.coverage * (1 - cover)
    return _behind_fence(raster.composite(scene.background / 255.0), spec), coverage


def render_frame(scene: SyntheticScene, index: int) -> tuple[np.ndarray, FrameTruth]:
    """The blurred (H, W, 3) uint8 frame ``index`` of the clip and its ground truth."""
    spec, cam = scene.spec, scene.camera
    n = spec.num_subframes
    motion = scene.trajectory.frame_motion(index)
    present = index in spec.present_frames
    if present:
        sub, coverage = render_exposure(scene, index)
    else:
        sub = np.broadcast_to(scene.background / 255.0, (n, *scene.background.shape))
        coverage = np.zeros((n, spec.height, spec.width))
    noise = stream_rng(spec.seed, _NOISE_STREAM, index).normal(0.0, spec.noise_sigma, scene.background.shape)
    frame = to_uint8(sub.mean(0) + noise)
    bbox = centres = radius = None
    if present:
        bbox = mask_box(coverage.max(0) > 0)
        mid = scene.trajectory.positions(scene.trajectory.exposure_times(index, (np.arange(n) + 0.5) / n))
        centres = _project(cam, mid)
        radius = math.sqrt(float(coverage.sum((1, 2)).mean()) / math.pi)
    truth = FrameTruth(
        index=index,
        present=present,
        motion=motion,
        subframes=to_uint8(sub),
        masks=mask_from_levels(to_uint8(coverage)),
        bbox=bbox,
        centres=centres,
        radius_px=radius,
    )
    return frame, truth


def generate_clip(spec: ClipSpec) -> SyntheticClip:
    """Generate every frame of ``spec`` in memory (a single blurred frame: num_frames = 1).

    For long clips, :func:`sfb_video.synth.io.write_clip` streams frames to disk instead.
    """
    scene = make_scene(spec)
    rendered = [render_frame(scene, k) for k in range(spec.num_frames)]
    frames = np.stack([frame for frame, _ in rendered])
    return SyntheticClip(scene, frames, tuple(truth for _, truth in rendered))
