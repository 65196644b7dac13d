"""The pinhole camera and how a crop of the frame changes it.

Convention:
    Camera coordinates follow OpenCV: x right, y down, z forward (depth > 0 in front).
    Pixel coordinates are continuous with pixel centres at integers: pixel (row i, column j)
    is the square [j - 0.5, j + 0.5] x [i - 0.5, i + 0.5] in (u, v). A full frame's principal
    point is its centre ((W - 1) / 2, (H - 1) / 2).
    Lengths are in object sizes: the mesh is normalised to unit scale (see ``mesh.py``).

A crop is rendered by changing the intrinsics, never by moving the object, so poses fitted in
different crops of one clip live in one 3D frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of a pinhole camera and the size of the image it renders.

    Attributes:
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels (pixel centres at integers).
        width, height: image size in pixels.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @staticmethod
    def from_fov(width: int, height: int, fov_y_deg: float) -> PinholeCamera:
        """A camera of vertical field of view ``fov_y_deg`` with square pixels, centred."""
        f = 0.5 * height / math.tan(math.radians(fov_y_deg) / 2)
        return PinholeCamera(f, f, (width - 1) / 2, (height - 1) / 2, width, height)

    def crop(self, x0: float, y0: float, w: float, h: float, out_w: int, out_h: int) -> PinholeCamera:
        """The camera that renders the box (x0, y0, w, h) of this image at (out_w, out_h).

        The box's top-left pixel is (x0, y0) and it spans w x h pixels; pixel edges, not centres,
        are mapped onto each other, so ``crop(0, 0, W, H, W, H)`` is the identity.
        """
        sx, sy = out_w / w, out_h / h
        return PinholeCamera(
            self.fx * sx,
            self.fy * sy,
            (self.cx - x0 + 0.5) * sx - 0.5,
            (self.cy - y0 + 0.5) * sy - 0.5,
            out_w,
            out_h,
        )

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Project camera-space points.

        Args:
            points: (*, 3) points in camera coordinates with z > 0.

        Returns:
            uv: (*, 2) pixel coordinates; depth: (*,) the z coordinate.
        """
        z = points[..., 2]
        u = self.fx * points[..., 0] / z + self.cx
        v = self.fy * points[..., 1] / z + self.cy
        return torch.stack((u, v), dim=-1), z

    def unproject(self, uv: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`project`: (*, 2) pixels at (*,) depths -> (*, 3) camera points."""
        x = (uv[..., 0] - self.cx) / self.fx * depth
        y = (uv[..., 1] - self.cy) / self.fy * depth
        return torch.stack((x, y, depth), dim=-1)
