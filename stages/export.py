"""Stage 5, export: saved frame results -> tsr.mp4, trajectory.csv, meshes/, recording.rrd.

Everything here is rendered from the results saved in the run folder and the clip itself, so
``sfb-video export`` can redo it at another TSR factor without fitting again. The clip is
streamed once and each result loaded only for its frame. Where a joint fit covers a frame
(:mod:`sfb_video.stages.windows`), the frame's object is the window's (its shared mesh and texture, its
pose on the window's trajectory), and the trajectory between exposures is exported too. Every
file is written atomically.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from sfb_video.config import CameraConfig, Config, DetectConfig, RenderConfig
from sfb_video.crop import Box
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.imageio import as_float
from sfb_video.mesh_files import motion_record, write_glb, write_obj
from sfb_video.model.scene import ObjectState
from sfb_video.recording import Recorder
from sfb_video.registration import unwarp
from sfb_video.results import FrameKey, FrameResult
from sfb_video.run_folder import (
    BEST_MESH,
    MESHES,
    TSR_VIDEO,
    ensure_folder,
    mesh_path,
    track_mesh_path,
)
from sfb_video.stages.composite import BLUR_POSES, explained, fitted_region, region_box
from sfb_video.stages.detect import difference_image, threshold_difference
from sfb_video.stages.run_results import RunResults
from sfb_video.stages.trajectory import gap_rows, to_frame_pixels, trajectory_rows
from sfb_video.stages.types import FrameWithBackground, Registered
from sfb_video.video import OUTPUT_PRESET, VideoWriter


class Upscaled(Sequence[torch.Tensor]):
    """Sub-frames of a box rendered smaller than the box, each brought to the box's size when
    asked for: the box's own background plus the rendering's change from its background, scaled
    up (so the background keeps its pixels). At 4K an object's box is 1640x1230 px: its 8
    sub-frames at that size were 190 MB in float.

    Args:
        background: (3, h, w), or (N, 3, h, w) one per sub-frame: the box's background.
        changes: (N, 3, h', w') the rendered sub-frames minus the background they were rendered
            over, at the render size.
    """

    def __init__(self, background: torch.Tensor, changes: torch.Tensor) -> None:
        self.background, self.changes = background, changes
        self.size = (background.shape[-1], background.shape[-2])

    def __len__(self) -> int:
        return self.changes.shape[0]

    def __getitem__(self, k: int) -> torch.Tensor:  # type: ignore[override]
        """(3, h, w) float32 sub-frame ``k``."""
        background = self.background if self.background.dim() == 3 else self.background[k]
        return background + _resize(self.changes[k], self.size)

    def mean(self, dim: int = 0) -> torch.Tensor:
        """(3, h, w) the sub-frames' mean (a tensor's signature, so that either can be averaged):
        the resize is linear, so it is the mean change scaled up."""
        if dim != 0:
            raise ValueError("sub-frames average over dim 0 only")
        background = self.background if self.background.dim() == 3 else self.background.mean(0)
        return background + _resize(self.changes.mean(0), self.size)


Patches = torch.Tensor | Upscaled
"""(N, 3, h, w) float32 sub-frames of a box in [0, 1]: rendered at the box's size, or
:class:`Upscaled` to it one at a time."""


@dataclass(frozen=True)
class Layer:
    """One object's sub-frames in its region of a frame.

    Attributes:
        patches: (N, 3, h, w) float32 in [0, 1], what replaces the box in each sub-frame;
            quantised to the frame's dtype where pasted.
        box: (x, y, w, h) where.
        weights: (h, w) in [0, 1], how much of each patch pixel replaces the frame's
            (:func:`sfb_video.stages.composite.object_region`).
    """

    patches: Patches
    box: Box
    weights: torch.Tensor


class Pasted(Sequence[torch.Tensor]):
    """Full frames, each the input frame with its objects' patches blended in, farthest first;
    made one at a time when asked for, so that N sub-frames of a large frame are never all in
    memory.

    Args:
        frame: (3, H, W) the input frame, uint8 or float32 in [0, 1]; the frames come out in
            its dtype.
        layers: the objects' :class:`Layer`, farthest first (each of N sub-frames).
    """

    def __init__(self, frame: torch.Tensor, layers: list[Layer]) -> None:
        self.frame, self.layers = frame, layers

    def __len__(self) -> int:
        return len(self.layers[0].patches)

    def __getitem__(self, k: int) -> torch.Tensor:  # type: ignore[override]
        if not -len(self) <= k < len(self):
            raise IndexError(k)
        full = self.frame.clone()
        for part in self.layers:
            x, y, w, h = part.box
            patch = part.patches[k]
            if full.dtype == torch.uint8:
                # Quantised as the frame is stored before the blend, so a fully covered pixel is
                # the patch's own 8-bit value.
                patch = patch.mul(255).clamp_(0, 255).round_()
            under = full[:, y : y + h, x : x + w].float()
            # under + weights * (patch - under), with one temporary of the box's size.
            blended = (patch - under).mul_(part.weights).add_(under)
            full[:, y : y + h, x : x + w] = blended.round_() if full.dtype == torch.uint8 else blended
        return full

    def weights(self) -> torch.Tensor:
        """(H, W) float32: how much of each frame pixel the objects replace."""
        out = torch.zeros(self.frame.shape[1:], dtype=torch.float32)
        for part in self.layers:
            x, y, w, h = part.box
            out[y : y + h, x : x + w] = torch.maximum(out[y : y + h, x : x + w], part.weights.cpu().float())
        return out


class Unwarped(Sequence[torch.Tensor]):
    """A registered frame's rendered sub-frames (full frames on its reference's canvas) brought
    back into the frame as filmed: the objects' regions of each are warped back and blended
    into the original frame, so the rest keeps the frame's own pixels.

    Args:
        subframes: the sub-frames on the reference's canvas.
        registered: the frame's registration.
    """

    def __init__(self, subframes: Pasted, registered: Registered) -> None:
        assert registered.to_canvas is not None
        self.subframes, self.registered = subframes, registered
        height, width = registered.original.shape[1:]
        self.size = (width, height)
        self.weights = unwarp(subframes.weights(), registered.to_canvas, self.size)

    def __len__(self) -> int:
        return len(self.subframes)

    def __getitem__(self, k: int) -> torch.Tensor:  # type: ignore[override]
        original = self.registered.original
        back = unwarp(self.subframes[k], self.registered.to_canvas, self.size).float()
        blended = original.float() + self.weights * (back - original.float())
        return blended.round_().to(torch.uint8) if original.dtype == torch.uint8 else blended


def mapped_back(frame: FrameWithBackground, camera: CameraConfig) -> bool:
    """Whether the outputs show ``frame`` as filmed, mapped back from its reference's pixels
    (a registered frame, unless ``camera.stabilised``)."""
    return not (frame.registered is None or frame.registered.failed or camera.stabilised)


def as_filmed(frame: FrameWithBackground, subframes: Pasted, camera: CameraConfig) -> Sequence[torch.Tensor]:
    """The sub-frames ``tsr.mp4`` shows: in the frame as filmed, or for a still camera (or
    ``camera.stabilised``) as rendered."""
    if not mapped_back(frame, camera):
        return subframes
    assert frame.registered is not None
    return Unwarped(subframes, frame.registered)


def unfitted(frame: FrameWithBackground, camera: CameraConfig) -> torch.Tensor:
    """What ``tsr.mp4`` shows of a frame without a fit: the frame as filmed, or stabilised (a
    frame that did not register shows its reference's background there)."""
    if frame.registered is None or camera.stabilised:
        return frame.pixels
    return frame.registered.original


@dataclass(frozen=True)
class Rendered:
    """One object of a frame rendered from its result, full-frame.

    Attributes:
        blurred: the blurred model over the background in the object's region (I_hat's layer).
        subframes: N full frames (3, H, W), the sharp sub-frames, made one at a time, in the
            dtype the frame is kept in (uint8 or float32, :func:`as_float`).
        explained: how much of the frame's difference from its background the fit explains
            over the object's region (:func:`sfb_video.stages.composite.explained`).
    """

    blurred: Layer
    subframes: Pasted
    explained: float

    @property
    def reconstruction(self) -> torch.Tensor:
        """(3, H, W) I_hat: the frame with the blurred model in the object's region."""
        return Pasted(self.subframes.frame, [self.blurred])[0]


def _resize(images: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """(..., 3, h, w) images resized to ``size`` (width, height), bilinear with antialiasing."""
    if images.shape[-2:] == (size[1], size[0]):
        return images
    batch = images.reshape(-1, *images.shape[-3:])
    out = F.interpolate(batch, size=(size[1], size[0]), mode="bilinear", antialias=True, align_corners=False)
    return out.reshape(*images.shape[:-2], size[1], size[0])


def streak_box(result: FrameResult, camera: PinholeCamera) -> Box:
    """The fit's crop box grown to hold the object's whole path during the exposure (a joint
    fit's trajectory may run past a detection that saw only part of the streak), within the
    frame."""
    motion = result.state.motion
    _, positions = motion.at(torch.linspace(0, 1, 9))
    uv, depth = camera.project(positions)
    reach = camera.fy * float(result.state.vertices.norm(dim=-1).max()) / depth + 2
    x, y, w, h = result.crop_box
    x0 = max(0, min(x, math.floor(float((uv[:, 0] - reach).min()))))
    y0 = max(0, min(y, math.floor(float((uv[:, 1] - reach).min()))))
    x1 = min(camera.width, max(x + w, math.ceil(float((uv[:, 0] + reach).max())) + 1))
    y1 = min(camera.height, max(y + h, math.ceil(float((uv[:, 1] + reach).max())) + 1))
    return x0, y0, x1 - x0, y1 - y0


def _export_size(box: Box, render: RenderConfig) -> tuple[int, int]:
    """The (width, height) a region ``box`` is rendered at: at most ``render.export_max_width``."""
    _, _, w, h = box
    scale = min(1.0, render.export_max_width / w)
    return max(1, round(w * scale)), max(1, round(h * scale))


def render_patches(
    state: ObjectState, camera: PinholeCamera, box: Box, background: torch.Tensor, n: int, render: RenderConfig
) -> Patches:
    """(n, 3, h, w) float32 sharp sub-frames of ``state`` in ``box`` over ``background``
    ((3, h, w), or (n, 3, h, w): one per sub-frame, such as a farther object's sub-frames).

    A box wider than ``render.export_max_width`` is rendered at that width and its sub-frames
    are :class:`Upscaled` to the box one at a time, when asked for."""
    x, y, w, h = box
    size = _export_size(box, render)
    small_bg = _resize(background, size)
    patches = state.render_subframes(camera.crop(x, y, w, h, *size), small_bg, n, render)
    if size == (w, h):
        return patches
    return Upscaled(background, patches - small_bg)


def render_frame(
    frame: FrameWithBackground,
    result: FrameResult,
    camera: PinholeCamera,
    n: int,
    detect: DetectConfig,
    render: RenderConfig,
    difference: np.ndarray | None = None,
) -> Rendered:
    """Render ``result`` over the background in the object's region and blend it into the
    frame (:mod:`sfb_video.stages.composite`): the model's path and the parts of the frame's streak
    connected to it, so that no part of the input's streak is left as a ghost.

    Outside the region the input frame is kept (so other movers stay as they were, until
    :func:`composite` adds theirs).

    Args:
        difference: (H, W) the frame's :func:`sfb_video.stages.detect.difference_image`, if already made.
    """
    if difference is None:
        difference = difference_image(frame.pixels, frame.background_pixels)
    region = fitted_region(result.state, camera, difference, detect, frame.known)
    box = region_box(region, streak_box(result, camera))
    x, y, w, h = box
    patch_bg = as_float(frame.background_pixels[:, y : y + h, x : x + w])
    patches = render_patches(result.state, camera, box, patch_bg, n, render)
    weights = torch.from_numpy(region[y : y + h, x : x + w]).to(patch_bg.device)
    blurred = patches.mean(0)
    if n * render.steps_per_subframe < BLUR_POSES:
        # Few sub-frames average into a few sharp copies, not the frame's blur: the quality
        # signal would depend on the TSR factor.
        size = _export_size(box, render)
        small_bg = _resize(patch_bg, size)
        camera_box = camera.crop(x, y, w, h, *size)
        blurred = patch_bg + _resize(
            result.state.render_blurred(camera_box, small_bg, BLUR_POSES, render) - small_bg, (w, h)
        )
    quality = explained(as_float(frame.pixels[:, y : y + h, x : x + w]), patch_bg, blurred, weights)
    sharp = Pasted(frame.pixels, [Layer(patches, box, weights)])
    return Rendered(Layer(blurred[None], box, weights), sharp, quality)


def _depth(result: FrameResult) -> float:
    """The object's distance from the camera at mid-exposure."""
    return float(result.state.motion.at(torch.full((1,), 0.5))[1][0, 2])


def _overlaps(a: Box, b: Box) -> bool:
    return min(a[0] + a[2], b[0] + b[2]) > max(a[0], b[0]) and min(a[1] + a[3], b[1] + b[3]) > max(a[1], b[1])


def composite(
    frame: FrameWithBackground,
    objects: list[tuple[FrameResult, Rendered]],
    camera: PinholeCamera,
    n: int,
    render: RenderConfig,
) -> tuple[torch.Tensor, Pasted]:
    """Every object's rendering of one frame in one: I_hat (3, H, W) and the sub-frames, blended
    farthest first, so that where two objects' regions overlap the nearer is in front. An object
    whose region overlaps a farther one's is rendered again over that object's sub-frames (not
    over the bare background, which would cut a hole in it)."""
    if len(objects) == 1:
        return objects[0][1].reconstruction, objects[0][1].subframes
    ordered = sorted(objects, key=lambda o: -_depth(o[0]))
    reconstruction = Pasted(frame.pixels, [r.blurred for _, r in ordered])[0]
    layers: list[Layer] = []
    for result, rendered in ordered:
        own = rendered.subframes.layers[0]
        if any(_overlaps(own.box, other.box) for other in layers):
            x, y, w, h = own.box
            plate = Pasted(frame.background_pixels, layers)
            under = torch.stack([as_float(plate[k][:, y : y + h, x : x + w]) for k in range(n)])
            own = Layer(render_patches(result.state, camera, own.box, under, n, render), own.box, own.weights)
        layers.append(own)
    return reconstruction, Pasted(frame.pixels, layers)


@dataclass
class Exported:
    """What streaming the clip through the exports gathered.

    Attributes:
        video_frames: frames written to ``tsr.mp4``.
        rows: trajectory rows (:func:`trajectory_rows`) of every fitted object, with its track.
        fits: per fitted object (frame index, track), what ``summary.json`` reports of it.
        best: the fitted object with the lowest image loss, or None.
    """

    video_frames: int = 0
    rows: list[dict[str, float | int | str]] = field(default_factory=list)
    fits: dict[FrameKey, dict[str, Any]] = field(default_factory=dict)
    best: FrameKey | None = None


def _mask_order(result: FrameResult) -> str | None:
    """Whether a fit's sub-frame masks kept their own order ("as given") or were "reversed" to
    join the track (which wins over DeFMO's order: one blurred image cannot fix it); None
    without sub-frame masks."""
    if result.masks is None:
        return None
    return "reversed" if result.masks_reversed else "as given"


def _fit_record(result: FrameResult, speed: float, diameter: float | None) -> dict[str, Any]:
    record: dict[str, Any] = {
        "start": result.start,
        "prototype": result.prototype,
        "losses": result.losses,
        "iterations": len(result.curve),
        "seconds": result.seconds,
        "masks": result.mask_source,
        "speed_sizes_per_s": speed,
        "motion": motion_record(result.state.motion),
    }
    order = _mask_order(result)
    if order is not None:
        record["masks_order"] = order
    if diameter is not None:
        record["speed_km_per_h"] = speed * diameter * 3.6
    return record


@dataclass(frozen=True)
class ObjectRecord:
    """One fitted object of a frame as the exports show it: its fit (a window's joint fit where
    one stands for it), its rendering, its trajectory rows (with its track and reference frame,
    in the frame's own pixels) and what ``summary.json`` says of it."""

    result: FrameResult
    rendered: Rendered
    rows: tuple[dict[str, float | int | str], ...]
    summary: dict[str, Any]


@dataclass(frozen=True)
class FrameRecord:
    """One frame of the exports: the frame, its difference ``mask`` and detected ``boxes`` (by
    track), its fitted objects, the reconstruction (the fitted objects blurred over the
    background; the frame where none), its composited sub-frames and the N frames ``tsr.mp4``
    shows of it (``filmed``)."""

    frame: FrameWithBackground
    mask: torch.Tensor
    boxes: dict[int, Box]
    objects: tuple[ObjectRecord, ...]
    reconstruction: torch.Tensor
    subframes: Sequence[torch.Tensor]
    filmed: Sequence[torch.Tensor]


def frame_record(
    frame: FrameWithBackground,
    results: RunResults,
    camera: PinholeCamera,
    fps: float,
    n: int,
    config: Config,
    diameter: float | None,
) -> FrameRecord:
    """The :class:`FrameRecord` of one frame of the clip, each object's saved fit (and its
    window's) loaded only while it is made, so memory does not grow with the clip."""
    difference = difference_image(frame.pixels, frame.background_pixels)
    mask = threshold_difference(difference, config.detect, frame.known)
    present = results.saved(frame.index)
    boxes = {s.track: s.box for s, _ in present if s.box is not None}
    if not present:
        return FrameRecord(frame, mask, boxes, (), frame.pixels, [frame.pixels], [unfitted(frame, config.camera)] * n)
    objects = tuple(
        _object_record(frame, single, results, difference, camera, fps, n, config, diameter) for _, single in present
    )
    del difference  # 33 MB a 4K frame, not needed while the objects are composited
    reconstruction, subframes = composite(frame, [(o.result, o.rendered) for o in objects], camera, n, config.render)
    return FrameRecord(
        frame, mask, boxes, objects, reconstruction, subframes, as_filmed(frame, subframes, config.camera)
    )


def _object_record(
    frame: FrameWithBackground,
    single: FrameResult,
    results: RunResults,
    difference: np.ndarray,
    camera: PinholeCamera,
    fps: float,
    n: int,
    config: Config,
    diameter: float | None,
) -> ObjectRecord:
    result, window = results.showing(single.key, single)
    rendered = render_frame(frame, result, camera, n, config.detect, config.render, difference)
    rows = list(trajectory_rows(result, camera, n, fps, config.video.exposure_fraction, diameter))
    record = _fit_record(result, float(rows[0]["speed_sizes_per_s"]), diameter)
    record["explained"] = rendered.explained
    record["object_box"] = result.state.image_box(camera)
    if window is not None:
        record.update(window=window.frames[0], losses_before=single.losses, prototype_before=single.prototype)
        # The gap to the next frame is drawn where the next frame is shown from a window too,
        # not from its single-frame fit (its window rejected).
        later = FrameKey(frame.index + 1, result.track)
        if frame.index + 1 in window.result.losses and results.shown_window(later) is not None:
            rows += gap_rows(window.result.trajectory, frame.index, camera, n, fps, diameter)
    if mapped_back(frame, config.camera):
        assert frame.registered is not None and frame.registered.to_canvas is not None
        to_frame_pixels(rows, frame.registered.to_canvas)
    reference = 0 if frame.registered is None else frame.registered.segment
    rows = [{"track": result.track, "reference": reference, **r} for r in rows]
    return ObjectRecord(result, rendered, tuple(rows), record)


def export_frames(
    folder: Path,
    frames: Iterator[FrameWithBackground],
    results: RunResults,
    camera: PinholeCamera,
    size: tuple[int, int],
    fps: float,
    n: int,
    config: Config,
    diameter: float | None,
    recorder: Recorder,
) -> Exported:
    """Stream the clip once (:func:`frame_record`) and write ``tsr.mp4`` (of ``size`` (width,
    height); N sub-frames per fitted frame, every object of the frame in them; the frame N times
    otherwise), ``meshes/frame_XXXXX_track_YY.glb`` and one ``meshes/track_YY.glb`` per track (its
    lowest-L_I frame's mesh), and log every frame to ``recorder``."""
    done = Exported()
    trajectory: dict[int, list[np.ndarray]] = {}
    tracks: dict[int, tuple[float, ObjectState]] = {}
    ensure_folder(folder / MESHES)
    with VideoWriter(folder / TSR_VIDEO, fps * n, *size, preset=OUTPUT_PRESET) as video:
        for frame in frames:
            record = frame_record(frame, results, camera, fps, n, config, diameter)
            _log_frame(recorder, record)
            for obj in record.objects:
                result = obj.result
                write_glb(result.state, mesh_path(folder, record.frame.index, result.track))
                points = trajectory.setdefault(result.track, [])
                points.append(np.array([[r["x"], r["y"], r["z"]] for r in obj.rows], dtype=np.float32))
                recorder.log_trajectory(np.concatenate(points), result.track)
                done.rows += obj.rows
                done.fits[result.key] = obj.summary
                loss = result.losses["image"]
                if done.best is None or loss < done.fits[done.best]["losses"]["image"]:
                    done.best = result.key
                if loss < tracks.get(result.track, (math.inf,))[0]:
                    tracks[result.track] = (loss, result.state)
            for sub in record.filmed:
                video.write(sub)
            recorder.log_subframes(record.frame.index, record.reconstruction, record.subframes)
            del record, frame  # its renderings, before the next frame's are made
        done.video_frames = video.frames_written
    for track, (_, state) in tracks.items():
        write_glb(state, track_mesh_path(folder, track))
    if done.best is not None:
        best = results.shown(done.best)
        write_obj(best.state, ensure_folder(folder / BEST_MESH), name="mesh")
    return done


def _log_frame(recorder: Recorder, record: FrameRecord) -> None:
    """The frame, its detections and each fitted object's fit, quality and masks, to ``recorder``."""
    index = record.frame.index
    recorder.log_frame(index, record.frame.pixels, record.frame.background_pixels)
    recorder.log_detection(index, record.boxes, record.mask)
    for obj in record.objects:
        result = obj.result
        recorder.log_fit(index, result.track, result.state, result.losses, result.curve)
        recorder.log_quality(index, result.track, obj.rendered.explained)
        order = _mask_order(result)
        source = result.mask_source if order is None else f"{result.mask_source}, order {order}"
        recorder.log_masks(index, source, result.crop_box, result.masks, result.track)
