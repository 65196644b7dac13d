"""The camera's motion: each frame registered to a reference frame, so that a handheld clip
holds still for the background, the detection and the fit.

A hand shakes, a camera follows the play; the running-median background and the one pinhole
camera of a clip both assume it does not move. Each frame is registered to its reference (the
first frame, at first) by a similarity (shift, turn, zoom) from matched ORB features with
RANSAC, which sets aside the fast mover and any other mover as outliers, then refined to a few
hundredths of a pixel by ECC over the pixels that similarity already explains. A frame that matches
its reference poorly is registered to the frame before and the two transforms chained; one that
has moved so far that it overlaps its reference less than ``camera.min_overlap`` becomes the
reference of a new *segment* (a pan longer than the frame). A frame that matches neither (no
texture, a cut, a flash) is not registered, and the pipeline does not fit it.

The registered frames are drawn on a *canvas*: the reference's view grown by how far the clip's
frames reach past it (a few pixels for a shake; for a pan up to ``camera.max_margin`` of the
frame's side), so that an object a frame sees beyond its reference's view is still there to be
found and fitted. The clip's one pinhole camera is the reference's, its principal point moved
by the canvas's margin (:meth:`Canvas.camera`).

Only the transforms are kept (3 x 3 each), so memory does not grow with the clip. On a still
camera every transform is within ``camera.still_px`` of the identity and, with
``camera.motion: auto``, no frame is warped at all: a still clip's output is unchanged.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from sfb_video.atomic import write_json
from sfb_video.config import CameraConfig
from sfb_video.errors import SfbError
from sfb_video.geometry.camera import PinholeCamera

WORK_SIDE = 640
"""Features are found on the frame scaled to at most this long a side: a 4K frame's features
are no better for a similarity, and ten times slower."""


@dataclass(frozen=True)
class Registration:
    """One frame's place in its reference's coordinates.

    Attributes:
        index: the frame's index in the clip.
        to_reference: (3, 3) the homography taking the frame's pixels (x, y, 1) to its
            reference's, or None where registration failed.
        segment: the reference it is registered to (0, 1, ... as the references are taken).
        note: why registration failed, or how it was made (``chained``), else empty.
        to_previous: (3, 3) for a reference the camera panned on to, its pixels to the
            previous reference's (None for any other frame, and after a cut).
    """

    index: int
    to_reference: np.ndarray | None
    segment: int = 0
    note: str = ""
    to_previous: np.ndarray | None = None


@dataclass(frozen=True)
class Canvas:
    """The image registered frames are drawn on: a reference's view with a margin around it.

    Attributes:
        left, top: where the reference's pixel (0, 0) lies on the canvas.
        width, height: the canvas's size in pixels.
    """

    left: int
    top: int
    width: int
    height: int

    @property
    def shift(self) -> np.ndarray:
        """(3, 3) reference pixels -> canvas pixels."""
        return np.array([[1.0, 0.0, self.left], [0.0, 1.0, self.top], [0.0, 0.0, 1.0]])

    def camera(self, camera: PinholeCamera) -> PinholeCamera:
        """The reference's ``camera`` rendering the whole canvas."""
        return PinholeCamera(camera.fx, camera.fy, camera.cx + self.left, camera.cy + self.top, self.width, self.height)


@dataclass
class CameraMotion:
    """Every frame's registration, and whether the camera moved at all.

    Attributes:
        frames: index -> :class:`Registration`.
        moving: whether any frame's transform moves a corner by more than ``still_px``; a still
            clip's frames are used as they are.
        canvas: what the registered frames are drawn on (None: the frames' own size).
    """

    frames: dict[int, Registration] = field(default_factory=dict)
    moving: bool = False
    canvas: Canvas | None = None
    _pans: dict[int, np.ndarray] | None = field(default=None, init=False, repr=False, compare=False)

    def of(self, index: int) -> Registration | None:
        return self.frames.get(index)

    def to_canvas(self, registration: Registration) -> np.ndarray | None:
        """(3, 3) a registered frame's pixels -> the canvas's, or None where it failed."""
        if registration.to_reference is None or self.canvas is None:
            return registration.to_reference
        return self.canvas.shift @ registration.to_reference

    def to_next_canvas(self, registration: Registration) -> np.ndarray | None:
        """(3, 3) a registered frame's pixels -> the next reference's canvas, where the camera
        panned on to a next reference; else None (the last reference, a cut, a failed frame)."""
        following = self._panned_to().get(registration.segment + 1)
        if registration.to_reference is None or following is None:
            return None
        to_next = np.linalg.inv(following) @ registration.to_reference
        return to_next if self.canvas is None else self.canvas.shift @ to_next

    def _panned_to(self) -> dict[int, np.ndarray]:
        """segment -> its reference's pixels to the previous reference's, for the references
        the camera panned on to (built once: a long clip asks for every frame)."""
        if self._pans is None:
            self._pans = {r.segment: r.to_previous for r in self.frames.values() if r.to_previous is not None}
        return self._pans

    @property
    def references(self) -> int:
        """How many reference frames the clip took (more than one: a pan past the first view)."""
        return len({r.segment for r in self.frames.values()})

    @property
    def failed(self) -> dict[int, str]:
        """The frames that could not be registered, with the reason."""
        return {i: r.note for i, r in self.frames.items() if r.to_reference is None}

    def save(self, path: Path) -> None:
        rows = [
            {
                "index": r.index,
                "to_reference": None if r.to_reference is None else r.to_reference.tolist(),
                "segment": r.segment,
                "note": r.note,
                "to_previous": None if r.to_previous is None else r.to_previous.tolist(),
            }
            for r in self.frames.values()
        ]
        canvas = None if self.canvas is None else dataclasses.astuple(self.canvas)
        write_json(path, {"moving": self.moving, "canvas": canvas, "frames": rows})

    @classmethod
    def load(cls, path: Path) -> CameraMotion:
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise SfbError(f"cannot read the camera's motion in {path}: {exc}") from None
        frames = {
            r["index"]: Registration(
                r["index"],
                None if r["to_reference"] is None else np.array(r["to_reference"]),
                r["segment"],
                r["note"],
                None if r.get("to_previous") is None else np.array(r["to_previous"]),
            )
            for r in data["frames"]
        }
        canvas = data.get("canvas")
        return cls(frames, bool(data["moving"]), None if canvas is None else Canvas(*canvas))


@dataclass(frozen=True)
class _Features:
    keypoints: np.ndarray  # (K, 2) full-frame pixels
    descriptors: np.ndarray | None  # (K, 32) uint8
    size: tuple[int, int]  # the frame's (width, height)
    gray: np.ndarray  # (h, w) float32, the frame at the working scale
    scale: float  # working pixels per frame pixel


def _gray(image: torch.Tensor) -> np.ndarray:
    """(H, W) uint8 grey of a (3, H, W) uint8 or float frame."""
    pixels = image if image.dtype == torch.uint8 else image.clamp(0, 1).mul(255).round().to(torch.uint8)
    rgb = pixels.permute(1, 2, 0).cpu().numpy()
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


def features(image: torch.Tensor, count: int) -> _Features:
    """ORB keypoints and descriptors of a (3, H, W) frame, in full-frame pixels."""
    gray = _gray(image)
    height, width = gray.shape
    scale = min(1.0, WORK_SIDE / max(height, width))
    if scale < 1.0:
        gray = cv2.resize(gray, (round(width * scale), round(height * scale)), interpolation=cv2.INTER_AREA)
    # Three pyramid levels, not eight: a camera's shake and pan hardly zoom, and keypoints from
    # coarse levels are placed to a few pixels (measured: a pan's worst corner 1.37 px -> 0.40).
    orb = cv2.ORB_create(nfeatures=count, fastThreshold=10, nlevels=3)
    keypoints, descriptors = orb.detectAndCompute(gray, None)
    # Pixel centres: the scaled image's pixel i covers the frame's (i + 0.5) / scale - 0.5.
    points = (np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2) + 0.5) / scale - 0.5
    return _Features(points, descriptors, (width, height), gray.astype(np.float32), scale)


def _working(scale: float) -> np.ndarray:
    """(3, 3) frame pixels -> working pixels (pixel centres kept: (p + 0.5) scale - 0.5)."""
    shift = 0.5 * scale - 0.5
    return np.array([[scale, 0.0, shift], [0.0, scale, shift], [0.0, 0.0, 1.0]])


def refine(frame: _Features, reference: _Features, to_reference: np.ndarray) -> np.ndarray:
    """``to_reference`` refined by ECC on the grey images, as a turn and a shift: features place
    a frame to a few tenths of a pixel, and a fence's thin wires then differ from the background
    along every edge; ECC brings it to a few hundredths. Not an affine: its two more degrees of
    freedom followed a swinging arm by a pixel on a still webcam clip. Kept only where it
    converges within 2 px of the start (a mover or a flash can pull it away)."""
    work = _working(frame.scale)
    start = np.linalg.inv(work @ to_reference @ np.linalg.inv(work))[:2].astype(np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 1e-5)
    # Only what the features' transform already explains: the movers (an arm, a player, the
    # object itself) are left out, or they pull the camera with them.
    height, width = frame.gray.shape
    predicted = cv2.warpAffine(reference.gray, start, (width, height), flags=cv2.INTER_LINEAR, borderValue=-1.0)
    agrees = (np.abs(frame.gray - predicted) < 20) & (predicted >= 0)
    mask = cv2.erode(agrees.astype(np.uint8), np.ones((7, 7), np.uint8))
    try:
        _, warp_ = cv2.findTransformECC(
            reference.gray, frame.gray, start.copy(), cv2.MOTION_EUCLIDEAN, criteria, mask, 3
        )
    except cv2.error:  # did not converge
        return to_reference
    refined = np.linalg.inv(work) @ np.linalg.inv(np.vstack([warp_, [0.0, 0.0, 1.0]]).astype(np.float64)) @ work
    return refined if corner_shift(refined @ np.linalg.inv(to_reference), frame.size) < 2.0 else to_reference


def match(frame: _Features, reference: _Features, min_inliers: int) -> tuple[np.ndarray | None, str]:
    """The similarity (3, 3) taking ``frame``'s pixels to ``reference``'s, or None and why not.

    Lowe's ratio test keeps the distinctive matches; RANSAC (seeded: the same clip gives the
    same transforms) keeps those one similarity explains, which sets the movers aside.
    """
    if frame.descriptors is None or reference.descriptors is None or len(frame.keypoints) < min_inliers:
        return None, f"too few features ({len(frame.keypoints)}) to register the camera"
    pairs = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(frame.descriptors, reference.descriptors, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.8 * p[1].distance]
    if len(good) < min_inliers:
        return None, f"only {len(good)} features matched its reference"
    src = frame.keypoints[[m.queryIdx for m in good]]
    dst = reference.keypoints[[m.trainIdx for m in good]]
    cv2.setRNGSeed(0)
    affine, inliers = cv2.estimateAffinePartial2D(
        src, dst, method=cv2.RANSAC, ransacReprojThreshold=2.0, maxIters=4000, confidence=0.999
    )
    kept = 0 if inliers is None else int(inliers.sum())
    if affine is None or kept < min_inliers:
        return None, f"only {kept} matched features agree on one camera motion"
    zoom = float(np.sqrt(abs(np.linalg.det(affine[:, :2]))))
    if not 0.8 < zoom < 1.25:
        return None, f"an implausible zoom of {zoom:.2f} between frames"
    return np.vstack([affine, [0.0, 0.0, 1.0]]), ""


def overlap(to_reference: np.ndarray, size: tuple[int, int]) -> float:
    """The share of the reference frame (``size`` = (width, height)) that the frame covers."""
    width, height = size
    corners = np.array([[0, 0], [width, 0], [width, height], [0, height]], dtype=np.float32)
    warped = cv2.perspectiveTransform(corners[None], to_reference)[0]
    area, _ = cv2.intersectConvexConvex(corners, warped.astype(np.float32))
    return float(area) / (width * height)


def corner_shift(to_reference: np.ndarray, size: tuple[int, int]) -> float:
    """How far (pixels) the transform moves the frame's farthest corner."""
    width, height = size
    corners = np.array([[[0, 0], [width - 1, 0], [width - 1, height - 1], [0, height - 1]]], dtype=np.float64)
    return float(np.abs(cv2.perspectiveTransform(corners, to_reference) - corners).max())


def register_frames(frames: Iterable[tuple[int, torch.Tensor]], config: CameraConfig) -> CameraMotion:
    """Register every (index, (3, H, W) image) of a clip, in order (see the module docstring).

    Holds two frames' features, not the frames.
    """
    motion = CameraMotion()
    reference: _Features | None = None
    previous: tuple[_Features, np.ndarray] | None = None  # the last registered frame, and its transform
    segment, failures = -1, 0
    for index, image in frames:
        found = features(image, config.features)
        textured = len(found.keypoints) >= config.min_inliers
        anchor = None  # why this frame becomes a reference, when it does
        to_previous = None
        if reference is None or (textured and len(reference.keypoints) < config.min_inliers):
            # The first frame, or one with texture after a reference without (a fade from black).
            anchor = ""
        else:
            to_reference, note = match(found, reference, config.min_inliers)
            if to_reference is None and previous is not None:
                step, _ = match(found, previous[0], config.min_inliers)
                if step is not None:
                    to_reference, note = previous[1] @ step, "chained"
            if to_reference is not None:
                to_reference = refine(found, reference, to_reference)
                if overlap(to_reference, found.size) < config.min_overlap:
                    anchor, to_previous = "new reference", to_reference  # the camera has moved on
            elif textured and failures >= 1:
                # Two textured frames in a row that match nothing before them: a cut to a new view.
                anchor = "new reference after a cut"
            else:
                failures += 1
                motion.frames[index] = Registration(index, None, segment, f"camera registration failed: {note}")
                continue
        if anchor is not None:
            reference, segment, to_reference, note = found, segment + 1, np.eye(3), anchor
        failures = 0
        motion.frames[index] = Registration(index, to_reference, segment, note, to_previous)
        previous = (found, to_reference)
    alone = Counter(r.segment for r in motion.frames.values() if r.to_reference is not None)
    for index, r in motion.frames.items():
        if r.to_reference is not None and alone[r.segment] == 1 and len(alone) > 1:
            # A reference with no other frame has nothing to make its background from.
            note = "camera registration failed: the camera moved on before a second frame saw this view"
            motion.frames[index] = Registration(index, None, r.segment, note)
    size = None if reference is None else reference.size
    motion.moving = any(
        r.segment > 0 or corner_shift(r.to_reference, size) > config.still_px
        for r in motion.frames.values()
        if r.to_reference is not None and size is not None
    )
    if size is not None:
        motion.canvas = canvas_of(motion, size, config.max_margin)
    return motion


def canvas_of(motion: CameraMotion, size: tuple[int, int], max_margin: float) -> Canvas:
    """The canvas that holds every registered frame of ``motion`` drawn in its reference's
    coordinates (frames of ``size`` = (width, height)), its margins at most ``max_margin`` of
    the frame's side: a transform gone wild does not make a huge canvas."""
    width, height = size
    corners = np.array([[[0, 0], [width - 1, 0], [width - 1, height - 1], [0, height - 1]]], dtype=np.float64)
    reach = np.zeros(4)  # how far past the reference's left, top, right and bottom pixel centres
    for r in motion.frames.values():
        if r.to_reference is not None:
            moved = cv2.perspectiveTransform(corners, r.to_reference)[0]
            low, high = moved.min(0), moved.max(0) - (width - 1, height - 1)
            reach = np.maximum(reach, [-low[0], -low[1], high[0], high[1]])
    # A pixel centre within half a pixel of the border is the border's (warp repeats it).
    sides = (width, height, width, height)
    left, top, right, bottom = (
        min(max(0, math.ceil(float(r) - 0.5)), math.floor(max_margin * side))
        for r, side in zip(reach, sides, strict=True)
    )
    return Canvas(left, top, width + left + right, height + top + bottom)


def warp(
    image: torch.Tensor, to_canvas: np.ndarray, size: tuple[int, int] | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """A (3, H, W) frame (uint8 or float) drawn on its reference's canvas of ``size`` (width,
    height; the frame's own when None), and the (h, w) bool pixels it covers there (the rest
    repeat its border)."""
    width, height = size if size is not None else (image.shape[2], image.shape[1])
    pixels = np.ascontiguousarray(image.permute(1, 2, 0).cpu().numpy())
    # Lanczos, not bilinear: bilinear's blur differs with each frame's sub-pixel offset, and a
    # fence's wires then differ from their median (a shaken fence's recall 0.25 -> 0.75).
    flags = cv2.INTER_LANCZOS4
    out = cv2.warpPerspective(pixels, to_canvas, (width, height), flags=flags, borderMode=cv2.BORDER_REPLICATE)
    if out.dtype != np.uint8:  # Lanczos rings past [0, 1]; uint8 saturates by itself
        out = np.clip(out, 0.0, 1.0)
    covered = cv2.warpPerspective(
        np.ones(image.shape[1:], np.uint8), to_canvas, (width, height), flags=cv2.INTER_NEAREST
    )
    return torch.from_numpy(out).permute(2, 0, 1).contiguous(), torch.from_numpy(covered > 0)


def unwarp(image: torch.Tensor, to_canvas: np.ndarray, size: tuple[int, int] | None = None) -> torch.Tensor:
    """A (3, h, w) or (h, w) image on the canvas brought back into the frame's own pixels, of
    ``size`` (width, height; the canvas's when None); a plane (weights) is 0 where the canvas
    does not reach, an image repeats its border."""
    planar = image.ndim == 2
    width, height = size if size is not None else (image.shape[-1], image.shape[-2])
    pixels = np.ascontiguousarray((image if planar else image.permute(1, 2, 0)).cpu().numpy())
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    border = cv2.BORDER_CONSTANT if planar else cv2.BORDER_REPLICATE
    out = cv2.warpPerspective(pixels, to_canvas, (width, height), flags=flags, borderMode=border)
    back = torch.from_numpy(np.ascontiguousarray(out))
    return back if planar else back.permute(2, 0, 1).contiguous()


def to_frame(points: torch.Tensor, to_canvas: np.ndarray) -> torch.Tensor:
    """(N, 2) pixel positions on the canvas, in the frame's own."""
    back = cv2.perspectiveTransform(points.detach().cpu().double().numpy()[None], np.linalg.inv(to_canvas))[0]
    return torch.from_numpy(back).to(points)
