"""The FMO deblurring benchmark's datasets (TbD, TbD-3D, Falling Objects), read as its own code reads them.

The benchmark (github.com/rozumden/fmo-deblurring-benchmark) scores a method frame by frame: it
hands the method the blurred frame, a background (a running median of frames), the sub-frame
count and the GT radius, and scores the method's sharp sub-frames against the GT sub-frames
inside a tight box. This module reproduces what its ``GroundTruthProcessor`` (reporters.py), its
loader helpers (loaders_helpers.py) and its ``evaluate_on`` (benchmark_loader.py) compute, from
a local copy of a dataset laid out as the benchmark expects::

    <root>/imgs/<seq>/%08d.png          blurred frames (numbered from 0, or from 1)
    <root>/imgs/<seq>/gt.txt            optional: GT sub-frame centres, 2 rows (x, y) per frame
    <root>/imgs/<seq>/gtr.txt           optional: GT radii, one row of N per frame
    <root>/imgs_gt/<seq>/%08d.png       GT sharp sub-frames, N per frame
    <root>/templates/<seq>_template.mat optional: a template whose size and scale give the radius
    <root>/gt_bbox/<seq>.txt            optional: one ``x y w h`` box per sub-frame
    <root>/roi_frames.txt               optional: one ``start end`` row per sequence

Throughout, "file number" is the number in a frame's file name: frame ``k`` of a sequence is file
``first_file + k``, and the benchmark indexes every GT table by file number (see
:attr:`BenchmarkSequence.first_file`).
"""

from __future__ import annotations

import glob
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path

import cv2
import numpy as np
import scipy.io
from skimage.measure import label, regionprops

from sfb_video.errors import SfbError

DATASETS = ("tbd", "tbd3d", "falling")
"""The benchmark's datasets, by the names :func:`list_sequences` takes."""

MEDIAN_FRAMES = 50
"""Frames in the background's running median (the benchmark's ``medn``)."""

BOX_MARGIN = 10
"""Pixels the benchmark adds around the radius-extended GT box before looking for the object."""

CHANGE_THRESHOLD = 0.1
"""A GT sub-frame pixel shows the object where its channel-summed |difference| to the background exceeds this."""

_MEDIAN_ROWS = 64
"""Image rows per chunk when taking the running median, so its working copy stays small."""


@dataclass(frozen=True)
class BenchmarkFrame:
    """One frame of a benchmark sequence with everything the benchmark hands a method and scores on.

    Shapes: ``H x W`` is the frame size and ``N`` the sequence's sub-frame count.
    """

    sequence: str
    index: int
    """0-based position within the sequence."""
    image: np.ndarray
    """(H, W, 3) float64 RGB in [0, 1]: the blurred frame."""
    background: np.ndarray
    """(H, W, 3) float64 RGB in [0, 1]: the benchmark's running-median background."""
    subframes: np.ndarray
    """(N, H, W, 3) float64 RGB in [0, 1]: the GT sharp sub-frames, in time order."""
    centres: np.ndarray
    """(N, 2) float64: the GT (x, y) sub-frame centres in pixels, NaN gaps filled as the benchmark fills them."""
    radius: int
    """The GT radius in pixels, rounded as the benchmark rounds it."""
    box: tuple[int, int, int, int]
    """(x, y, w, h): the tight box the benchmark hands the method and scores inside."""


@dataclass(frozen=True)
class BenchmarkSequence:
    """One sequence of a benchmark dataset; :meth:`frames` streams its frames.

    The GT tables are read when the sequence is listed, so a sequence without GT fails early.
    """

    dataset: str
    name: str
    folder: Path
    """``<root>/imgs/<seq>``."""
    num_subframes: int
    """N: the number of columns of the GT trajectory."""
    num_frames: int
    first_file: int
    """File number of frame 0 (the benchmark's ``start_ind``): the roi start, plus 1 when the
    sequence has no ``00000000.png``. Frame ``k`` is ``%08d.png % (first_file + k)``, its GT centres
    are row pair ``first_file + k`` of gt.txt and its GT sub-frames are files
    ``(first_file + k) * N + j + gt_offset`` of ``imgs_gt/<seq>``."""
    gt_folder: Path
    """``<root>/imgs_gt/<seq>``."""
    gt_offset: int
    """1 when ``imgs_gt/<seq>`` has no ``00000000.png`` (its numbering starts at 1), else 0."""
    centres_table: np.ndarray = field(repr=False, compare=False)
    """(R, N, 2) float64: GT (x, y) sub-frame centres by file number, NaNs as stored."""
    radius_table: np.ndarray = field(repr=False, compare=False)
    """(R', C) float64: GT radii; R' > 1 means one row of per-sub-frame radii per file number,
    R' == 1 a single radius at [0, 0] (the benchmark's rule, see :meth:`radius`)."""

    def frames(self) -> Iterator[BenchmarkFrame]:
        """Yield the sequence's frames in order, reading them as they are needed.

        Holds at most ``min(MEDIAN_FRAMES, num_frames)`` frames (in the files' own 8- or 16-bit
        dtype) for the running median, never the whole sequence.
        """
        m = min(MEDIAN_FRAMES, self.num_frames)
        first, scale = _read_png(self.frame_path(0))
        # The window is a ring: slot k % m holds the newest frame with that residue. The median
        # does not care about the order of the frames in it.
        window = np.empty((m, *first.shape), dtype=first.dtype)
        window[0] = first
        for k in range(1, m):
            window[k] = self._read_frame(k, first, scale)
        initial = _median(window, scale)
        for k in range(self.num_frames):
            if k < m:
                # The benchmark's first window is frames 0..m-1, frame k itself included.
                native = window[k].copy()
                background = initial
            else:
                # Later, the window is the m frames before k: the benchmark takes the median
                # first and only then pushes frame k in.
                native = self._read_frame(k, first, scale)
                background = _median(window, scale)
                window[k % m] = native
            image = native / scale
            subframes = self._read_subframes(k, image.shape[0], image.shape[1])
            centres = self.centres(k)
            radius = self.radius(k)
            yield BenchmarkFrame(
                sequence=self.name,
                index=k,
                image=image,
                background=background,
                subframes=subframes,
                centres=centres,
                radius=radius,
                box=tight_box(centres, radius, subframes, background),
            )

    def frame_path(self, k: int) -> Path:
        """Path of frame ``k`` (0-based within the sequence)."""
        return self.folder / f"{self.first_file + k:08d}.png"

    def subframe_path(self, k: int, j: int) -> Path:
        """Path of GT sub-frame ``j`` of frame ``k``."""
        return self.gt_folder / f"{(self.first_file + k) * self.num_subframes + j + self.gt_offset:08d}.png"

    def centres(self, k: int) -> np.ndarray:
        """(N, 2) GT (x, y) sub-frame centres of frame ``k``, with NaN sub-frames filled as the benchmark
        fills them: sub-frame 0 takes the first non-NaN one, a later one the mean of its neighbours
        when the next is not NaN, else the (already filled) previous one."""
        par = self.centres_table[self.first_file + k].copy()
        # The benchmark tests the sum of x and y for NaN, not each coordinate.
        nans = np.isnan(par.sum(axis=1))
        if nans.any():
            valid = np.flatnonzero(~nans)
            if valid.size == 0:
                raise SfbError(f"{self.folder}: frame {k} has no finite GT sub-frame centre")
            n = par.shape[0]
            for j in np.flatnonzero(nans):
                if j == 0:
                    par[j] = par[valid[0]]
                elif j < n - 1 and not nans[j + 1]:
                    par[j] = (par[j - 1] + par[j + 1]) / 2
                else:
                    par[j] = par[j - 1]
        return par

    def radius(self, k: int) -> int:
        """GT radius of frame ``k``: the rounded nan-max of its row when there are per-frame radii, else
        the rounded single value (rounding half to even, as ``np.round``)."""
        table = self.radius_table
        value = np.nanmax(table[self.first_file + k]) if table.shape[0] > 1 else table[0, 0]
        if not np.isfinite(value):
            raise SfbError(f"{self.folder}: frame {k} has no finite GT radius")
        return int(np.round(value))

    def _read_frame(self, k: int, like: np.ndarray, scale: float) -> np.ndarray:
        """Frame ``k`` as stored, (H, W, 3) uint8 or uint16 RGB, checked against the sequence's frame 0."""
        path = self.frame_path(k)
        native, frame_scale = _read_png(path)
        if native.shape != like.shape or frame_scale != scale:
            raise SfbError(
                f"frame {path} is {native.shape[1]}x{native.shape[0]} {native.dtype}, unlike the sequence's "
                f"first frame ({like.shape[1]}x{like.shape[0]} {like.dtype})"
            )
        return native

    def _read_subframes(self, k: int, height: int, width: int) -> np.ndarray:
        """(N, H, W, 3) float64 GT sub-frames of frame ``k``, cut to the frame's size as the benchmark cuts them."""
        out = np.empty((self.num_subframes, height, width, 3))
        for j in range(self.num_subframes):
            path = self.subframe_path(k, j)
            native, scale = _read_png(path)
            if native.shape[0] < height or native.shape[1] < width:
                raise SfbError(f"GT sub-frame {path} is smaller than its {width}x{height} frame")
            out[j] = native[:height, :width] / scale
        return out


def list_sequences(root: Path | str, dataset: str) -> list[BenchmarkSequence]:
    """The sequences of ``dataset`` (one of :data:`DATASETS`) under ``root``, in the benchmark's order.

    tbd: every ``imgs/*_*`` folder except those whose name holds ``ping_wall`` or ``fall_coin``,
    sorted by the name with ``VS_`` removed; tbd3d: ``imgs/*_GT_*``, sorted; falling:
    ``imgs/*_GTgamma``, sorted. Raises :class:`SfbError` for an unknown dataset, a missing root, a
    root without sequences, or a sequence without frames or GT.
    """
    if dataset not in DATASETS:
        raise SfbError(f"unknown FMO benchmark dataset {dataset!r}: expected one of {', '.join(DATASETS)}")
    root = Path(root)
    if not root.is_dir():
        raise SfbError(f"FMO benchmark dataset folder {root} does not exist")
    names = _select(root / "imgs", dataset)
    if not names:
        raise SfbError(f"no {dataset} sequences under {root / 'imgs'}")
    roi = _read_roi(root / "roi_frames.txt")
    return [_load_sequence(root, dataset, name, position, roi) for position, name in enumerate(names)]


def tight_box(
    centres: np.ndarray, radius: int, subframes: np.ndarray, background: np.ndarray
) -> tuple[int, int, int, int]:
    """The benchmark's tight box, (x, y, w, h), of one frame.

    ``centres`` (N, 2) GT (x, y) centres; ``subframes`` (N, H, W, 3) GT sub-frames; ``background``
    (H, W, 3). The box of the centres, extended by ``radius`` and then by :data:`BOX_MARGIN`, is
    searched for pixels where some sub-frame differs from the background; the bounding box of the
    largest 8-connected group of them is the tight box, or the extended box if there is none.
    """
    height, width = background.shape[:2]
    # (top, left, bottom, right), truncated toward zero as the benchmark's astype(int) does.
    box = np.array([centres[:, 1].min(), centres[:, 0].min(), centres[:, 1].max(), centres[:, 0].max()]).astype(int)
    box = _extend_box(_extend_box(box, radius, height, width), BOX_MARGIN, height, width)
    top, left, bottom, right = (int(v) for v in box)
    # The benchmark crops [top:bottom, left:right] although bottom/right were clipped to H-1/W-1:
    # the last row and column are never searched. Kept, to score on the same box.
    diff = np.abs(subframes[:, top:bottom, left:right] - background[top:bottom, left:right]).sum(axis=-1)
    changed = (diff > CHANGE_THRESHOLD).sum(axis=0) > 0.5
    best = None
    if changed.size:
        for region in regionprops(label(changed)):
            # Strictly larger: on a tie the first region in label (raster) order wins, as in the benchmark.
            if best is None or region.area > best.area:
                best = region
    if best is None:
        return left, top, right - left, bottom - top
    r0, c0, r1, c1 = best.bbox
    return left + int(c0), top + int(r0), int(c1 - c0), int(r1 - r0)


def _extend_box(box: np.ndarray, ext: int, height: int, width: int) -> np.ndarray:
    """(4,) int (top, left, bottom, right) grown by ``ext`` on every side, clipped as the benchmark
    clips: every coordinate at 0 from below, bottom at H-1 and right at W-1 from above."""
    out = box + np.array([-ext, -ext, ext, ext])
    out[out < 0] = 0
    out[2] = min(out[2], height - 1)
    out[3] = min(out[3], width - 1)
    return out


def _select(imgs: Path, dataset: str) -> list[str]:
    """Names of the sequence folders of ``dataset`` under ``imgs``, in the benchmark's order."""
    if not imgs.is_dir():
        return []
    # glob, as the benchmark uses, skips names that start with a dot; only folders are sequences.
    names = [p.name for p in imgs.iterdir() if p.is_dir() and not p.name.startswith(".")]
    if dataset == "tbd":
        names = [n for n in names if fnmatchcase(n, "*_*") and "ping_wall" not in n and "fall_coin" not in n]
        # A stable sort: the benchmark's np.argsort leaves ties (a name with and without VS_) unordered.
        return sorted(names, key=lambda n: n.replace("VS_", ""))
    pattern = "*_GT_*" if dataset == "tbd3d" else "*_GTgamma"
    return sorted(n for n in names if fnmatchcase(n, pattern))


def _read_roi(path: Path) -> np.ndarray | None:
    """(S, 2) int rows of ``start end`` (inclusive frame numbers) from roi_frames.txt, or None without one."""
    if not path.exists():
        return None
    table = _loadtxt(path)
    if table.shape[1] < 2:
        raise SfbError(f"{path} must hold two columns (first and last frame), got {table.shape[1]}")
    # The benchmark's astype(int) truncates.
    return table[:, :2].astype(int)


def _load_sequence(root: Path, dataset: str, name: str, position: int, roi: np.ndarray | None) -> BenchmarkSequence:
    """Read the frame range and the GT tables of sequence ``name``, the ``position``-th of its dataset."""
    folder = root / "imgs" / name
    name_subframes = 12 if "-12" in name else 8
    if roi is None:
        first = 0
        count = len(glob.glob(os.path.join(glob.escape(str(folder)), "*.png")))
    else:
        if position >= roi.shape[0]:
            raise SfbError(f"{root / 'roi_frames.txt'} has {roi.shape[0]} rows, none for sequence {position} ({name})")
        first, last = (int(v) for v in roi[position])
        count = last - first + 1
    if not (folder / f"{0:08d}.png").exists():
        first += 1  # the sequence is numbered from 1
    if count < 1:
        raise SfbError(f"sequence {folder} has no frames")

    gt_txt = folder / "gt.txt"
    bbox_txt = root / "gt_bbox" / f"{name}.txt"
    if gt_txt.exists():
        pars = _loadtxt(gt_txt)
        # Rows 2f and 2f+1 are the x and y of file f's sub-frames: (R, 2, N) -> (R, N, 2).
        centres = pars[: pars.shape[0] // 2 * 2].reshape(-1, 2, pars.shape[1]).transpose(0, 2, 1)
        radii = _radius_table(root, folder, name)
    elif bbox_txt.exists():
        # The benchmark reads the radius from gt_bbox too in this case, even where gtr.txt or a
        # template exists.
        centres, radii = _bbox_tables(bbox_txt, name_subframes, first)
    else:
        raise SfbError(f"sequence {folder} has no GT trajectory: neither {gt_txt} nor {bbox_txt} exists")
    if centres.shape[0] < first + count:
        raise SfbError(f"the GT trajectory of {folder} covers {centres.shape[0]} frames, it needs {first + count}")
    if radii.shape[0] > 1 and radii.shape[0] < first + count:
        raise SfbError(f"the GT radii of {folder} cover {radii.shape[0]} frames, it needs {first + count}")

    gt_folder = root / "imgs_gt" / name
    if not gt_folder.is_dir():
        raise SfbError(f"sequence {folder} has no GT sub-frames: {gt_folder} does not exist")
    return BenchmarkSequence(
        dataset=dataset,
        name=name,
        folder=folder,
        # The benchmark overrides the name's count with the trajectory's column count.
        num_subframes=int(centres.shape[1]),
        num_frames=count,
        first_file=first,
        gt_folder=gt_folder,
        gt_offset=0 if (gt_folder / f"{0:08d}.png").exists() else 1,
        centres_table=centres,
        radius_table=radii,
    )


def _radius_table(root: Path, folder: Path, name: str) -> np.ndarray:
    """(R, C) radii of a sequence with a gt.txt: gtr.txt's rows if there is one, else the template's
    single radius (template height / 2 / scale) as a (1, 1) table."""
    gtr = folder / "gtr.txt"
    if gtr.exists():
        return _loadtxt(gtr)
    template_path = root / "templates" / f"{name}_template.mat"
    if not template_path.exists():
        raise SfbError(f"sequence {folder} has no GT radius: neither {gtr} nor {template_path} exists")
    try:
        data = scipy.io.loadmat(str(template_path))
        template, scale = data["template"], data["scale"]
    except (OSError, ValueError, KeyError, TypeError, NotImplementedError) as e:
        raise SfbError(f"cannot read the template {template_path}: {_first_line(e)}") from e
    return np.atleast_2d((template.shape[0] / 2) / np.asarray(scale, dtype=float))


def _bbox_tables(path: Path, num_subframes: int, first: int) -> tuple[np.ndarray, np.ndarray]:
    """Centres (R, N, 2) and radii (R, N) from a gt_bbox file of ``x y w h`` rows, one per sub-frame.

    The centre is the box's centre, the radius half its longer side; ``first`` empty frames are put in
    front, as the benchmark does, so that both tables are indexed by file number.
    """
    boxes = _loadtxt(path)
    if boxes.shape[1] != 4 or boxes.shape[0] % num_subframes:
        raise SfbError(
            f"{path} must hold x y w h rows, {num_subframes} per frame; got {boxes.shape[0]} rows of {boxes.shape[1]}"
        )
    centres = (boxes[:, :2] + 0.5 * boxes[:, 2:]).reshape(-1, num_subframes, 2)
    radii = np.max(0.5 * boxes[:, 2:], axis=1).reshape(-1, num_subframes)
    centres = np.concatenate([np.zeros((first, num_subframes, 2)), centres])
    radii = np.concatenate([np.zeros((first, num_subframes)), radii])
    return centres, radii


def _loadtxt(path: Path) -> np.ndarray:
    """A whitespace-separated table of numbers as a 2-D float64 array (a single row stays a row)."""
    try:
        table = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as e:
        raise SfbError(f"cannot read the table {path}: {_first_line(e)}") from e
    if table.size == 0:
        raise SfbError(f"the table {path} is empty")
    return table


def _first_line(error: BaseException) -> str:
    """The first line of an exception's message (or its repr when it has none), for a one-line error."""
    text = str(error).strip()
    return text.splitlines()[0] if text else repr(error)


def _read_png(path: Path) -> tuple[np.ndarray, float]:
    """A PNG as stored, (H, W, 3) uint8 or uint16 RGB (alpha dropped), and the value of full scale.

    Values are normalised by the dtype's full scale (255 or 65535). The benchmark's own imread keys on
    the channel count instead (3 channels: /255, 4 channels: /65535, and it keeps the alpha); for
    3-channel 16-bit files, whose values it would put in [0, 257], dividing by the dtype is the
    correct reading.
    """
    if not path.is_file():
        raise SfbError(f"missing PNG {path}")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SfbError(f"cannot read PNG {path}")
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise SfbError(f"PNG {path} is not RGB or RGBA (shape {image.shape})")
    if image.dtype == np.uint8:
        scale = 255.0
    elif image.dtype == np.uint16:
        scale = 65535.0
    else:
        raise SfbError(f"PNG {path} has unsupported sample type {image.dtype}")
    # cv2 gives BGR(A): reverse to RGB, dropping alpha.
    return np.ascontiguousarray(image[:, :, 2::-1]), scale


def _median(window: np.ndarray, scale: float) -> np.ndarray:
    """(H, W, 3) float64 per-pixel median of ``window`` (m, H, W, 3), divided by ``scale``.

    Taken on the stored integers, row chunk by row chunk, so the working copy is small. With an even
    m the two middle values are scaled before they are averaged, which is the benchmark's arithmetic
    (np.median of frames already divided by the scale), bit for bit.
    """
    m, height = window.shape[0], window.shape[1]
    hi = m // 2
    kth = [hi] if m % 2 else [hi - 1, hi]
    out = np.empty(window.shape[1:], dtype=np.float64)
    for r0 in range(0, height, _MEDIAN_ROWS):
        part = np.partition(window[:, r0 : r0 + _MEDIAN_ROWS], kth, axis=0)
        if m % 2:
            out[r0 : r0 + _MEDIAN_ROWS] = part[hi] / scale
        else:
            out[r0 : r0 + _MEDIAN_ROWS] = (part[hi - 1] / scale + part[hi] / scale) / 2
    return out
