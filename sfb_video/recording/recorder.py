"""The recorder: everything a run logs, on rerun's timelines, into ``recording.rrd``
(the entity layout is :mod:`sfb_video.recording`'s)."""

from __future__ import annotations

import contextlib
import json
import math
import os
import uuid
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import rerun as rr
import torch
import yaml

from sfb_video.atomic import AtomicOutput, output_error, temporary_sibling
from sfb_video.errors import OutputError, SfbError, check_shape
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.imageio import to_uint8
from sfb_video.mesh_files import to_trimesh
from sfb_video.model.formation import exposure_times
from sfb_video.model.scene import ObjectState
from sfb_video.recording.layout import APPLICATION_ID, FRAME, STEP, SUBFRAME, layout, shape_text, spans, track_entity
from sfb_video.recording.pipe import Pipe
from sfb_video.recording.video_stream import VideoEncoder
from sfb_video.timing import timed

# The footer is an index of every chunk, written on close: it keeps LazyStore and random access
# working, at the cost of a few KB of memory per chunk until then (about 30 KB per frame
# measured). Everything else streams to disk; False makes memory flat but rerun then warns on
# stderr and readers treat the file as the legacy format.
WRITE_FOOTER = True
# rerun's writer only waits on our copy thread (:class:`~sfb_video.recording.pipe.Pipe`), which
# never stops reading; the limit is for a disk that stops answering (a healthy one takes a frame in milliseconds).
FLUSH_TIMEOUT_S = 120.0
MAX_VIEW = (1920, 1080)
"""The largest images the recording holds, (width, height): a larger clip is recorded at 1/f of
its size, f the smallest whole number that fits it (a 4K clip at 1920x1080). An AV1 encoder of
a 4K stream holds about 200 MB, and the recording has five streams."""
MASK_CLASS = 1
SUBFRAME_MASK_CLASS = 2
# In object sizes (the unit of the 3D scene), so they scale with the object.
TRAJECTORY_LINE_RADIUS = 0.02
TRAJECTORY_POINT_RADIUS = 0.05

Box = tuple[int, int, int, int]


class Recorder(AtomicOutput):
    """Writes the rerun recording of one clip; see the module docstring for what goes where.

    Use it as a context manager: it closes (renames the file into place) on success and aborts
    (removes the temporary file) on an exception. Each recorder has its own
    ``rr.RecordingStream``, never the global one, so several can be open in one process.

    Args:
        path: the final ``.rrd`` path, in a folder that exists.
        camera: the full-frame camera every image passed in must match.
        name: the clip's name, shown as the recording's name in the viewer.
        subframes: n, the TSR sub-frames of each frame (the subframe timeline's step).
        recording_id: rerun's recording id; by default derived from ``name``, so re-runs of one
            clip share it (the viewer merges recordings with the same id).
        max_view: :data:`MAX_VIEW`. Images, boxes, masks and the pinhole are taken at the
            camera's size and recorded at the reduced one, all alike; the 3D scene is unchanged.

    Raises:
        SfbError: if the temporary file cannot be created.
    """

    @timed("recording")
    def __init__(
        self,
        path: str | Path,
        camera: PinholeCamera,
        name: str,
        *,
        subframes: int,
        recording_id: str | None = None,
        max_view: tuple[int, int] = MAX_VIEW,
    ) -> None:
        if subframes < 1:
            raise SfbError(f"subframes must be at least 1, got {subframes}")
        self.path = Path(path)
        self.camera = camera
        if min(max_view) < 1:
            raise SfbError(f"max_view must be at least 1x1, got {max_view}")
        self.shrink = max(1, math.ceil(max(camera.width / max_view[0], camera.height / max_view[1])))
        """f: the recording's images are about 1/f of the camera's size."""
        self.view_size = (max(1, round(camera.width / self.shrink)), max(1, round(camera.height / self.shrink)))
        # Per axis: a size that f does not divide (4096x2160, f 3) is scaled by view / size.
        self._sx, self._sy = self.view_size[0] / camera.width, self.view_size[1] / camera.height
        self.subframes = subframes
        self._frame: int | None = None
        self._masks_shown: set[int] = set()  # the tracks whose masks show
        self._sources: dict[int, dict[str, list[int]]] = {}  # track -> mask source -> frames
        self._steps: dict[int, int] = {}  # track -> the steps of its fits logged so far
        self._paths: dict[int, np.ndarray] = {}  # track -> its trajectory, as last logged
        self._videos: dict[str, VideoEncoder] = {}  # stream -> its encoder
        self._codecs: set[str] = set()  # the paths whose codec is logged
        self._tmp: Path | None = temporary_sibling(self.path, ".rrd")
        self._pipe: Pipe | None = None
        if recording_id is None:
            recording_id = str(uuid.uuid5(uuid.NAMESPACE_URL, f"{APPLICATION_ID}:{name}"))
        self._rec = rr.RecordingStream(application_id=APPLICATION_ID, recording_id=recording_id)
        # Wall-clock log times would make two runs of one clip differ in content, and would add a
        # fourth timeline the viewer might pick by default.
        self._rec.set_log_time_enabled(False)
        try:
            self._pipe = Pipe(self._tmp)
            self._rec.save(self._pipe.path, write_footer=WRITE_FOOTER)
            self._pipe.start()
        except OSError as e:
            self.abort()
            raise output_error(self.path, e) from None
        except RuntimeError as e:
            self.abort()
            raise OutputError(f"cannot write the recording {self.path}: {str(e).splitlines()[0]}") from None
        try:
            self._rec.send_recording_name(name)
            self._log_static(camera)
        except BaseException:
            self.abort()
            raise

    # ----------------------------------------------------------------------------------------------
    # Logging

    @timed("recording")
    def log_frame(self, index: int, image: torch.Tensor, background: torch.Tensor) -> None:
        """Log frame ``index``: the input ``image`` and the ``background``, both (3, H, W) in [0, 1]."""
        self._check_image(image, "image")
        self._check_image(background, "background")
        self._flush()  # what the previous frame logged: a write error surfaces here, not at the end
        self._at_frame(index)
        self._log_video("world/camera/image", image)
        self._log_video("background", background)

    @timed("recording")
    def log_detection(self, index: int, boxes: dict[int, Box], mask: torch.Tensor | None) -> None:
        """Log the detections of frame ``index``.

        Args:
            boxes: per track, its object's (x, y, w, h) in pixels; empty clears the previous
                frame's boxes.
            mask: (H, W) bool or float (> 0.5 is the object), or None (clears the previous mask).
        """
        self._at_frame(index)
        if not boxes:
            self._log("world/camera/image/detection", rr.Clear(recursive=False))
        else:
            self._log(
                "world/camera/image/detection",
                rr.Boxes2D(
                    mins=[(b[0] * self._sx, b[1] * self._sy) for b in boxes.values()],
                    sizes=[(b[2] * self._sx, b[3] * self._sy) for b in boxes.values()],
                    labels=[f"track {t}" for t in boxes],
                ),
            )
        if mask is None:
            self._log("world/camera/image/mask", rr.Clear(recursive=False))
        else:
            check_shape(mask, (self.camera.height, self.camera.width), "mask")
            ids = (mask.detach().float().cpu() > 0.5).numpy().astype(np.uint8) * MASK_CLASS
            self._log("world/camera/image/mask", rr.SegmentationImage(self._shrunk(ids), opacity=0.5))

    @timed("recording")
    def log_subframes(self, index: int, reconstruction: torch.Tensor, subframes: Sequence[torch.Tensor]) -> None:
        """Log frame ``index``'s rendering, every object's in one.

        Args:
            reconstruction: (3, H, W) full-frame I_hat in [0, 1].
            subframes: the n full-frame TSR sub-frames (3, H, W) in [0, 1] (a tensor (n, 3, H, W)
                or a sequence that makes them one at a time), at ``index * n + k`` on the
                subframe timeline, the middle one at ``index`` on the frame timeline too; or
                one, shown for the whole frame (a frame without a fit).
        """
        self._check_image(reconstruction, "reconstruction")
        if isinstance(subframes, torch.Tensor):
            check_shape(subframes, (None, 3, self.camera.height, self.camera.width), "subframes")
        n = len(subframes)
        if n not in (1, self.subframes):
            raise SfbError(f"frame {index}: {n} sub-frames, expected {self.subframes} (or 1 for the whole frame)")
        self._at_frame(index)
        self._log_video("reconstruction", reconstruction)
        for k in range(n):
            sub = subframes[k]
            self._check_image(sub, "subframe")
            self._at(subframe=index * self.subframes + k)
            self._log_video("tsr", sub)
            if k == n // 2:
                # The middle one stands for its frame on the frame timeline, where the object's
                # pose is the mid-exposure one (without it the super-resolved panel was empty
                # there). A stream of its own: a sample of the full stream there would refer to
                # sub-frames that timeline does not hold.
                self._at(frame=index)
                self._log_video("tsr", sub, stream="tsr middle")

    @timed("recording")
    def log_fit(
        self,
        index: int,
        track: int,
        state: ObjectState,
        losses: dict[str, float],
        curve: list[dict[str, float]],
    ) -> None:
        """Log the fit of track ``track``'s object in frame ``index`` (under ``world/track_XX``,
        ``losses/track_XX`` and ``fit/track_XX``).

        Args:
            state: the fitted object; its mesh is logged with its pose at mid-exposure on the frame
                timeline and at each sub-frame's mid-time on the subframe timeline.
            losses: the final value of each loss.
            curve: one dict (loss name -> value) per optimisation step.
        """
        n = self.subframes
        device = state.motion.x0.device
        mid_rot, mid_pos = state.motion.at(torch.full((1,), 0.5, device=device))
        sub_rot, sub_pos = state.motion.at(exposure_times(n, device))
        entity, part = track_entity(track), f"track_{track:02d}"

        self._at_frame(index)
        self._log(entity, _mesh3d(state))
        for name, value in losses.items():
            self._log(f"losses/{part}/{rr.escape_entity_path_part(name)}", rr.Scalars(float(value)))

        self._at(frame=index)
        self._log(entity, _transform(mid_rot[0], mid_pos[0]))
        for k in range(n):
            self._at(subframe=index * n + k)
            self._log(entity, _transform(sub_rot[k], sub_pos[k]))

        # One columnar call per loss instead of a log call per step and loss: a fit runs hundreds
        # of steps. send_columns ignores the stream's current time, so the index is explicit.
        first = self._steps.get(track, 0)
        self._steps[track] = first + len(curve)
        for name in dict.fromkeys(key for row in curve for key in row):
            steps = [s for s, row in enumerate(curve) if name in row]
            self._check_open()
            self._rec.send_columns(
                f"fit/{part}/{rr.escape_entity_path_part(name)}",
                indexes=[rr.TimeColumn(STEP, sequence=[first + s for s in steps])],
                columns=rr.Scalars.columns(scalars=[float(curve[s][name]) for s in steps]),
                strict=True,
            )

    def log_quality(self, index: int, track: int, explained: float) -> None:
        """Log how much of frame ``index``'s difference from its background track ``track``'s fit
        explains (:func:`sfb_video.stages.composite.explained`) as ``quality/track_XX/explained``."""
        self._at_frame(index)
        self._log(f"quality/track_{track:02d}/explained", rr.Scalars(float(explained)))

    @timed("recording")
    def log_masks(self, index: int, source: str, box: Box, masks: torch.Tensor | None, track: int = 0) -> None:
        """Note which masks the fit of track ``track``'s object in frame ``index`` used (written
        once, on close, as ``run/masks``) and, when it used sub-frame masks, show them at each
        sub-frame's mid-time (an entity per track: two objects' masks side by side).

        Args:
            source: what the fit used, in words (``"diff"``, ``"defmo"``, with their order).
            box: (x, y, w, h) the crop box the masks cover, in frame pixels.
            masks: (N, h, w) soft masks in [0, 1] at the crop's working size, in time order, or
                None (a fit without them; clears earlier masks).
        """
        n = self.subframes
        entity = f"world/camera/image/subframe_mask/track_{track:02d}"
        self._sources.setdefault(track, {}).setdefault(source, []).append(index)
        if masks is None:
            if track in self._masks_shown:
                self._at(subframe=index * n)
                self._log(entity, rr.Clear(recursive=False))
                self._masks_shown.discard(track)
            return
        check_shape(masks, (None, None, None), "masks")
        x, y, w, h = box
        if w <= 0 or h <= 0 or x < 0 or y < 0 or x + w > self.camera.width or y + h > self.camera.height:
            raise SfbError(f"mask box {box} is not inside the {self.camera.width}x{self.camera.height} frame")
        pasted = torch.nn.functional.interpolate(
            masks.detach().float().cpu()[:, None], size=(h, w), mode="bilinear", align_corners=False
        )[:, 0]
        for k in range(n):
            ids = np.zeros((self.camera.height, self.camera.width), dtype=np.uint8)
            j = min(int((k + 0.5) * masks.shape[0] / n), masks.shape[0] - 1)
            ids[y : y + h, x : x + w] = (pasted[j] > 0.5).numpy().astype(np.uint8) * SUBFRAME_MASK_CLASS
            self._at(subframe=index * n + k)
            self._log(entity, rr.SegmentationImage(self._shrunk(ids), opacity=0.5))
        self._masks_shown.add(track)

    @timed("recording")
    def log_trajectory(self, points: np.ndarray, track: int = 0) -> None:
        """Log track ``track``'s (P, 3) 3D positions so far at the last frame logged, replacing
        the previous ones."""
        if self._frame is None:
            raise SfbError("log a frame before the trajectory: it is logged at the current frame")
        points = np.asarray(points, dtype=np.float32)
        if points.ndim != 2 or points.shape[1] != 3:
            raise SfbError(f"trajectory points must have shape (*, 3), got {points.shape}")
        self._at_frame(self._frame)
        self._paths[track] = points
        if len(points) == 0:
            self._log(f"world/trajectory/track_{track:02d}", rr.Clear(recursive=False))
            return
        self._log(
            f"world/trajectory/track_{track:02d}",
            rr.LineStrips3D([points], radii=TRAJECTORY_LINE_RADIUS),
            rr.Points3D(points, radii=TRAJECTORY_POINT_RADIUS),
        )

    @timed("recording")
    def log_run(self, config: dict, summary: dict) -> None:
        """Log the run's resolved ``config``, its ``summary`` (summary.json's content) and the shape
        each track's windows chose (:func:`shape_text`) once, as static text under ``run``."""
        text = yaml.safe_dump(config, sort_keys=False)
        self._log("run/config", rr.TextDocument(f"```yaml\n{text}```", media_type=rr.MediaType.MARKDOWN), static=True)
        text = json.dumps(summary, indent=2)
        self._log(
            "run/summary", rr.TextDocument(f"```json\n{text}\n```", media_type=rr.MediaType.MARKDOWN), static=True
        )
        shapes = shape_text(summary.get("joint", {}).get("windows", []))
        self._log("run/shapes", rr.TextDocument(shapes, media_type=rr.MediaType.MARKDOWN), static=True)

    # ----------------------------------------------------------------------------------------------
    # Finishing

    @timed("recording")
    def close(self) -> None:
        """Finish the file and move it onto ``path``. Does nothing if already closed or aborted.

        Raises:
            OutputError: the file could not be written (a full disk: the footer, written last,
                may be what does not fit); no temporary file is left then.
        """
        if self._tmp is None:
            return
        try:
            self._log_sources()
            self._rec.send_blueprint(layout(sorted(self._steps), list(self._paths.values()), self.subframes))
            self._flush()  # an OutputError comes after aborting
            self._close_videos()
        except BaseException:
            self.abort()  # Ctrl-C while waiting (does nothing after an abort)
            raise
        tmp, self._tmp = self._tmp, None
        try:
            # disconnect() writes the footer and closes rerun's end of the pipe; the file is
            # complete once the copy thread has written the last bytes.
            self._rec.disconnect()
            self._finish_pipe()
            os.replace(tmp, self.path)
        except OSError as e:
            tmp.unlink(missing_ok=True)
            raise output_error(self.path, e) from None
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise

    def abort(self) -> None:
        """Stop recording and remove the temporary file; ``path`` is left untouched."""
        if self._tmp is None:
            return
        tmp, self._tmp = self._tmp, None
        try:
            with contextlib.suppress(Exception):  # an encoder's error is moot: the file is removed
                self._close_videos()
            self._rec.disconnect()
            # Its write error, if any, is moot: the file is removed.
            with contextlib.suppress(OSError):
                self._finish_pipe()
        finally:
            tmp.unlink(missing_ok=True)

    # ----------------------------------------------------------------------------------------------
    # Internals

    def _log_static(self, camera: PinholeCamera) -> None:
        self._log("world", rr.ViewCoordinates.RDF, static=True)
        # rerun's pixel centres are at half-integers: the shrunk image's coordinates are those
        # scaled by view / size.
        sx, sy = self._sx, self._sy
        intrinsics = [[camera.fx * sx, 0.0, (camera.cx + 0.5) * sx], [0.0, camera.fy * sy, (camera.cy + 0.5) * sy]]
        self._log(
            "world/camera",
            rr.Pinhole(
                image_from_camera=[*intrinsics, [0.0, 0.0, 1.0]],
                resolution=list(self.view_size),
                camera_xyz=rr.ViewCoordinates.RDF,
            ),
            static=True,
        )
        # On the parent, so that the Clear of a frame without a mask cannot touch it; the mask finds
        # its class colours there.
        # Class 0 needs its own colour, transparent: left out, the viewer tints the whole frame.
        classes = [
            (0, "", (0, 0, 0, 0)),
            (MASK_CLASS, "object", (255, 64, 64)),
            (SUBFRAME_MASK_CLASS, "sub-frame mask", (64, 160, 255)),
        ]
        self._log("world/camera/image", rr.AnnotationContext(classes), static=True)

    def _log_sources(self) -> None:
        """The masks the fits used, once, per track: a line per source with its frames."""
        lines = [
            f"- track {track}: {source}, frames {spans(frames)}"
            for track, sources in sorted(self._sources.items())
            for source, frames in sources.items()
        ]
        text = "\n".join(lines) or "no object was fitted"
        self._log("run/masks", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)

    def _at_frame(self, index: int) -> None:
        """Stamp the next log calls at frame ``index`` and at its first sub-frame, so that what is
        logged once a frame shows on both timelines."""
        self._at(frame=index, subframe=index * self.subframes)

    def _at(self, *, frame: int | None = None, subframe: int | None = None) -> None:
        """Set exactly the given timelines for the next log calls (the others are unset)."""
        self._check_open()
        self._rec.reset_time()
        if frame is not None:
            self._frame = int(frame)
            self._rec.set_time(FRAME, sequence=int(frame))
        if subframe is not None:
            self._rec.set_time(SUBFRAME, sequence=int(subframe))

    def _log_video(self, path: str, image: torch.Tensor, stream: str | None = None) -> None:
        """Log (3, H, W) ``image`` at ``path`` as the next sample of its video ``stream`` (by
        default the path's own), at the times set; the first sample of a path logs its codec."""
        stream = stream or path
        encoder = self._videos.get(stream)
        if encoder is None:
            encoder = self._videos[stream] = VideoEncoder(*self.view_size)
        if path not in self._codecs:
            self._log(path, rr.VideoStream(codec=rr.VideoCodec.AV1), static=True)
            self._codecs.add(path)
        sample, keyframe = encoder.encode(self._shrunk(to_uint8(image)))
        self._log(path, rr.VideoStream.from_fields(sample=sample, is_keyframe=keyframe))

    def _shrunk(self, pixels: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 colours, or (H, W) uint8 ids of one class and 0, at the recording's
        size, averaged over each pixel's area (INTER_AREA); ids where at least half the area is
        the class (the nearest pixel would sit a quarter pixel up and left of the image)."""
        if self.shrink == 1:
            return pixels
        if pixels.ndim == 3:
            return cv2.resize(pixels, self.view_size, interpolation=cv2.INTER_AREA)
        label = int(pixels.max())
        share = cv2.resize((pixels > 0).astype(np.float32), self.view_size, interpolation=cv2.INTER_AREA)
        return (share >= 0.5).astype(np.uint8) * label

    def _close_videos(self) -> None:
        """Close every encoder, each whatever the others do; the first error is raised after."""
        videos, self._videos = self._videos, {}
        error: BaseException | None = None
        for encoder in videos.values():
            try:
                encoder.close()
            except BaseException as e:  # Ctrl-C included: the rest still close
                error = error or e
        if error is not None:
            raise error

    def _log(self, path: str, *archetypes: rr.AsComponents, static: bool = False) -> None:
        self._check_open()
        self._rec.log(path, *archetypes, static=static, strict=True)

    def _flush(self) -> None:
        """Hand everything logged so far to the copy thread, and raise the first error it met
        writing the file (a full disk) as an OutputError, after aborting: the recording cannot be
        completed, and the caller's ``with`` block must not wait on it.

        The copy runs behind rerun's flush, so an error of the bytes just handed over surfaces at
        the next flush (the next frame, or :meth:`close`)."""
        self._check_open()
        assert self._pipe is not None  # open means piped (abort and close drop both)
        try:
            self._rec.flush(timeout_sec=FLUSH_TIMEOUT_S)
        except RuntimeError as e:
            error = OutputError(f"cannot write {self.path}: the disk did not answer ({str(e).splitlines()[0]})")
        else:
            error = None if self._pipe.error is None else output_error(self.path, self._pipe.error)
        if error is not None:
            self.abort()
            raise error

    def _finish_pipe(self) -> None:
        """Close the pipe after rerun closed its end: wait for the last bytes to be written."""
        pipe, self._pipe = self._pipe, None
        if pipe is not None:
            pipe.finish(FLUSH_TIMEOUT_S)

    def _check_open(self) -> None:
        if self._tmp is None:
            raise SfbError(f"the recording {self.path} is already closed")

    def _check_image(self, image: torch.Tensor, name: str) -> None:
        check_shape(image, (3, self.camera.height, self.camera.width), name)


def _transform(rotation: torch.Tensor, position: torch.Tensor) -> rr.Transform3D:
    """The pose x_cam = R x_obj + t of (3, 3) ``rotation`` and (3,) ``position`` (pose_vertices' convention)."""
    return rr.Transform3D(
        translation=position.detach().cpu().numpy().astype(np.float32),
        mat3x3=rotation.detach().cpu().numpy().astype(np.float32),
    )


def _mesh3d(state: ObjectState) -> rr.Mesh3D:
    """The textured mesh of ``state`` in object coordinates, one vertex per distinct (vertex, UV) pair."""
    mesh = to_trimesh(state)
    positions = np.asarray(mesh.vertices, dtype=np.float32)
    triangles = np.asarray(mesh.faces, dtype=np.uint32)
    texcoords = np.array(mesh.visual.uv, dtype=np.float32)
    # to_trimesh flips v up for OBJ/glTF; rerun's texcoords have v down like image rows (origin at
    # the top-left, as in Vulkan/Metal), which is the project's own convention, so flip it back.
    texcoords[:, 1] = 1 - texcoords[:, 1]
    return rr.Mesh3D(
        vertex_positions=positions,
        triangle_indices=triangles,
        vertex_normals=_smooth_normals(positions, triangles),
        vertex_texcoords=texcoords,
        albedo_texture=to_uint8(state.texture),
    )


def _smooth_normals(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V, 3) unit vertex normals for (V, 3) positions and (F, 3) counter-clockwise triangles.

    rerun shades a mesh without normals poorly. The vertices split at UV seams are merged by
    position first, so the seams do not show as creases.
    """
    _, group = np.unique(positions, axis=0, return_inverse=True)
    group = group.reshape(-1)
    corners = positions[triangles]
    # The cross product's length is twice the area: larger faces weigh more.
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    sums = np.zeros((int(group.max()) + 1 if group.size else 0, 3), dtype=np.float64)
    np.add.at(sums, group[triangles], np.broadcast_to(face_normals[:, None, :], (len(triangles), 3, 3)))
    normals = sums[group]
    return (normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)).astype(np.float32)
