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


def blend(rgb: torch.Tensor, alpha: torch.Tensor, background: torch.Tensor) -> torch.Tensor:
    """Blur T renders over a background.

    Args:
        rgb: (T, 3, H, W) rendered colour.
        alpha: (T, 1, H, W) soft silhouette.
        background: (3, H, W).

    Returns:
        (3, H, W) the blurred image.
    """
    return (rgb * alpha).mean(0) + (1 - alpha.mean(0)) * background
