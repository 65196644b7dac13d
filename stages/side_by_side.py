"""Objects falling beside each other, their streaks one blob: the blob's strong cores, which are
two objects' streaks (parallel, beside each other, one ahead of the other), and the blob shared
out among them."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from sfb_video.config import DetectConfig


@dataclass(frozen=True)
class Core:
    """A connected run of a blob's strong pixels (above ``detect.threshold``).

    Attributes:
        pixels: (N, 2) its pixels' (x, y); centre: (2,) their mean; axis: (2,) unit, the
            direction of their greatest spread; width: four standard deviations across it.
    """

    pixels: np.ndarray
    centre: np.ndarray
    axis: np.ndarray
    width: float

    @classmethod
    def of(cls, where: np.ndarray) -> Core:
        """The core of the (h, w) bool ``where``."""
        pixels = np.stack(np.nonzero(where)[::-1], 1).astype(np.float64)
        centre = pixels.mean(0)
        spread, directions = np.linalg.eigh(np.cov((pixels - centre).T))
        return cls(pixels, centre, directions[:, 1], 4 * math.sqrt(max(float(spread[0]), 0.0)))

    def extent(self, axis: np.ndarray, origin: np.ndarray) -> tuple[float, float]:
        along = (self.pixels - origin) @ axis
        return float(along.min()), float(along.max())


def parallel(a: np.ndarray, b: np.ndarray, max_deg: float) -> bool:
    """Whether two (2,) unit directions in the image differ by at most ``max_deg`` degrees
    (either way along a line)."""
    return math.degrees(math.acos(min(1.0, abs(float(a @ b))))) <= max_deg


def apart(a: Core, b: Core, config: DetectConfig) -> bool:
    """Whether two strong cores of one blob are two objects' streaks: parallel
    (``parallel_deg``), beside each other (their centres more than half their mean width apart
    across the longer one's axis: not a streak cut in a row by a fence's wire) and one ahead of the
    other (their extents along it share less than ``aligned`` of the shorter: not a ring's two
    sides)."""
    if not parallel(a.axis, b.axis, config.parallel_deg):
        return False
    ea, eb = a.extent(a.axis, a.centre), b.extent(a.axis, a.centre)
    longer = a if ea[1] - ea[0] >= eb[1] - eb[0] else b
    offset = b.centre - a.centre
    across = abs(float(offset[0] * -longer.axis[1] + offset[1] * longer.axis[0]))
    if across <= (a.width + b.width) / 4:
        return False
    ea, eb = a.extent(longer.axis, a.centre), b.extent(longer.axis, a.centre)
    shared = min(ea[1], eb[1]) - max(ea[0], eb[0])
    return shared < config.aligned * min(ea[1] - ea[0], eb[1] - eb[0])


def side_by_side(blob: np.ndarray, difference: np.ndarray, config: DetectConfig) -> list[np.ndarray] | None:
    """A (h, w) bool ``blob`` whose strong cores (its (h, w) :func:`difference_image` above
    ``threshold``, closed by ``core_close_px``) are the streaks of objects falling beside each
    other shared out among them: (h, w) bool parts, or None where the blob is one object's (or a
    part would be smaller than ``min_area_px``).

    Cores that are not apart (:func:`apart`) are one object's, and so are the cores not apart from
    those, in a chain: a curved streak's pieces, each at an angle to the next, stay one object
    (a swinging ball's). Only cores of at least ``core_share`` of the largest
    count; their pixels go to their objects, every other pixel of the blob to the object whose
    largest core's axis lies nearest. (The hysteresis joins such streaks by their faint fringes.)"""
    min_area = config.min_area_px
    strong = (blob & (difference > config.threshold)).astype(np.uint8)
    close = np.ones((config.core_close_px,) * 2, np.uint8)
    strong = cv2.morphologyEx(strong, cv2.MORPH_CLOSE, close) & blob
    count, cores = cv2.connectedComponents(strong.astype(np.uint8), connectivity=8)
    sizes = np.bincount(cores.ravel(), minlength=count)
    sizes[0] = 0
    # Three pixels at least: a core's axis is the spread of its pixels.
    big = [
        k for k in np.argsort(-sizes, kind="stable") if sizes[k] >= max(min_area, 3, config.core_share * sizes.max())
    ]
    found = [Core.of(cores == k) for k in big]
    group = list(range(len(found)))  # cores not apart are one object's, and so on in a chain
    for i, j in itertools.combinations(range(len(found)), 2):
        if group[i] != group[j] and not apart(found[i], found[j], config):
            group = [group[i] if g == group[j] else g for g in group]
    # Each object's largest core (``big`` runs largest first), and all its cores.
    members = {g: [int(big[k]) for k in range(len(found)) if group[k] == g] for g in dict.fromkeys(group)}
    objects = [(found[group.index(g)], ks) for g, ks in members.items()]
    if len(objects) < 2:
        return None
    # A pixel outside the cores goes to the object whose largest core's axis, between its ends, lies
    # nearest: a streak's faint tail beyond its core lies on its own axis, nearer another core.
    v, u = np.mgrid[: blob.shape[0], : blob.shape[1]]
    points = np.stack((u, v), -1).astype(np.float64)
    distances = []
    for core, _ in objects:
        lo, hi = core.extent(core.axis, core.centre)
        along = np.clip((points - core.centre) @ core.axis, lo, hi)
        on_axis = np.linalg.norm(points - core.centre - along[..., None] * core.axis, axis=-1)
        distances.append(on_axis - core.width / 2)
    owner = np.argmin(np.stack(distances), axis=0)
    for k, (_, ks) in enumerate(objects):
        owner[np.isin(cores, ks)] = k
    parts = [blob & (owner == k) for k in range(len(objects))]
    return None if min(int(p.sum()) for p in parts) < min_area else parts
