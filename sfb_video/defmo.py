"""DeFMO's sub-frame masks of a crop, from kornia's network (Rozumnyi et al., CVPR 2021).

DeFMO takes a blurred image and its background and returns the object's appearance and alpha
mask at 24 times spread over the exposure. Shape from Blur fits its silhouettes to those masks
(L_S) and reaches its best scores that way (paper, Table 2). The network ships with kornia; its
two weight files (``encoder_best.pt``, ``rendering_best.pt``) come from Hugging Face and are
kept in torch hub's cache (``~/.cache/torch/hub/checkpoints``), where a folder given by the
user can also hold them. Nothing here reaches the network unless :func:`download_weights` is
called.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import torch
import torch.nn.functional as F
from kornia.core.download import load_state_dict_from_url
from kornia.feature import DeFMO
from kornia.feature.defmo import urls

from sfb_video.config import CropConfig
from sfb_video.crop import Box, Crop, crop_box, masks_onto
from sfb_video.errors import SfbError

INPUT_SIZE = (240, 320)
"""(height, width) DeFMO was trained at; its windows are 4:3 like crops, so resizing keeps shapes."""
WEIGHT_FILES = {"encoder": "encoder_best.pt", "rendering": "rendering_best.pt"}
"""Each part of the network and the file that holds its weights (kornia's names)."""
DOWNLOAD_TIMEOUT_S = 30.0
"""A download that stalls this long fails instead of hanging."""


def cache_dir() -> Path:
    """Where torch hub, and so kornia, keeps downloaded weights."""
    return Path(torch.hub.get_dir()) / "checkpoints"


def has_weights(folder: Path) -> bool:
    """Whether ``folder`` holds both of DeFMO's weight files."""
    return all((folder / name).is_file() for name in WEIGHT_FILES.values())


def download_weights(timeout: float = DOWNLOAD_TIMEOUT_S) -> Path:
    """Fetch DeFMO's weights into torch hub's cache (about 170 MB) and return that folder.

    Raises:
        SfbError: when they cannot be fetched (no network, a server error, a stalled transfer).
    """
    for part in WEIGHT_FILES:
        try:
            load_state_dict_from_url(urls[f"defmo_{part}"], timeout=timeout, map_location="cpu")
        except Exception as exc:  # any failure to fetch is the same to a user
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise SfbError(f"cannot download the DeFMO weights ({reason}); use --masks diff") from None
    return cache_dir()


def load_defmo(folder: Path, device: torch.device) -> DeFMO:
    """DeFMO with the weights in ``folder``, in evaluation mode on ``device``.

    Raises:
        SfbError: when a weight file is missing, unreadable or not DeFMO's.
    """
    paths = {part: folder / name for part, name in WEIGHT_FILES.items()}
    missing = [str(p) for p in paths.values() if not p.is_file()]
    if missing:
        raise SfbError(f"no DeFMO weights at {', '.join(missing)}")
    network = DeFMO(pretrained=False)
    for part, path in paths.items():
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception:  # pickle, zip and EOF errors all mean the same to a user
            raise SfbError(f"cannot load the DeFMO weights {path}: not a PyTorch weight file") from None
        try:
            getattr(network, part).load_state_dict(state, strict=True)
        except (RuntimeError, TypeError, AttributeError) as exc:
            reason = str(exc).splitlines()[0]
            raise SfbError(f"cannot load the DeFMO weights {path}: they do not fit DeFMO's {part} ({reason})") from None
    return network.eval().to(device)


def time_bins(count: int, n: int) -> torch.Tensor:
    """(n, count) weights that average ``count`` instants k / (count - 1) into ``n`` sub-frames.

    Sub-frame j covers [j / n, (j + 1) / n) of the exposure, as the fitter's sub-frames do; each
    instant goes to the sub-frame it falls in, the last one (time 1) to the last sub-frame.
    """
    times = torch.linspace(0, 1, count)
    index = (times * n).floor().long().clamp(max=n - 1)
    bins = F.one_hot(index, n).T.float()
    if bool((bins.sum(1) == 0).any()):
        raise SfbError(f"{count} DeFMO sub-frames cannot fill {n} sub-frames; use at most {count} time steps")
    return bins / bins.sum(1, keepdim=True)


@torch.no_grad()  # not inference_mode: the masks go into a loss that autograd tracks
def defmo_masks(
    network: DeFMO,
    image: torch.Tensor,
    background: torch.Tensor,
    box: Box,
    crop: Crop,
    n: int,
    config: CropConfig,
) -> torch.Tensor:
    """DeFMO's alpha masks of the object in ``box``, averaged into ``n`` sub-frames, on ``crop``.

    DeFMO sees a 4:3 window of the frame around ``box``, wider than the crop
    (``config.defmo_margin``), resized to its 320x240 with the background as 6 channels; its
    alphas are resized back onto the window and cut to the crop at the crop's working size.

    Args:
        image, background: (3, H, W) the whole frame and its background, in [0, 1].
        box: (x, y, w, h) the object's box in the frame.
        crop: the working crop the fit uses, cut around ``box``.
        n: sub-frames to average DeFMO's 24 instants into.

    Returns:
        (n, h, w) soft masks in [0, 1] at the crop's size, in DeFMO's time order (which may run
        either way: one blurred image cannot tell).
    """
    device = next(network.parameters()).device
    height, width = image.shape[1:]
    wx, wy, ww, wh = crop_box(
        box, (width, height), replace(config, margin=config.defmo_margin, aspect=INPUT_SIZE[1] / INPUT_SIZE[0])
    )
    pair = torch.cat((image, background))[None, :, wy : wy + wh, wx : wx + ww].to(device)
    pair = F.interpolate(pair, size=INPUT_SIZE, mode="bilinear", antialias=True, align_corners=False)
    alpha = network(pair)[0, :, 3, : INPUT_SIZE[0], : INPUT_SIZE[1]]  # (24, 240, 320)
    grouped = torch.einsum("nk,khw->nhw", time_bins(alpha.shape[0], n).to(alpha), alpha)
    return masks_onto(grouped, (wx, wy, ww, wh), crop).to(crop.image.device)
