"""Accuracy measures: the FMO deblurring benchmark's TIoU, PSNR and SSIM, and the paper's 3D errors.

Benchmark conventions, as its own code computes them (rozumden/fmo-deblurring-benchmark): every
image measure is taken on the tight box crop of the sub-frames; PSNR comes from one float32 MSE
over all pixels, channels and sub-frames (peak 1, and 100 for identical images); SSIM is
scikit-image's per sub-frame, averaged, with the data range of the *estimate* (the benchmark
passes the estimate second, and takes the range from its second argument); TIoU is the mean
over sub-frames of the IoU of two discs of the ground-truth radius, at the estimated and the
true centres, taking the better of the two time directions; the sub-frames are reversed before
PSNR and SSIM when the estimate's first sub-frame is closer to the last true one than to the
first. A single frame does not tell which way time runs, hence both flips.

3D errors (paper, Sec. 5): translation error in object sizes, the angle of the rotation made
during the exposure, and the mean bidirectional vertex-to-surface distance between the
estimated and true meshes, aligned and rescaled to fit a unit cube.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh
from skimage.metrics import structural_similarity
from trimesh.registration import icp

ICP_SAMPLES = 2000
"""Surface points of the estimate that ICP aligns with the true mesh."""

ICP_TARGET_SAMPLES = 20000
"""Surface points of the true mesh that ICP aligns them with (nearest neighbours in a k-d tree):
the exact closest points on the surface cost 10-40 times the time (5-64 s a frame against
0.3-2.5 s, benchmarks/RESULTS.md) for the same error to 0.003 of a unit cube."""


def psnr(estimate: np.ndarray, truth: np.ndarray) -> float:
    """PSNR in dB of (N, H, W, 3) sub-frames in [0, 1], from one float32 MSE over all of them."""
    mse = float(np.mean((estimate.astype(np.float32) - truth.astype(np.float32)) ** 2))
    return 100.0 if mse == 0 else 20 * math.log10(1.0 / math.sqrt(mse))


def ssim(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Mean over sub-frames of the SSIM of (N, H, W, 3) images, the data range the estimate's.

    A constant estimate has no range; it is then taken as 1 (the benchmark would divide by 0).
    """
    span = float(estimate.max() - estimate.min())
    scores = [
        structural_similarity(t, e, channel_axis=-1, data_range=span if span > 0 else 1.0)
        for e, t in zip(estimate.astype(np.float64), truth.astype(np.float64), strict=True)
    ]
    return float(np.mean(scores))


def disc_iou(distance: np.ndarray | float, radius: float) -> np.ndarray:
    """IoU of two discs of equal ``radius`` whose centres lie ``distance`` apart (any shape)."""
    d = np.clip(np.asarray(distance, dtype=np.float64) / (2 * radius), 0.0, 1.0)
    # Lens area of two circles of radius r at distance 2 r d, over the disc area pi r^2.
    lens = (2 * np.arccos(d) - 2 * d * np.sqrt(1 - d**2)) / math.pi
    return lens / (2 - lens)


def tiou(centres: np.ndarray, truth: np.ndarray, radius: float, may_flip: bool = True) -> float:
    """Mean disc IoU of estimated (N, 2) and true (N, 2) sub-frame centres, in pixels.

    Args:
        may_flip: take the better of the estimate and its reverse, as the benchmark does; a
            video, whose direction the pipeline resolves, is scored without.
    """
    forward = float(disc_iou(np.linalg.norm(centres - truth, axis=-1), radius).mean())
    if not may_flip:
        return forward
    return max(forward, tiou(centres[::-1], truth, radius, may_flip=False))


def should_flip(estimate: np.ndarray, truth: np.ndarray) -> bool:
    """The benchmark's rule: reverse (N, ...) sub-frames when the first is closer to the last truth."""
    first = estimate[0].astype(np.float64)
    return bool(np.mean((first - truth[0]) ** 2) > np.mean((first - truth[-1]) ** 2))


def benchmark_scores(
    estimate: np.ndarray,
    truth: np.ndarray,
    centres: np.ndarray,
    true_centres: np.ndarray,
    radius: float,
    may_flip: bool = True,
) -> tuple[dict[str, float], bool]:
    """TIoU, PSNR and SSIM of one frame by the benchmark's protocol, and whether it reversed the estimate.

    Args:
        estimate, truth: (N, h, w, 3) sub-frames on the tight box, in [0, 1].
        centres, true_centres: (N, 2) sub-frame centres in pixels, in the estimate's own order.
        may_flip: apply the benchmark's two flips; off for a video, whose direction is resolved.
    """
    flipped = may_flip and should_flip(estimate, truth)
    if flipped:
        estimate = estimate[::-1]
    scores = {
        "tiou": tiou(centres, true_centres, radius, may_flip=may_flip),
        "psnr": psnr(estimate, truth),
        "ssim": ssim(estimate, truth),
    }
    return scores, flipped


def translation_error(positions: np.ndarray, truth: np.ndarray) -> float:
    """Mean distance between estimated and true (N, 3) positions, in object sizes."""
    return float(np.linalg.norm(positions - truth, axis=-1).mean())


def rotation_error_deg(rotation: np.ndarray, truth: np.ndarray) -> float:
    """Angle in degrees between two (3, 3) rotations."""
    cos = (np.trace(rotation.T @ truth) - 1) / 2
    return math.degrees(math.acos(min(1.0, max(-1.0, cos))))


def unit_cube(vertices: np.ndarray) -> np.ndarray:
    """(V, 3) vertices moved and scaled so that their bounding box is centred and its longest side 1."""
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    return (vertices - (low + high) / 2) / float((high - low).max())


def _surface_distance(points: np.ndarray, mesh: trimesh.Trimesh) -> float:
    return float(trimesh.proximity.closest_point(mesh, points)[1].mean())


def _rms_normalised(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The mesh centred on its surface's centroid with unit RMS radius, and dense surface samples."""
    samples = trimesh.sample.sample_surface(mesh, ICP_SAMPLES, seed=0)[0]
    centre = samples.mean(axis=0)
    scale = float(np.sqrt(((samples - centre) ** 2).sum(axis=1).mean()))
    return trimesh.Trimesh((mesh.vertices - centre) / scale, mesh.faces, process=False), (samples - centre) / scale


def mesh_distance(
    vertices: np.ndarray, faces: np.ndarray, true_vertices: np.ndarray, true_faces: np.ndarray, align: bool = True
) -> float:
    """The paper's mesh error: (D(M, M_gt) + D(M_gt, M)) / 2, in unit-cube object sizes.

    D(M1, M2) is the mean distance of M1's vertices to M2's surface, both meshes rescaled to fit
    a unit cube. With ``align`` the estimate is first moved onto the truth: both are brought to
    the same rotation-free scale (unit RMS radius of their surfaces), then ICP finds the rigid
    motion onto dense samples of the truth's surface, starting from the poses given (pass both
    in the same frame, e.g. posed at the start of the exposure, so that ICP starts near the
    answer).

    Args:
        vertices, faces: (V, 3) float and (F, 3) int, the estimate.
        true_vertices, true_faces: the ground truth, likewise.
    """
    estimate = trimesh.Trimesh(np.asarray(vertices, dtype=np.float64), faces, process=False)
    truth = trimesh.Trimesh(np.asarray(true_vertices, dtype=np.float64), true_faces, process=False)
    if align:
        estimate, samples = _rms_normalised(estimate)
        truth, _ = _rms_normalised(truth)
        target = trimesh.sample.sample_surface(truth, ICP_TARGET_SAMPLES, seed=1)[0]
        # ICP on dense surface samples: a low-poly mesh's few vertices could slide along faces.
        matrix, _, _ = icp(samples, target, threshold=1e-10, max_iterations=100, scale=False, reflection=False)
        estimate.apply_transform(matrix)
    estimate = trimesh.Trimesh(unit_cube(estimate.vertices), faces, process=False)
    truth = trimesh.Trimesh(unit_cube(truth.vertices), true_faces, process=False)
    return 0.5 * (_surface_distance(estimate.vertices, truth) + _surface_distance(truth.vertices, estimate))
