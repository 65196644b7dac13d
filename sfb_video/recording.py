"""A rerun recording (``recording.rrd``) of a processed clip, to replay the run in the rerun viewer.

Open it with ``rerun recording.rrd``. The file is streamed to disk while the clip is processed:
memory holds no images, only rerun's small per-chunk index (see ``WRITE_FOOTER``). It appears
under its final name only when the recorder is closed; until then it is a hidden temporary file
in the same folder (:func:`sfb_video.atomic.temporary_sibling`), removed if the run fails.

rerun encodes the file (its own file sink, footer included) but does not write it to disk: it
writes into a pipe, and a thread of ours copies the pipe into the temporary file with plain
writes (:class:`_Pipe`). rerun's own file writer stops at a write error (a full disk) and says so
only in its log, after which its flush times out and its disconnect waits forever; through the
pipe, which is always drained, rerun's writer never fails, and a write error is an ``OSError`` of
ours, reported as a one-line :class:`~sfb_video.errors.OutputError` at the next frame or on close.

Entity layout (what each path holds):

    world                          static ViewCoordinates RDF: world = the camera frame (OpenCV,
                                   x right, y down, z forward), so the 3D view matches the image.
    world/camera                   static Pinhole: the clip's intrinsics and resolution, camera at
                                   the world origin.
    world/camera/image             the input frame (JPEG), shown in the pinhole's 2D view and on
                                   its frustum in 3D; static AnnotationContext for the mask.
    world/camera/image/detection   Boxes2D: the detected objects' boxes, labelled by track; Clear on
                                   frames without one.
    world/camera/image/mask        SegmentationImage: the detection mask (class 1 = "object",
                                   uncompressed); Clear on frames without one.
    world/camera/image/subframe_mask  SegmentationImage, subframe timeline only: the sub-frame mask
                                   (DeFMO's; class 2 = "sub-frame mask") each fit used, in the
                                   fit's time order; only in runs with such masks.
    run/masks, run/config, run/summary, run/shapes  static TextDocuments: the masks the fits used,
                                   per track and frames ("diff", or "defmo" and whether DeFMO's
                                   order was kept or reversed); the run's resolved config; its
                                   summary.json; the shape each joint window chose and its margin.
    world/track_XX/object          Mesh3D: track XX's fitted textured mesh in object coordinates
                                   (unit scale), and Transform3D (translation + mat3x3): its pose,
                                   object -> camera coordinates.
    world/trajectory/track_XX      LineStrips3D + Points3D: track XX's 3D positions so far.
    background                     the estimated background (JPEG).
    reconstruction                 I_hat, the fitted object blurred over the background (JPEG).
    tsr                            the temporal super-resolution sub-frames (JPEG), one per
                                   sub-frame time step.
    losses/track_XX/<name>         Scalars: the final value of each loss of a frame's fit.
    fit/track_XX/<name>            Scalars, step timeline only: each loss along the optimisation
                                   of each of the track's fits, one after another.
    quality/track_XX/explained     Scalars: how much of the frame's difference the fit explains.

The layout the viewer opens on (:func:`layout`, sent with the recording as its blueprint): the
input frame with its detection beside the super-resolved sub-frame, the 3D view framed on the
objects' trajectories, and tabs: one per track (its losses and explained), the fits' curves on
the step timeline, the reconstruction and background, the run's text. It opens on the subframe
timeline, where every panel it shows has content.

Timelines (all sequences):

    frame      the frame index. Everything but ``tsr``, ``fit`` and the sub-frame poses is on it;
               at a frame the object's transform is its pose at mid-exposure.
    subframe   ``frame * n + k`` for sub-frame k of the n each frame has (``subframes``): scrub it
               to play the sub-frames. ``tsr`` and the pose at each sub-frame's mid-time live
               here, not on ``frame`` (so they cannot shadow the frame-level pose); everything
               else logged per frame is also stamped at ``frame * n`` so that it shows while
               scrubbing.
    step       the optimisation steps of ``fit/track_XX/<name>``, counted on across the track's
               fits (a frame's fit starts where the previous one ended), so that they read as
               one curve after another, not as a pile of curves that all start at 0.

Reading it back in Python: ``rerun.chunk.RrdReader(path).stream().to_chunks()`` gives chunks with
``entity_path`` (with a leading "/"), ``is_static``, ``timeline_names`` and ``to_record_batch()``,
whose columns are the timelines and components named "<Archetype>:<field>" (e.g.
"Transform3D:translation"); matrices are stored column-major.

Pixel convention: the project puts pixel centres at integers, rerun at half-integers (pixel (0, 0)
covers [0, 1] x [0, 1]), so the pinhole's principal point is (cx + 0.5, cy + 0.5) and a box of
pixels (x, y, w, h) spans [x, x + w] x [y, y + h].
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import threading
import uuid
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
import torch
import yaml

from sfb_video.atomic import AtomicOutput, output_error, temporary_sibling
from sfb_video.errors import OutputError, SfbError, check_shape
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.imageio import to_uint8
from sfb_video.mesh_files import to_trimesh
from sfb_video.model.formation import exposure_times
from sfb_video.model.scene import ObjectState
from sfb_video.timing import timed

APPLICATION_ID = "sfb-video"
FRAME, SUBFRAME, STEP = "frame", "subframe", "step"
JPEG_QUALITY = 90
# The footer is an index of every chunk, written on close: it keeps LazyStore and random access
# working, at the cost of a few KB of memory per chunk until then (about 30 KB per frame
# measured). Everything else streams to disk; False makes memory flat but rerun then warns on
# stderr and readers treat the file as the legacy format.
WRITE_FOOTER = True
# rerun's writer only waits on our copy thread (:class:`_Pipe`), which never stops reading; the
# limit is for a disk that stops answering (a healthy one takes a frame in milliseconds).
FLUSH_TIMEOUT_S = 120.0
# How much of the pipe the copy thread takes at a time.
PIPE_READ_SIZE = 1 << 20
MASK_CLASS = 1
SUBFRAME_MASK_CLASS = 2
# In object sizes (the unit of the 3D scene), so they scale with the object.
TRAJECTORY_LINE_RADIUS = 0.02
TRAJECTORY_POINT_RADIUS = 0.05
EYE_MIN_DISTANCE = 6.0
"""The 3D view's eye stands at least this far from the trajectories' middle, in object sizes."""

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

    Raises:
        SfbError: if the temporary file cannot be created.
    """

    @timed("recording")
    def __init__(
        self, path: str | Path, camera: PinholeCamera, name: str, *, subframes: int, recording_id: str | None = None
    ) -> None:
        if subframes < 1:
            raise SfbError(f"subframes must be at least 1, got {subframes}")
        self.path = Path(path)
        self.camera = camera
        self.subframes = subframes
        self._frame: int | None = None
        self._masks_shown: set[int] = set()  # the tracks whose masks show
        self._sources: dict[int, dict[str, list[int]]] = {}  # track -> mask source -> frames
        self._steps: dict[int, int] = {}  # track -> the steps of its fits logged so far
        self._paths: dict[int, np.ndarray] = {}  # track -> its trajectory, as last logged
        self._tmp: Path | None = temporary_sibling(self.path, ".rrd")
        self._pipe: _Pipe | None = None
        if recording_id is None:
            recording_id = str(uuid.uuid5(uuid.NAMESPACE_URL, f"{APPLICATION_ID}:{name}"))
        self._rec = rr.RecordingStream(application_id=APPLICATION_ID, recording_id=recording_id)
        # Wall-clock log times would make two runs of one clip differ in content, and would add a
        # fourth timeline the viewer might pick by default.
        self._rec.set_log_time_enabled(False)
        try:
            self._pipe = _Pipe(self._tmp)
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
        self._log("world/camera/image", _jpeg(image))
        self._log("background", _jpeg(background))

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
                    mins=[b[:2] for b in boxes.values()],
                    sizes=[b[2:] for b in boxes.values()],
                    labels=[f"track {t}" for t in boxes],
                ),
            )
        if mask is None:
            self._log("world/camera/image/mask", rr.Clear(recursive=False))
        else:
            check_shape(mask, (self.camera.height, self.camera.width), "mask")
            ids = (mask.detach().float().cpu() > 0.5).numpy().astype(np.uint8) * MASK_CLASS
            self._log("world/camera/image/mask", rr.SegmentationImage(ids, opacity=0.5))

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
        self._log("reconstruction", _jpeg(reconstruction))
        for k in range(n):
            sub = subframes[k]
            self._check_image(sub, "subframe")
            # The middle one stands for its frame on the frame timeline, where the object's pose
            # is the mid-exposure one: without it the super-resolved panel was empty there.
            self._at(frame=index if k == n // 2 else None, subframe=index * self.subframes + k)
            self._log("tsr", _jpeg(sub))

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
            self._log(entity, rr.SegmentationImage(ids, opacity=0.5))
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
        intrinsics = [[camera.fx, 0.0, camera.cx + 0.5], [0.0, camera.fy, camera.cy + 0.5], [0.0, 0.0, 1.0]]
        self._log(
            "world/camera",
            rr.Pinhole(
                image_from_camera=intrinsics,
                resolution=[camera.width, camera.height],
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
            f"- track {track}: {source}, frames {_spans(frames)}"
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


class _Pipe:
    """A named pipe for rerun's file sink to write into, copied into ``target`` by a thread.

    The pipe is made in a private temporary folder and its name removed once both ends are open
    (:meth:`start`), so that nothing of it outlives the process. The thread reads until rerun
    closes its end (on disconnect) and never stops reading before: after a write error it keeps
    draining and drops what it reads, so rerun's writer is never blocked and its flush and
    disconnect always return. The first error is kept in :attr:`error`.

    Raises:
        OSError: ``target`` cannot be opened, or the pipe cannot be made.
    """

    def __init__(self, target: Path) -> None:
        self.error: OSError | None = None
        self._thread: threading.Thread | None = None
        self._out: int | None = os.open(target, os.O_WRONLY | os.O_TRUNC | os.O_CLOEXEC)
        self._folder: Path | None = None
        self._in: int | None = None
        try:
            self._folder = Path(tempfile.mkdtemp(prefix="sfb-video-recording-"))
            self.path = self._folder / "pipe"
            os.mkfifo(self.path, 0o600)
            # Non-blocking, or opening the reading end would wait for a writer; rerun's save()
            # opens its end synchronously, and finds this one there.
            self._in = os.open(self.path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
        except BaseException:
            self._close()
            raise

    def start(self) -> None:
        """Start copying, once rerun has opened its end (rerun's ``save`` returned)."""
        assert self._in is not None
        self._remove_name()
        os.set_blocking(self._in, True)
        self._thread = threading.Thread(target=self._copy, name="sfb-video recording writer", daemon=True)
        self._thread.start()

    def finish(self, timeout_s: float) -> None:
        """Wait for the copy to end (rerun has closed its end) and close the file.

        Raises:
            OSError: the first write error, or TimeoutError if the copy did not end in time.
        """
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                # A disk that stopped answering: the thread (a daemon) is left to it.
                raise TimeoutError(f"the recording was not written within {timeout_s:g} s")
        self._close()
        if self.error is not None:
            raise self.error

    def _copy(self) -> None:
        assert self._in is not None and self._out is not None
        try:
            while chunk := os.read(self._in, PIPE_READ_SIZE):
                if self.error is None:
                    try:
                        _write_all(self._out, chunk)
                    except OSError as e:
                        self.error = e
        except OSError as e:  # reading a pipe fails only if something is badly wrong; keep it
            self.error = self.error or e
        finally:
            self._close()

    def _close(self) -> None:
        """Close both descriptors and remove the pipe's name; safe to call more than once."""
        fd_in, fd_out, self._in, self._out = self._in, self._out, None, None
        if fd_in is not None:
            with contextlib.suppress(OSError):
                os.close(fd_in)
        if fd_out is not None:
            try:
                os.close(fd_out)
            except OSError as e:  # some file systems (NFS) report a failed write only here
                self.error = self.error or e
        self._remove_name()

    def _remove_name(self) -> None:
        folder, self._folder = self._folder, None
        if folder is not None:
            with contextlib.suppress(OSError):
                (folder / "pipe").unlink(missing_ok=True)
                folder.rmdir()


def shape_text(windows: Sequence[dict]) -> str:
    """Markdown: per joint window (summary.json's ``joint.windows``), its track, frames and
    shape, and where a trial of shapes chose it (a track's first window, with ``joint.prototypes``)
    how clearly: its margin and each shape's score over the sphere's. Other windows carry on the
    shape of the track's earlier fits (the previous window's, or the single-frame fits')."""
    if not windows:
        return "No joint windows: every frame shows its single-frame fit."
    lines = ["| track | frames | shape | margin | scores over the sphere's |", "|---:|---|---|---:|---|"]
    for w in windows:
        margin = w.get("shape_margin")
        scores = ", ".join(f"{name} {value:.2f}" for name, value in (w.get("shape_trial") or {}).items())
        scores = scores or "no trial: the shape of the track's earlier fits"
        lines.append(
            f"| {w['track']} | {_spans(w['frames'])} | {w['prototype']} | "
            f"{'-' if margin is None else format(margin, '+.2f')} | {scores} |"
        )
    return "\n".join(lines)


def _spans(frames: Sequence[int]) -> str:
    """Frame indices as runs: [0, 1, 2, 5] -> "0-2, 5"."""
    runs: list[list[int]] = []
    for f in sorted(frames):
        if runs and f == runs[-1][1] + 1:
            runs[-1][1] = f
        else:
            runs.append([f, f])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def layout(tracks: Sequence[int], paths: Sequence[np.ndarray], subframes: int) -> rrb.Blueprint:
    """The viewer's layout of a recording (its blueprint), for what a person comes to see.

    Top: the input frame with its detection (and masks) beside the super-resolved sub-frame.
    Bottom: the 3D view framed on the trajectories, beside tabs: one per track (its losses per
    frame and how much it explains), the fits' loss curves (on the step timeline), the
    reconstruction and background, the run's text (masks, summary, config). It opens on the
    subframe timeline (the frame timeline for a recording of one sub-frame per frame), where
    every panel it shows has content. Its views' ids are derived from their place in it, so the
    same recording's layout is the same at every load and two runs write the same layout.

    Args:
        tracks: the tracks fitted; paths: (P, 3) each track's 3D positions.
    """
    per_track = [
        rrb.TimeSeriesView(
            name=f"track {t}",
            origin="/",
            contents=[f"losses/track_{t:02d}/**", f"quality/track_{t:02d}/**"],
        )
        for t in tracks
    ]
    curves = rrb.TimeSeriesView(name="fit curves (step timeline)", origin="fit")
    text = rrb.Vertical(
        rrb.TextDocumentView(name="shapes", origin="run/shapes"),
        rrb.TextDocumentView(name="masks", origin="run/masks"),
        rrb.TextDocumentView(name="summary", origin="run/summary"),
        rrb.TextDocumentView(name="config", origin="run/config"),
        name="run",
    )
    images = rrb.Horizontal(
        rrb.Spatial2DView(name="reconstruction", origin="reconstruction"),
        rrb.Spatial2DView(name="background", origin="background"),
        name="reconstruction",
    )
    scene = rrb.Spatial3DView(
        name="3D",
        origin="world",
        # The frame on the camera's frustum would hide the object behind it from this eye.
        contents=["+ $origin/**", "- world/camera/image/**"],
        eye_controls=_eye(paths),
    )
    root = rrb.Vertical(
        rrb.Horizontal(
            rrb.Spatial2DView(name="input and detection", origin="world/camera/image"),
            rrb.Spatial2DView(name="super-resolved", origin="tsr"),
        ),
        rrb.Horizontal(scene, rrb.Tabs(*per_track, curves, images, text, active_tab=0)),
        row_shares=[3, 2],
    )
    _fix_ids(root, "root")
    timeline = SUBFRAME if subframes > 1 else FRAME
    return rrb.Blueprint(root, rrb.TimePanel(timeline=timeline, state="expanded"), auto_layout=False, auto_views=False)


def _eye(paths: Sequence[np.ndarray]) -> rrb.archetypes.EyeControls3D | None:
    """An eye looking along the camera's axis at the middle of the trajectories, back far enough
    to see them whole (None: no trajectory; the viewer frames the scene)."""
    points = [p for p in paths if len(p)]
    if not points:
        return None
    every = np.concatenate(points).astype(np.float64)
    low, high = every.min(0), every.max(0)
    target = (low + high) / 2
    # In object sizes: a still object is still seen at a few of its sizes.
    distance = 1.2 * float(np.linalg.norm(high - low)) + EYE_MIN_DISTANCE
    # The camera frame is RDF (y down): the eye sits a little above the camera's axis.
    direction = np.array([0.0, -0.35, -1.0]) / np.linalg.norm([0.0, -0.35, -1.0])
    return rrb.archetypes.EyeControls3D(
        kind="Orbital", position=target + distance * direction, look_target=target, eye_up=[0.0, -1.0, 0.0]
    )


def _fix_ids(part: rrb.Container | rrb.View, place: str) -> None:
    """Give ``part`` and what it holds ids derived from ``place``, not random ones."""
    part.id = uuid.uuid5(uuid.NAMESPACE_URL, f"{APPLICATION_ID}:layout:{place}")
    if isinstance(part, rrb.Container):  # a view's contents are its entity queries
        for i, inner in enumerate(part.contents):
            _fix_ids(inner, f"{place}/{i}")


def _write_all(fd: int, data: bytes) -> None:
    """Write all of ``data`` to ``fd``: a write may take only part of it (a short write just
    before the disk is full), and only the next one reports why."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _jpeg(image: torch.Tensor) -> rr.EncodedImage | rr.Image:
    """A (3, H, W) image in [0, 1] as a JPEG-encoded rerun image."""
    return rr.Image(to_uint8(image), color_model="RGB").compress(jpeg_quality=JPEG_QUALITY)


def track_entity(track: int) -> str:
    """The entity of track ``track``'s object: its mesh and pose."""
    return f"world/track_{track:02d}/object"


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
