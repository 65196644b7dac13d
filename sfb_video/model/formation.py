"""Image formation over one exposure (paper, eq. 4), in our explicit-coverage form.

    I_hat = mean_t(F_t * A_t) + (1 - mean_t(A_t)) * B

with F_t the rendered colour and A_t the soft silhouette at time step t of T. A sub-frame
k of N (temporal super-resolution) is the same integral over [k / N, (k + 1) / N]: the time
steps falling in that interval, composited over B.
"""

from __future__ import annotations

import torch


def exposure_times(time_steps: int, device: torch.device | str = "cpu") -> torch.Tensor:
    """(T,) midpoints of T equal slices of the exposure [0, 1]: the quadrature nodes."""
    return (torch.arange(time_steps, device=device, dtype=torch.float32) + 0.5) / time_steps


def composite(rgb: torch.Tensor, alpha: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    """Blur T renders over a background.

    Args:
        rgb: (T, 3, H, W) rendered colour.
        alpha: (T, 1, H, W) soft silhouette.
        background: (3, H, W).

    Returns:
        (3, H, W) the blurred image.
    """
    return (rgb * alpha).mean(0) + (1 - alpha.mean(0)) * background


def subframes(rgb: torch.Tensor, alpha: torch.Tensor, background: torch.Tensor, n: int) -> torch.Tensor:
    """Split T renders into ``n`` consecutive sub-frames, each composited over the background.

    Args:
        rgb, alpha, background: as for :func:`composite`; T must be a multiple of ``n``.

    Returns:
        (n, 3, H, W) sub-frames; their mean is :func:`composite` of all T renders.
    """
    steps = rgb.shape[0]
    if steps % n:
        raise ValueError(f"{steps} time steps cannot be split into {n} equal sub-frames")
    k = steps // n
    rgb_k = rgb.reshape(n, k, *rgb.shape[1:])
    alpha_k = alpha.reshape(n, k, *alpha.shape[1:])
    return (rgb_k * alpha_k).mean(1) + (1 - alpha_k.mean(1)) * background
