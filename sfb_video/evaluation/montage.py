"""Montages a person can look at: each sequence's true sub-frames beside the ones we render.

Per sequence and mode, one PNG: a pair of rows per frame, the truth's sub-frames above ours,
each on the frame's tight box (the region the benchmark scores), scaled to a common height, with
the blurred input as the first column of both rows. A number can hide a box drawn as a ball; a
picture cannot.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from sfb_video.evaluation.datasets import BenchmarkFrame
from sfb_video.evaluation.runner import FrameRow, true_subframes
from sfb_video.imageio import write_image

TILE_PX = 96
"""Height of every tile: small objects are scaled up, so their shape can be seen."""
GAP_PX = 2


def _tile(image: np.ndarray, width: int) -> np.ndarray:
    return cv2.resize(image.astype(np.float32), (width, TILE_PX), interpolation=cv2.INTER_NEAREST)


class Montages:
    """The frames' sub-frames, collected per (sequence, mode) as they are scored."""

    def __init__(self) -> None:
        self.frames: dict[tuple[str, str], list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = defaultdict(list)

    def add(self, sequence: str, mode: str, image: np.ndarray, truth: np.ndarray, ours: np.ndarray) -> None:
        """One frame: its blurred box (h, w, 3) and the true and our (N, h, w, 3) sub-frames, in [0, 1]."""
        self.frames[(sequence, mode)].append((image, truth, ours))

    def add_frame(self, row: FrameRow, frame: BenchmarkFrame, ours: np.ndarray) -> None:
        """A scored frame, as the evaluation runner hands it (:data:`~sfb_video.evaluation.runner.ImageSink`)."""
        x, y, w, h = frame.box
        self.add(row.sequence, row.mode, frame.image[y : y + h, x : x + w], true_subframes(frame), ours)

    def write(self, folder: Path) -> list[Path]:
        """One PNG per (sequence, mode) into ``folder``: ``<sequence>_<mode>.png``."""
        folder.mkdir(parents=True, exist_ok=True)
        written = []
        for (sequence, mode), frames in self.frames.items():
            h, w = frames[0][0].shape[:2]
            width = max(1, round(w * TILE_PX / h))
            rows = []
            for image, truth, ours in frames:
                for subframes in (truth, ours):
                    tiles = [_tile(image, width)] + [_tile(s, width) for s in subframes]
                    gap = np.ones((TILE_PX, GAP_PX, 3), np.float32)
                    rows.append(np.concatenate([t for tile in tiles for t in (tile, gap)][:-1], axis=1))
                rows.append(np.ones((GAP_PX * 3, rows[-1].shape[1], 3), np.float32))
            path = folder / f"{sequence}_{mode}.png"
            write_image(path, np.concatenate(rows[:-1], axis=0))
            written.append(path)
        return written
