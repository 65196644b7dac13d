"""Small FMO-benchmark datasets in the benchmark's exact layout, built from a known scene.

:func:`write_fixture` writes a TbD, TbD-3D or Falling Objects style dataset of two short sequences:
a mildly structured background and a shaded disc of known radius that moves, within each frame's
exposure, along a short known segment. A GT sub-frame is the sharp disc at sub-frame ``j``'s centre
over the background; a blurred frame is the mean of ``4 N`` finer sharp renders. Each frame's
segment lies in its own quarter of the image, so no pixel shows the disc in two frames of a
sequence and the benchmark's running median of any window of them is the background exactly.

Between them the three datasets cover: gt.txt + gtr.txt (tbd3d), gt.txt + template .mat (tbd, with
a ``VS_`` name whose order changes when ``VS_`` is dropped and excluded ``ping_wall``/``fall_coin``
folders), gt_bbox (falling, 16-bit PNGs, with a gtr.txt the benchmark ignores there), ``-12``
sequences, frames and GT sub-frames numbered from 1, NaNs in gt.txt, alpha channels, and
roi_frames.txt (tbd). The returned :class:`FixtureDataset` holds what was written, so tests can
compare the loader's output with the truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import scipy.io

HEIGHT, WIDTH = 48, 64
"""Frame size of the fixtures."""

FINE_PER_SUBFRAME = 4
"""Sharp renders per sub-frame averaged into a blurred frame."""

HALF_LENGTH = 6.0
"""Half the length, in pixels, of the segment the disc covers during one exposure."""

_SLOTS = ((0.25, 0.27, 0.0), (0.75, 0.27, 25.0), (0.25, 0.73, -20.0), (0.75, 0.73, 160.0))
"""(x / W, y / H, direction in degrees) of the segment of file ``f``: slot ``f % 4``. The four slots
are far enough apart that discs in different slots never overlap."""


@dataclass(frozen=True)
class FixtureSequence:
    """One written sequence and its truth; ``F`` frames of ``N`` sub-frames, ``H x W`` pixels."""

    name: str
    num_subframes: int
    first_file: int
    """File number of frame 0 (what the loader's ``first_file`` must be)."""
    bit_depth: int
    """8 or 16: the PNGs' sample depth."""
    alpha: bool
    """Whether the PNGs carry an alpha channel (which the loader must drop)."""
    radius: int
    """The disc's radius in pixels, also the radius the benchmark's rules give from the GT files."""
    radius_source: str
    """Where the loader must take the radius from: ``"gtr"``, ``"template"`` or ``"gt_bbox"``."""
    centres: np.ndarray
    """(F, N, 2) float64 true (x, y) sub-frame centres."""
    images: np.ndarray
    """(F, H, W, 3) float64 RGB in [0, 1]: the blurred frames as written (after quantisation)."""
    subframes: np.ndarray
    """(F, N, H, W, 3) float64 RGB in [0, 1]: the GT sub-frames as written."""
    background: np.ndarray
    """(H, W, 3) float64 RGB in [0, 1]: the background as written."""
    nan_subframes: tuple[tuple[int, int], ...]
    """(frame, sub-frame) pairs whose centre gt.txt stores as NaN."""

    @property
    def num_frames(self) -> int:
        return int(self.images.shape[0])


@dataclass(frozen=True)
class FixtureDataset:
    """A written dataset: its root, and its sequences in the order the benchmark lists them."""

    root: Path
    dataset: str
    sequences: tuple[FixtureSequence, ...]
    excluded: tuple[str, ...]
    """Folders under ``imgs/`` that the loader must not list."""


@dataclass(frozen=True)
class _Spec:
    name: str
    files: range
    """File numbers written to imgs/<seq>."""
    frames: range
    """File numbers of the sequence's frames (all files, or the roi's)."""
    num_subframes: int
    radius: int
    radius_source: str
    bit_depth: int = 8
    alpha: bool = False
    gt_offset: int = 0
    nan_subframes: tuple[tuple[int, int], ...] = ()
    seed: int = 0


_SPECS: dict[str, tuple[_Spec, ...]] = {
    # Listed with VS_ dropped: hit_tennis < mug_throw (a plain sort puts "VS_..." first). The roi
    # rows, in that order, are [1, 3] and [0, 2]; VS_mug_throw is numbered from 1, so its roi
    # start 0 means file 1.
    "tbd": (
        _Spec("hit_tennis", range(0, 5), range(1, 4), 8, 5, "template", seed=1),
        _Spec("VS_mug_throw", range(1, 5), range(1, 4), 8, 4, "template", seed=2),
    ),
    "tbd3d": (
        _Spec(
            "ball_GT_one",
            range(0, 4),
            range(0, 4),
            8,
            5,
            "gtr",
            alpha=True,
            # Sub-frames 0 and 1 (both take sub-frame 2: 0 the first finite one, 1 the mean of its
            # filled predecessor and 2), two in a row (the first takes its predecessor, the second
            # the mean of its neighbours) and the last (takes its predecessor).
            nan_subframes=((1, 0), (1, 1), (2, 4), (2, 5), (3, 7)),
            seed=3,
        ),
        _Spec("box_GT_two-12", range(1, 4), range(1, 4), 12, 4, "gtr", gt_offset=1, seed=4),
    ),
    "falling": (
        _Spec("key_GTgamma", range(0, 3), range(0, 3), 8, 5, "gt_bbox", bit_depth=16, seed=5),
        _Spec(
            "pen-12_GTgamma", range(1, 4), range(1, 4), 12, 4, "gt_bbox", bit_depth=16, alpha=True, gt_offset=1, seed=6
        ),
    ),
}

_ROI = {"tbd": ((1, 3), (0, 2))}

_EXCLUDED = {
    "tbd": ("VS_ping_wall", "fall_coin", "notes"),
    "tbd3d": ("ball_one", "box_gt_three"),
    "falling": ("key_GTgamma_old", "GTgamma"),
}


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Write (H, W, 3) RGB or (H, W, 4) RGBA uint8/uint16 ``rgb`` as a PNG (cv2 wants BGR(A))."""
    path.parent.mkdir(parents=True, exist_ok=True)
    order = [2, 1, 0, 3] if rgb.shape[2] == 4 else [2, 1, 0]
    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[:, :, order])):
        raise OSError(f"could not write {path}")


def quantise(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """(..., 3) float image in [0, 1] as uint8 or uint16 samples."""
    top = 255 if bit_depth == 8 else 65535
    return np.round(np.clip(image, 0.0, 1.0) * top).astype(np.uint8 if bit_depth == 8 else np.uint16)


def dequantise(samples: np.ndarray) -> np.ndarray:
    """uint8/uint16 samples as float64 in [0, 1]."""
    return samples / (255.0 if samples.dtype == np.uint8 else 65535.0)


def write_image(path: Path, image: np.ndarray, bit_depth: int = 8, alpha: bool = False) -> np.ndarray:
    """Write (H, W, 3) float ``image`` as an 8- or 16-bit PNG (with a constant, non-opaque alpha if
    asked, which a reader must ignore) and return the (H, W, 3) float64 values as written."""
    samples = quantise(image, bit_depth)
    if alpha:
        top = 255 if bit_depth == 8 else 65535
        samples = np.concatenate([samples, np.full((*samples.shape[:2], 1), int(0.6 * top), samples.dtype)], 2)
    write_png(path, samples)
    return dequantise(samples[:, :, :3])


def write_fixture(root: Path, dataset: str) -> FixtureDataset:
    """Write a small ``dataset`` ("tbd", "tbd3d" or "falling") under ``root`` and return its truth."""
    root = Path(root)
    sequences = tuple(_write_sequence(root, spec) for spec in _SPECS[dataset])
    if dataset in _ROI:
        np.savetxt(root / "roi_frames.txt", np.array(_ROI[dataset]), fmt="%d")
    for name in _EXCLUDED[dataset]:
        # A frame and nothing else: listing one of these would fail for want of GT.
        write_image(root / "imgs" / name / "00000000.png", np.full((HEIGHT, WIDTH, 3), 0.5))
    return FixtureDataset(root=root, dataset=dataset, sequences=sequences, excluded=_EXCLUDED[dataset])


def scene_background(seed: int) -> np.ndarray:
    """(H, W, 3) float64 background: a colour ramp with a mild diagonal ripple."""
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(float)
    tint = np.array([0.9, 1.0, 1.1]) + 0.05 * seed
    ramp = 0.25 + 0.2 * (xx / WIDTH)[..., None] * tint + 0.1 * (yy / HEIGHT)[..., None]
    ripple = 0.06 * np.sin(2 * np.pi * (xx / 9 + yy / 13)[..., None] + np.arange(3) + seed)
    return ramp + ripple


def render(background: np.ndarray, centre: np.ndarray, radius: float, colour: np.ndarray) -> np.ndarray:
    """(H, W, 3) the sharp disc of ``radius`` at ``centre`` (x, y) over ``background``, anti-aliased
    over one pixel and shaded darker towards its rim."""
    yy, xx = np.mgrid[0:HEIGHT, 0:WIDTH].astype(float)
    dist = np.hypot(xx - centre[0], yy - centre[1])
    cover = np.clip(radius + 0.5 - dist, 0.0, 1.0)[..., None]
    shade = (1.0 - 0.3 * np.clip(dist / radius, 0.0, 1.0))[..., None]
    # background + cover * (object - background): exactly the background where cover is 0.
    return background + cover * (colour * shade - background)


def segment(file_number: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (x, y) of the disc's centre during the exposure of file ``file_number``."""
    fx, fy, angle = _SLOTS[file_number % len(_SLOTS)]
    angle = math.radians(angle + 7 * seed)
    centre = np.array([fx * WIDTH, fy * HEIGHT])
    step = HALF_LENGTH * np.array([math.cos(angle), math.sin(angle)])
    return centre - step, centre + step


def _write_sequence(root: Path, spec: _Spec) -> FixtureSequence:
    n = spec.num_subframes
    folder = root / "imgs" / spec.name
    gt_folder = root / "imgs_gt" / spec.name
    background = scene_background(spec.seed)
    colour = np.array([0.95, 0.55 + 0.03 * spec.seed, 0.15])
    numbers = range(0, spec.files[-1] + 1)  # every GT table is indexed by file number from 0
    sub_t = (np.arange(n) + 0.5) / n
    fine_t = (np.arange(FINE_PER_SUBFRAME * n) + 0.5) / (FINE_PER_SUBFRAME * n)

    centres = np.zeros((len(numbers), n, 2))
    images: dict[int, np.ndarray] = {}
    subframes: dict[int, np.ndarray] = {}
    for f in numbers:
        start, end = segment(f, spec.seed)
        centres[f] = start + sub_t[:, None] * (end - start)
        if f in spec.files:
            fine = [render(background, start + t * (end - start), spec.radius, colour) for t in fine_t]
            images[f] = write_image(folder / f"{f:08d}.png", np.mean(fine, axis=0), spec.bit_depth, spec.alpha)
        # GT sub-frames of every file number, a file 0 without a frame included: with gt_offset 0
        # that makes imgs_gt's 00000000.png exist, with 1 it makes it absent.
        subframes[f] = np.stack(
            [
                write_image(
                    gt_folder / f"{f * n + j + spec.gt_offset:08d}.png",
                    render(background, centres[f, j], spec.radius, colour),
                    spec.bit_depth,
                    spec.alpha,
                )
                for j in range(n)
            ]
        )

    stored = centres.copy()
    for k, j in spec.nan_subframes:
        stored[spec.frames[k], j] = np.nan
    if spec.radius_source == "gt_bbox":
        _write_gt_bbox(root, spec, centres)
    else:
        # (F, N, 2) -> rows x_0, y_0, x_1, y_1, ... of N columns, one pair per file number.
        np.savetxt(folder / "gt.txt", stored.transpose(0, 2, 1).reshape(-1, n))
        if spec.radius_source == "gtr":
            # Per-file rows whose nan-max is the radius; neither their mean, first nor plain max is.
            rows = np.full((len(numbers), n), spec.radius - 1.4)
            rows[:, 3] = spec.radius
            rows[:, 5] = np.nan
            np.savetxt(folder / "gtr.txt", rows)
        else:
            # Radius (rows / 2) / scale = (4 r + 1) / 4 = r + 0.25, which rounds to r.
            template = np.zeros((4 * spec.radius + 1, 3 * spec.radius, 3))
            path = root / "templates" / f"{spec.name}_template.mat"
            path.parent.mkdir(parents=True, exist_ok=True)
            scipy.io.savemat(str(path), {"template": template, "scale": np.array([[2.0]])})

    frames = list(spec.frames)
    return FixtureSequence(
        name=spec.name,
        num_subframes=n,
        first_file=spec.frames[0],
        bit_depth=spec.bit_depth,
        alpha=spec.alpha,
        radius=spec.radius,
        radius_source=spec.radius_source,
        centres=centres[frames],
        images=np.stack([images[f] for f in frames]),
        subframes=np.stack([subframes[f] for f in frames]),
        background=dequantise(quantise(background, spec.bit_depth)),
        nan_subframes=spec.nan_subframes,
    )


def _write_gt_bbox(root: Path, spec: _Spec, centres: np.ndarray) -> None:
    """gt_bbox/<seq>.txt: an ``x y w h`` box per sub-frame of the sequence's frames (the benchmark pads
    the table with ``first_file`` empty frames itself), whose longer side is the diameter; and a
    gtr.txt with a wrong radius, which the benchmark ignores when the trajectory comes from gt_bbox."""
    n = spec.num_subframes
    long_side = 2.0 * spec.radius
    # The shorter side alternates between width and height across the two falling sequences.
    short_side = long_side - 2.0
    w, h = (long_side, short_side) if spec.seed % 2 else (short_side, long_side)
    rows = []
    for f in spec.frames:
        for j in range(n):
            x, y = centres[f, j]
            rows.append([x - w / 2, y - h / 2, w, h])
    path = root / "gt_bbox" / f"{spec.name}.txt"
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, np.array(rows))
    np.savetxt(root / "imgs" / spec.name / "gtr.txt", np.full((spec.files[-1] + 1, n), spec.radius + 4.0))


def write_plain_sequence(
    root: Path, name: str, frames: np.ndarray, subframes: np.ndarray, centres: np.ndarray, radius: float
) -> None:
    """Write a hand-made TbD-3D style sequence, every file numbered from 0.

    ``frames`` (F, H, W, 3) and ``subframes`` (F, N, H, W, 3) uint8 or uint16 samples, ``centres``
    (F, N, 2) (x, y), ``radius`` the value of every gtr.txt entry.
    """
    root = Path(root)
    num_frames, n = subframes.shape[:2]
    for k in range(num_frames):
        write_png(root / "imgs" / name / f"{k:08d}.png", frames[k])
        for j in range(n):
            write_png(root / "imgs_gt" / name / f"{k * n + j:08d}.png", subframes[k, j])
    np.savetxt(root / "imgs" / name / "gt.txt", np.asarray(centres, float).transpose(0, 2, 1).reshape(-1, n))
    np.savetxt(root / "imgs" / name / "gtr.txt", np.full((num_frames, n), float(radius)))
