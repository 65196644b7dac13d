"""Stage 3b, masks: which sub-frame masks the fits use, and each frame's masks in time order.

With DeFMO's weights at hand, each detected frame gets DeFMO's sub-frame masks and the fitter
uses the silhouette loss L_S on them; without, it uses the difference-image loss L_D (paper,
Table 2: TIoU 0.693 with DeFMO's masks, 0.591 with L_D). ``auto`` takes DeFMO when its weights
are already on this machine and never reaches the network; ``defmo`` downloads them when
missing. DeFMO cannot tell which way its sub-frames run; a frame whose direction the track
already knows gets its masks in that direction (:func:`orient_masks`).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from kornia.feature import DeFMO

from sfb_video.config import CropConfig
from sfb_video.crop import Box, Crop
from sfb_video.defmo import cache_dir, defmo_masks, download_weights, has_weights, load_defmo
from sfb_video.errors import SfbError
from sfb_video.stages.types import FrameWithBackground

MODES = ("auto", "defmo", "diff")


MaskMaker = Callable[[FrameWithBackground, Box, Crop, int], torch.Tensor]
"""(frame, object box, the crop around it, n) -> (n, h, w) sub-frame masks on the crop, in some
time order."""


@dataclass(frozen=True)
class MaskSource:
    """Where a run's sub-frame masks come from.

    Attributes:
        name: ``"defmo"`` (L_S on DeFMO's masks), ``"diff"`` (L_D on the difference mask), or
            another name for masks from elsewhere (the tests use the synthetic ground truth).
        reason: why, in words, for the log and ``summary.json``.
        make: makes a frame's masks; None for the difference mask.
    """

    name: str
    reason: str
    make: MaskMaker | None = None

    def masks(self, frame: FrameWithBackground, box: Box, crop: Crop, n: int) -> torch.Tensor | None:
        """(n, h, w) sub-frame masks of the object in ``box`` on ``crop``, or None for the difference mask."""
        return None if self.make is None else self.make(frame, box, crop, n)


def defmo_source(network: DeFMO, config: CropConfig, reason: str) -> MaskSource:
    """DeFMO's masks, in DeFMO's time order (which may run either way: one image cannot tell)."""

    def make(frame: FrameWithBackground, box: Box, crop: Crop, n: int) -> torch.Tensor:
        return defmo_masks(network, frame.image, frame.background, box, crop, n, config)

    return MaskSource("defmo", reason, make)


def print_line(line: str) -> None:
    """The default log: one line on stderr, where it does not mix with a command's results."""
    print(line, file=sys.stderr)


def choose_masks(
    mode: str,
    weights: Path | None,
    config: CropConfig,
    device: torch.device,
    log: Callable[[str], None] | None = print_line,
) -> MaskSource:
    """Resolve ``--masks`` and ``--defmo-weights`` into a :class:`MaskSource`, saying which and why.

    Args:
        mode: ``auto`` (DeFMO when its weights are here, else the difference mask), ``defmo``
            (download the weights when missing) or ``diff``.
        weights: a folder holding DeFMO's ``encoder_best.pt`` and ``rendering_best.pt``
            (default: torch hub's cache).
        config: where DeFMO looks around an object (``defmo_margin``).
        device: where DeFMO runs.
        log: receives the one line that says which masks are used and why (None: silent).

    Raises:
        SfbError: an unknown mode; a ``weights`` folder without the weights or whose weights do
            not load; ``defmo`` when the weights cannot be downloaded or do not load (``auto``
            falls back to the difference mask when the cached ones do not).
    """
    if mode not in MODES:
        raise SfbError(f"--masks must be one of {', '.join(MODES)}, got {mode!r}")
    if weights is not None and not has_weights(weights):
        raise SfbError(f"--defmo-weights {weights}: no encoder_best.pt and rendering_best.pt there")
    cache = cache_dir()
    if mode == "diff":
        source = MaskSource("diff", "asked for with --masks diff")
    elif weights is not None:
        source = defmo_source(load_defmo(weights, device), config, f"weights from {weights}")
    elif has_weights(cache):
        try:
            source = defmo_source(load_defmo(cache, device), config, f"weights from {cache}")
        except SfbError as exc:
            if mode == "defmo":
                raise
            source = MaskSource("diff", f"{exc}; delete them and run with --masks defmo to download them again")
    elif mode == "defmo":
        source = defmo_source(load_defmo(download_weights(), device), config, f"weights downloaded to {cache}")
    else:
        source = MaskSource(
            "diff",
            f"no DeFMO weights in {cache} (download them once with --masks defmo, or pass --defmo-weights FOLDER)",
        )
    if log is not None:
        what = "DeFMO's sub-frame masks (L_S)" if source.name == "defmo" else "the difference image (L_D)"
        log(f"masks: {what}: {source.reason}")
    return source


def mask_centroids(masks: torch.Tensor) -> torch.Tensor:
    """(N, 2) mask-weighted centres (u, v), in pixels, of (N, h, w) soft sub-frame masks."""
    h, w = masks.shape[1:]
    ys = torch.arange(h, dtype=masks.dtype, device=masks.device)
    xs = torch.arange(w, dtype=masks.dtype, device=masks.device)
    mass = masks.sum((1, 2)).clamp_min(1e-8)
    return torch.stack(((masks.sum(1) * xs).sum(1) / mass, (masks.sum(2) * ys).sum(1) / mass), -1)


def orient_masks(masks: torch.Tensor, start_uv: torch.Tensor) -> tuple[torch.Tensor, bool]:
    """``masks`` (N, h, w) in the time order that starts nearer ``start_uv`` (2,), and whether reversed."""
    first, last = mask_centroids(masks[[0, -1]])
    start_uv = start_uv.to(first)
    if float((last - start_uv).norm()) < float((first - start_uv).norm()):
        return masks.flip(0), True
    return masks, False
