"""Stage 3, detect: find the fast moving object (FMO) in a frame, or report that there is none.

The difference D = ||I - B||_2 > threshold (with weaker differences connected to it) is opened
to remove noise. An FMO travels further than its own size within one frame, so the pixels it
covers now show something else in the frames two before and two after (two and three away on
the one side a clip's end leaves), while a slow mover (an arm, a person) differs from the
background there too, and a change of the scene still shows the same in the later ones: such
pixels are dropped (:func:`moving_mask`), and what is left is split into blobs (fragments a few
pixels apart joined). A tracked object is looked for near where its motion predicts it, among
blobs large enough for its predicted size, preferring large blobs near the prediction and of
its colour, and shades (a shadow's faint change of brightness) least; otherwise the largest blob
wins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np
import torch

from sfb_video.config import DetectConfig
from sfb_video.crop import Box, box_union, mask_box
from sfb_video.imageio import as_float
from sfb_video.stages.side_by_side import side_by_side
from sfb_video.stages.types import Detection, FrameWithBackground, Prediction
from sfb_video.timing import timed


def _opened(mask: np.ndarray, config: DetectConfig) -> torch.Tensor:
    """(H, W) bool mask opened by an ``open_px`` square, which removes specks of noise."""
    out = mask.astype(np.uint8)
    if config.open_px > 1:
        out = cv2.morphologyEx(out, cv2.MORPH_OPEN, np.ones((config.open_px, config.open_px), np.uint8))
    return torch.from_numpy(out.astype(bool))


DIFFERENCE_BAND_VALUES = 1 << 22
"""The difference is taken a band of rows at a time, over about this many values, so that its
float temporaries stay small for any frame size."""


@timed("detect")
def difference_image(image: torch.Tensor, background: torch.Tensor) -> np.ndarray:
    """(H, W) float32 ||I - B||_2 over RGB (the paper's D before its threshold).

    Args:
        image, background: (3, H, W), each uint8 or float32 in [0, 1] (as frames are kept).
    """
    height, width = image.shape[1:]
    difference = np.empty((height, width), dtype=np.float32)
    rows = max(1, DIFFERENCE_BAND_VALUES // (3 * width))
    for top in range(0, height, rows):
        band = as_float(image[:, top : top + rows]) - as_float(background[:, top : top + rows])
        # Written out: torch's norm over the channel dimension took 70 ms a 640x480 frame on
        # this CPU (a strided reduction), this 0.4 ms; they differ by float rounding.
        band.square_()
        difference[top : top + rows] = band[0].add_(band[1]).add_(band[2]).sqrt_().cpu().numpy()
    return difference


def weak_level(difference: np.ndarray, config: DetectConfig, known: torch.Tensor | None = None) -> float:
    """The hysteresis's lower threshold for a frame's ``difference`` (H, W): ``weak_noise``
    times its noise level (over the ``known`` (H, W) bool pixels, all when None), at least
    ``weak_threshold`` and at most ``threshold``."""
    height, width = difference.shape
    every = (slice(None, None, max(1, height // 256)), slice(None, None, max(1, width // 256)))
    sample = difference[every]
    if known is not None and bool(known[every].any()):
        sample = sample[known[every].cpu().numpy()]
    # Most pixels show only noise, so the median difference is the noise level.
    noise = float(np.median(sample))
    return min(config.threshold, max(config.weak_threshold, config.weak_noise * noise))


def hysteresis(difference: np.ndarray, strong: np.ndarray, level: float) -> np.ndarray:
    """(H, W) bool: the 8-connected regions of ``difference`` > ``level`` that hold a pixel of
    ``strong`` (H, W) bool."""
    if not strong.any():
        return np.zeros_like(strong)
    _, labels = cv2.connectedComponents((difference > level).astype(np.uint8), connectivity=8)
    keep = np.zeros(int(labels.max()) + 1, dtype=bool)
    keep[labels[strong]] = True
    keep[0] = False
    return keep[labels]


@timed("detect")
def difference_mask(
    image: torch.Tensor, background: torch.Tensor, config: DetectConfig, known: torch.Tensor | None = None
) -> torch.Tensor:
    """(H, W) bool: ||I - B||_2 > threshold over RGB, with the weaker differences connected to
    those kept too (:func:`hysteresis` down to :func:`weak_level`), opened by an ``open_px``
    square.

    Args:
        image, background: (3, H, W), each uint8 or float32 in [0, 1] (as frames are kept).
        known: (H, W) bool the pixels compared with a background (a moving camera's,
            :attr:`~sfb_video.stages.types.FrameWithBackground.known`; None: all).
    """
    return threshold_difference(difference_image(image, background), config, known)


def threshold_difference(
    difference: np.ndarray, config: DetectConfig, known: torch.Tensor | None = None
) -> torch.Tensor:
    """:func:`difference_mask` of a frame's (H, W) :func:`difference_image`."""
    strong = difference > config.threshold
    return _opened(hysteresis(difference, strong, weak_level(difference, config, known)), config)


@dataclass(frozen=True)
class Neighbour:
    """What the slow-mover test needs of a frame two (or, at a clip's ends, three) before or after.

    Attributes:
        mask: (H, W) bool its difference mask.
        still: (H, W) bool where this frame still shows in that one (:func:`still_there`),
            for a later frame; none for an earlier one.
    """

    mask: torch.Tensor
    still: torch.Tensor


@timed("detect")
def moving_mask(mask: torch.Tensor, neighbours: list[Neighbour], config: DetectConfig) -> torch.Tensor:
    """(H, W) bool: the pixels of ``mask`` less those of a slow mover, opened again.

    A pixel is a slow mover's where it differs from the background in every neighbour (an arm
    that covers much the same pixels throughout; grown by ``motion_px`` first), or where it
    still shows in a later neighbour (a change of the scene that stays, a line drawn over the
    video). Removing pixels one by one, not blob by blob, keeps a streak that
    touches a slow mover (a ball passing an arm) apart from it.
    """
    kernel = np.ones((2 * config.motion_px + 1,) * 2, np.uint8)

    def grown(m: torch.Tensor) -> np.ndarray:
        return cv2.dilate(m.cpu().numpy().astype(np.uint8), kernel).astype(bool)

    keep = mask.cpu().numpy().astype(bool)
    if neighbours:
        everywhere = np.ones_like(keep)
        for n in neighbours:
            everywhere &= grown(n.mask)
            keep &= ~n.still.cpu().numpy()
        keep &= ~everywhere
    return _opened(keep, config)


def still_there(image: torch.Tensor, background: torch.Tensor, later: torch.Tensor) -> torch.Tensor:
    """(H, W) bool: where this frame looks more like a ``later`` frame than like its own
    background (||I - I_later|| below half of ||I - B||): what differs from the background now
    and still shows then, as a change of the scene or a line drawn over the video does. A fast
    mover's pixels do not: it has gone on, and the later frame shows the background there.

    Args:
        image, background, later: (3, H, W) each uint8 or float32 in [0, 1].
    """
    return torch.from_numpy(difference_image(image, later) < 0.25 * difference_image(image, background))


def detect(
    index: int,
    mask: torch.Tensor,
    neighbours: list[Neighbour],
    prediction: Prediction | None,
    config: DetectConfig,
) -> Detection | None:
    """The FMO among the blobs of one frame's difference ``mask``, or None.

    Args:
        index: the frame's index.
        mask: (H, W) bool difference mask of this frame (:func:`difference_mask`).
        neighbours: the frames two before and two after, where there are
            (:func:`sfb_video.stages.track.with_neighbours`).
        prediction: where a tracked object should be, if one is tracked.
        config: thresholds.
    """
    return choose_blob(index, moving_mask(mask, neighbours, config), prediction, config)


def blobs(mask: np.ndarray, config: DetectConfig) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """The blobs of a (H, W) bool ``mask``: fragments less than ``2 * merge_px`` apart joined
    into one (a streak cut by a fence's wires, or split where it crosses a background of its
    own colour), then fragments of at least ``min_area_px`` pixels whose boxes share
    ``merge_overlap`` of the smaller (the two sides of a ring's streak, a disc seen through a
    fence).

    Returns:
        as :func:`cv2.connectedComponentsWithStats`: the number of labels (0 is the
        background), (H, W) int32 labels of the mask's own pixels, (count, 5) x, y, w, h, area
        of each blob's own pixels, and (count, 2) their centroids.
    """
    grown = mask.astype(np.uint8)
    if config.merge_px > 0:
        grown = cv2.dilate(grown, np.ones((2 * config.merge_px + 1,) * 2, np.uint8))
    count, labels = cv2.connectedComponents(grown, connectivity=8)
    labels = np.where(mask, labels, 0).astype(np.int32)
    stats, _ = _blob_stats(mask, labels, count)
    parent = np.arange(count)
    big = [k for k in range(1, count) if stats[k, 4] >= config.min_area_px]
    changed = True
    while changed:  # boxes grow as they merge: repeat until none overlaps another
        changed = False
        for i, a in enumerate(big):
            for b in big[i + 1 :]:
                ra, rb = parent[a], parent[b]
                if ra != rb and _overlap(stats[ra], stats[rb], config.merge_overlap):
                    parent[parent == rb] = ra
                    stats[ra, :4] = box_union(stats[ra], stats[rb])
                    changed = True
    labels = parent[labels].astype(np.int32)
    stats, centroids = _blob_stats(mask, labels, count)
    return count, labels, stats, centroids


def _overlap(a: np.ndarray, b: np.ndarray, share: float) -> bool:
    """Whether two (x, y, w, h, ...) boxes share ``share`` of the smaller one."""
    w = min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0])
    h = min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1])
    return w > 0 and h > 0 and w * h >= share * min(a[2] * a[3], b[2] * b[3])


def _blob_stats(mask: np.ndarray, labels: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(count, 5) x, y, w, h, area and (count, 2) centroids of each label's pixels in ``mask``."""
    stats = np.zeros((count, 5), dtype=np.int64)
    centroids = np.zeros((count, 2))
    ys, xs = np.nonzero(mask)
    own = labels[ys, xs]
    area = np.bincount(own, minlength=count)
    for values, low, high, mean in ((xs, 0, 2, 0), (ys, 1, 3, 1)):
        lo = np.full(count, np.iinfo(np.int64).max)
        hi = np.full(count, -1)
        np.minimum.at(lo, own, values)
        np.maximum.at(hi, own, values)
        stats[:, low], stats[:, high] = lo, hi - lo + 1
        centroids[:, mean] = np.bincount(own, weights=values, minlength=count) / np.maximum(area, 1)
    stats[:, 4] = area
    return stats, centroids


def blob_colour(image: np.ndarray, background: np.ndarray, where: np.ndarray) -> tuple[float, float, float]:
    """The chromaticity (r, g, b summing to 1) of a blob's :func:`strongest_quarter`.

    Args:
        image, background: (3, H, W) the frame and its background, each uint8 or float in [0, 1].
        where: (H, W) bool, the blob.
    """
    r, g, b = (float(v) for v in _chromaticity(strongest_quarter(image, background, where).own))
    return r, g, b


@dataclass(frozen=True)
class Quarter:
    """What the quarter of a blob's pixels that differ most from the background shows: nearest
    the object's own colour, where a streak's fainter parts are mostly background.

    Attributes:
        own: (3,) their mean RGB in [0, 1]; behind: the background's there; difference: their
            mean ||I - B||.
    """

    own: np.ndarray
    behind: np.ndarray
    difference: float


def strongest_quarter(image: np.ndarray, background: np.ndarray, where: np.ndarray) -> Quarter:
    """The :class:`Quarter` of the blob ``where`` (H, W) bool in (3, H, W) ``image`` over
    ``background``, each uint8 or float in [0, 1]."""
    pixels, behind = _blob_pixels(image, where), _blob_pixels(background, where)
    change = np.linalg.norm(pixels - behind, axis=0)
    strongest = change >= np.quantile(change, 0.75)
    return Quarter(pixels[:, strongest].mean(1), behind[:, strongest].mean(1), float(change[strongest].mean()))


def _chromaticity(rgb: np.ndarray) -> np.ndarray:
    return rgb / max(float(rgb.sum()), 1e-6)


def _blob_pixels(image: np.ndarray, where: np.ndarray) -> np.ndarray:
    """(3, N) float32 in [0, 1]: the pixels of (3, H, W) ``image`` (uint8 or float in [0, 1]) where
    ``where`` (H, W) holds. Each array by its own type: a still clip's frames are uint8 over a
    float background where it is a given image or the whole clip's median."""
    pixels = image[:, where].astype(np.float32)
    return pixels / 255.0 if image.dtype == np.uint8 else pixels


def is_shade(quarter: Quarter, config: DetectConfig) -> bool:
    """Whether a blob (its :func:`strongest_quarter`) is a faint change of brightness alone
    (``shade_chroma``, ``shade_contrast``), as a shadow or a flicker of the light makes: no
    object's own colour shows in it."""
    chroma = float(np.abs(_chromaticity(quarter.own) - _chromaticity(quarter.behind)).sum())
    return chroma <= config.shade_chroma and quarter.difference < config.shade_contrast


@timed("detect")
def gate_distance(
    prediction: Prediction, centre: tuple[float, float], size: tuple[int, int], area: float, config: DetectConfig
) -> float | None:
    """Pixels from a track's ``prediction`` to a blob's ``centre`` when the blob may be the tracked
    object, else None: it is not smaller than the track's object allows (``min_fill`` of its
    disc) and lies within ``gate`` diameters of the prediction, plus half the blob's longer side
    of its ``size`` (w, h). The one rule by which a blob continues a track."""
    if area < max(config.min_area_px, config.min_fill * math.pi / 4 * prediction.diameter**2):
        return None
    distance = math.hypot(centre[0] - prediction.centre[0], centre[1] - prediction.centre[1])
    if distance > config.gate * max(prediction.diameter, 1.0) + max(size) / 2:
        return None
    return distance


@dataclass
class FrameBlobs:
    """The blobs of one frame's moving mask (:func:`blobs`), found once for every track that
    looks for its object there.

    Attributes:
        count, labels, stats, centroids: as :func:`blobs` returns them.
        pixels: the frame's (3, H, W) pixels and background as arrays, for the blobs' colours.
        changed: the frame's (H, W) bool difference mask (:func:`difference_mask`), slow movers
            not taken out, for :meth:`own_object`.
        joined: (count,) for each label, the label of the blob it was split from
            (:func:`side_by_side`), its own where it was not.
        config: the detection section: what makes a blob a shred or a shade.
    """

    count: int
    labels: np.ndarray
    stats: np.ndarray
    centroids: np.ndarray
    pixels: tuple[np.ndarray, np.ndarray] | None = None
    changed: np.ndarray | None = None
    joined: np.ndarray | None = None
    config: DetectConfig = field(default_factory=DetectConfig)

    def __post_init__(self) -> None:
        self._quarters: dict[int, Quarter] = {}
        self._changed_areas: tuple[np.ndarray, np.ndarray] | None = None

    def own_object(self, label: int) -> bool:
        """Whether blob ``label`` may be an object of its own beside another tracked one: not a
        shred of a larger mover (the changed regions it lies in, slow movers' pixels
        included, hold at most ``shred_ratio`` times its area: an arm whose fringe moved
        fast) and not a shade (a faint change of brightness alone: the shadow a ball casts on
        the wall). The first needs the frame's ``changed`` mask, the second its pixels; without
        them, a blob passes that test."""
        if self.changed is not None:
            if self._changed_areas is None:
                _, regions = cv2.connectedComponents(self.changed.astype(np.uint8), connectivity=8)
                self._changed_areas = regions, np.bincount(regions.ravel())
            regions, areas = self._changed_areas
            touched = np.unique(regions[self.labels == label])
            touched = touched[touched > 0]
            # Objects side by side, split from one blob, share their changed region.
            siblings = [label] if self.joined is None else np.flatnonzero(self.joined == self.joined[label]).tolist()
            own = sum(self.area(k) for k in siblings if k == label or np.isin(regions[self.labels == k], touched).any())
            if float(areas[touched].sum()) > self.config.shred_ratio * own:
                return False
        return not self.shade(label)

    def shade(self, label: int) -> bool:
        """Whether blob ``label`` is a shade (:func:`is_shade`); False without the frame."""
        quarter = self._quarter(label)
        return quarter is not None and is_shade(quarter, self.config)

    def colour(self, label: int) -> tuple[float, float, float] | None:
        """The chromaticity of blob ``label`` (:func:`blob_colour`), None without the frame."""
        quarter = self._quarter(label)
        if quarter is None:
            return None
        r, g, b = (float(v) for v in _chromaticity(quarter.own))
        return r, g, b

    def _quarter(self, label: int) -> Quarter | None:
        """Blob ``label``'s :func:`strongest_quarter`, found once for its colour and its shade."""
        if self.pixels is None:
            return None
        if label not in self._quarters:
            self._quarters[label] = strongest_quarter(*self.pixels, self.labels == label)
        return self._quarters[label]

    def area(self, label: int) -> float:
        return float(self.stats[label, cv2.CC_STAT_AREA])

    def detection(self, index: int, label: int, others: int = 0, part: np.ndarray | None = None) -> Detection:
        """Blob ``label`` as frame ``index``'s detection, or the ``part`` of it (an (H, W) bool
        mask, :meth:`split`) that is one object's where two objects' streaks touch."""
        if part is None:
            x, y, w, h = (int(v) for v in self.stats[label, :4])
            return Detection(index, (x, y, w, h), torch.from_numpy(self.labels == label), others, self.colour(label))
        box = mask_box(part)
        assert box is not None  # split() gives no empty part
        colour = None if self.pixels is None else blob_colour(*self.pixels, part)
        return Detection(index, box, torch.from_numpy(part), others, colour)

    def merge(self, label: int, pieces: list[int]) -> None:
        """Make blob ``label`` and the ``pieces`` (other labels) one blob, ``label``; the pieces
        are left empty (no pixel, no box, no area: no blob picks them), their centroids and
        colours as they were."""
        mask = np.isin(self.labels, [label, *pieces])
        self.labels[mask] = label
        box = mask_box(mask)
        assert box is not None  # blob label has pixels
        v, u = np.nonzero(mask)
        self.stats[label] = (*box, len(u))
        self.centroids[label] = (u.mean(), v.mean())
        self.stats[pieces] = 0
        self._quarters.pop(label, None)

    def split(self, label: int, predictions: list[Prediction], min_area: float) -> list[np.ndarray] | None:
        """Blob ``label`` shared out among the objects whose streaks ``predictions`` foresee
        touching in it (:func:`share_out`): (H, W) bool masks in the predictions' order, or None."""
        return share_out(self.labels == label, predictions, min_area)

    def touches(self, label: int, prediction: Prediction) -> bool:
        """Whether ``prediction``'s streak (the segment between its ends, widened by the object's
        radius) covers a pixel of blob ``label``; False where it has no ends."""
        if prediction.ends is None:
            return False
        x, y, w, h = (int(v) for v in self.stats[label, :4])
        v, u = np.nonzero(self.labels[y : y + h, x : x + w] == label)
        points = np.stack((u + x, v + y), 1).astype(np.float64)
        return bool((streak_distances(points, prediction) <= 0).any())


def streak_distances(points: np.ndarray, prediction: Prediction) -> np.ndarray:
    """(N,) how far each (x, y) of ``points`` (N, 2) lies from ``prediction``'s streak: from the
    segment between its ends, less the object's radius (negative inside the streak)."""
    assert prediction.ends is not None
    a, b = (np.array(e, dtype=np.float64) for e in prediction.ends)
    along = np.clip((points - a) @ (b - a) / max(float((b - a) @ (b - a)), 1e-9), 0.0, 1.0)
    nearest = a + along[:, None] * (b - a)
    return np.linalg.norm(points - nearest, axis=1) - prediction.diameter / 2


def share_out(
    blob: np.ndarray, predictions: list[Prediction], min_area: float, origin: tuple[int, int] = (0, 0)
) -> list[np.ndarray] | None:
    """An (h, w) bool ``blob`` whose top-left pixel is the frame's ``origin`` (x, y) shared out
    among the objects whose streaks ``predictions`` foresee touching in it: each pixel to the
    nearest predicted streak (the segment between its ends, less the object's radius). (h, w)
    bool masks in the predictions' order, or None where a prediction has no ends or a part
    would be smaller than ``min_area`` pixels."""
    if any(p.ends is None for p in predictions):
        return None
    v, u = np.nonzero(blob)
    points = np.stack((u + origin[0], v + origin[1]), 1).astype(np.float64)
    owner = np.argmin(np.stack([streak_distances(points, p) for p in predictions]), axis=0)
    parts = []
    for k in range(len(predictions)):
        part = np.zeros(blob.shape, dtype=bool)
        part[v[owner == k], u[owner == k]] = True
        if part.sum() < min_area:
            return None
        parts.append(part)
    return parts


def _split_side_by_side(
    labels: np.ndarray, stats: np.ndarray, frame: tuple[torch.Tensor, torch.Tensor], config: DetectConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The ``labels`` (H, W) of :func:`blobs` with each blob of objects side by side
    (:func:`side_by_side`) split into one label an object, and for each label the blob it was
    split from (:attr:`FrameBlobs.joined`). ``frame``: its (3, H, W) pixels and background."""
    joined = list(range(len(stats)))
    labels = labels.copy()
    for label in range(1, len(stats)):
        x, y, w, h, area = (int(v) for v in stats[label])
        if area < 2 * config.min_area_px:
            continue
        window = (slice(y, y + h), slice(x, x + w))
        difference = difference_image(*(f[(slice(None), *window)] for f in frame))
        parts = side_by_side(labels[window] == label, difference, config)
        for part in (parts or [])[1:]:
            labels[window][part] = len(joined)
            joined.append(label)
    return labels, np.array(joined)


def frame_blobs(
    moving: torch.Tensor,
    config: DetectConfig,
    frame: tuple[torch.Tensor, torch.Tensor] | None = None,
    changed: torch.Tensor | None = None,
) -> FrameBlobs:
    """The blobs of a frame's ``moving`` mask (:func:`moving_mask`), with the frame's pixels and
    background (3, H, W) each when given, for their colours and to split the blobs of objects
    side by side (:func:`side_by_side`), and its ``changed`` (H, W) difference mask, for
    :meth:`FrameBlobs.own_object`."""
    mask = moving.cpu().numpy().astype(bool)
    count, labels, stats, centroids = blobs(mask, config)
    pixels = None if frame is None else (frame[0].cpu().numpy(), frame[1].cpu().numpy())
    joined = None
    if frame is not None:
        labels, joined = _split_side_by_side(labels, stats, frame, config)
        count = len(joined)
        stats, centroids = _blob_stats(mask, labels, count)
    whole = None if changed is None else changed.cpu().numpy().astype(bool)
    return FrameBlobs(count, labels, stats, centroids, pixels, whole, joined, config)


def box_blobs(frame: FrameWithBackground, box: Box, config: DetectConfig, whole: bool = False) -> FrameBlobs:
    """The blobs of a frame whose object's ``box`` (x, y, w, h) is given (a benchmark hands it
    over): one blob, the box's changed pixels (``whole``: all its pixels), with the whole box as
    its box; none where nothing changed there. A track goes on into it by the same gate as into a
    detected blob."""
    x, y, w, h = box
    labels = np.zeros(tuple(frame.pixels.shape[1:]), np.int32)
    if whole:
        labels[y : y + h, x : x + w] = 1
    else:
        changed = difference_mask(frame.pixels, frame.background_pixels, config, frame.known)
        labels[y : y + h, x : x + w] = changed[y : y + h, x : x + w].cpu().numpy()
    ys, xs = np.nonzero(labels)
    pixels = (frame.pixels.cpu().numpy(), frame.background_pixels.cpu().numpy())
    if xs.size == 0:
        return FrameBlobs(1, labels, np.zeros((1, 5), np.int32), np.zeros((1, 2)), pixels, config=config)
    stats = np.array([[0, 0, 0, 0, 0], [x, y, w, h, xs.size]], np.int32)
    centroids = np.array([[0.0, 0.0], [xs.mean(), ys.mean()]])
    return FrameBlobs(2, labels, stats, centroids, pixels, config=config)


def blob_cost(found: FrameBlobs, label: int, prediction: Prediction, config: DetectConfig) -> float | None:
    """What it costs to take blob ``label`` for the object ``prediction`` foresees, or None
    outside its gate (:func:`gate_distance`): the miss ``m`` in the object's diameters as
    ``log(1 + m**2)``, plus ``log`` of how many times smaller than the frame's largest blob it is,
    of ``1 + (d / colour_scale)**2`` for a colour ``d`` off the prediction's, and of
    ``shade_penalty`` for a shade (:meth:`FrameBlobs.shade`). Nearness alone would pick a speck or
    a shred of a slow mover next to a poor prediction over the real streak a little further
    away, or an arm's shred or a wall's shadow near it over the object's own colour."""
    area = found.area(label)
    w, h = (int(v) for v in found.stats[label, 2:4])
    centre = (float(found.centroids[label][0]), float(found.centroids[label][1]))
    distance = gate_distance(prediction, centre, (w, h), area, config)
    if distance is None:
        return None
    largest = max(found.area(k) for k in range(1, found.count))
    cost = math.log1p((distance / max(prediction.diameter, 1.0)) ** 2) + math.log(largest / area)
    colour = found.colour(label)
    if prediction.colour is not None and colour is not None:
        cost += math.log1p((math.dist(colour, prediction.colour) / config.colour_scale) ** 2)
    if found.shade(label):
        cost += math.log(config.shade_penalty)
    return cost


def rivals(found: FrameBlobs, label: int, prediction: Prediction, config: DetectConfig) -> int:
    """How many other blobs within ``prediction``'s gate could have been blob ``label``'s object:
    those at least a quarter of its area."""
    quarter = found.area(label) / 4
    return sum(
        k != label and found.area(k) >= quarter and blob_cost(found, k, prediction, config) is not None
        for k in range(1, found.count)
    )


def pick_blob(found: FrameBlobs, prediction: Prediction | None, config: DetectConfig) -> tuple[int, int] | None:
    """The label of the FMO among ``found``'s blobs, and how many other blobs could have been it
    (:func:`rivals`), or None: without a ``prediction`` the largest blob of ``min_area_px`` or
    more; with one, the blob of least :func:`blob_cost`."""
    if prediction is None:
        sized = [k for k in range(1, found.count) if found.area(k) >= config.min_area_px]
        if not sized:
            return None
        label = max(sized, key=lambda k: (found.area(k), -k))
        return label, sum(k != label and found.area(k) >= found.area(label) / 4 for k in sized)
    costs = {k: c for k in range(1, found.count) if (c := blob_cost(found, k, prediction, config)) is not None}
    if not costs:
        return None
    label = min(costs, key=lambda k: (costs[k], k))
    return label, rivals(found, label, prediction, config)


def choose_blob(
    index: int,
    moving: torch.Tensor,
    prediction: Prediction | None,
    config: DetectConfig,
    frame: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> Detection | None:
    """The FMO among the blobs of a frame's ``moving`` mask (:func:`moving_mask`), or None
    (:func:`pick_blob`).

    Split from :func:`detect` so that a tracker trying several predictions on one frame runs
    the slow-mover test once. With the ``frame`` (its (3, H, W) pixels and background), the
    detection carries its blob's colour, and a prediction's colour (the track's) weighs blobs.
    """
    found = frame_blobs(moving, config, frame)
    picked = pick_blob(found, prediction, config)
    return None if picked is None else found.detection(index, *picked)
