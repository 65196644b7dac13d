"""The whole pipeline for one clip: read -> background -> track (detect, fit) -> joint -> export.

The run folder (:mod:`sfb_video.run_folder`) is created, resumed or staged for replacement
first. Every fitted frame is written into it once no later frame can change it (at most a few
frames after it is fitted), and every window's joint fit when it is done; each file is written
once. A run that stops (Ctrl-C, a crash, a full disk) resumes from there when started again with
the same clip and config. The exports are written last, from the saved results,
``summary.json`` after them, and the run is marked finished (and a replacement swapped in) only then.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
from collections.abc import Callable, Generator
from dataclasses import dataclass, fields
from pathlib import Path

import torch
from tqdm import tqdm

from sfb_video.atomic import write_json
from sfb_video.config import CameraConfig, Config, config_to_dict, save_config
from sfb_video.errors import SfbError, printable
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.recording import Recorder
from sfb_video.registration import CameraMotion
from sfb_video.results import FrameResult, SavedWindow
from sfb_video.run_folder import (
    CAMERA_MOTION,
    CONFIG,
    OUTPUTS,
    RECORDING,
    SUMMARY,
    TRAJECTORY,
    RunFolder,
    open_run,
    read_marker,
    saved_frames,
)
from sfb_video.stages.background import frames_read, with_backgrounds
from sfb_video.stages.export import export_frames
from sfb_video.stages.masks import MaskSource, choose_masks, print_line
from sfb_video.stages.read import check_video, probe, select_frames
from sfb_video.stages.register import camera_motion
from sfb_video.stages.run_results import FolderSource, RunResults, read_run, write_statuses
from sfb_video.stages.summary import summarise
from sfb_video.stages.track import track_and_fit
from sfb_video.stages.trajectory import write_csv
from sfb_video.stages.types import FrameStatus, FrameWithBackground
from sfb_video.stages.windows import fit_windows
from sfb_video.timing import timed
from sfb_video.video import VideoInfo


@dataclass(frozen=True)
class ClipOptions:
    """What a user asks of a clip's run, the same for one clip (``process``) and for every clip
    of a ``batch``: declared here once.

    Attributes:
        frames: only the frames this selection picks (``START:STOP``, :func:`select_frames`;
            all when None).
        background: a background image instead of the estimated one.
        focal_px: the camera's focal length in pixels (else from ``camera.fov_y_deg``).
        object_diameter: the object's real diameter in metres, for metric positions and speeds.
        overwrite: replace a finished run in the run folder.
        masks: ``auto``, ``defmo`` or ``diff``: which sub-frame masks the fits use
            (:func:`sfb_video.stages.masks.choose_masks`).
        defmo_weights: a folder with DeFMO's weights (default: torch hub's cache).
    """

    frames: str | None = None
    background: Path | None = None
    focal_px: float | None = None
    object_diameter: float | None = None
    overwrite: bool = False
    masks: str = "auto"
    defmo_weights: Path | None = None

    def for_clip(self, video: Path, out: Path) -> ProcessOptions:
        """These options for the run of ``video`` into the run folder ``out``."""
        return ProcessOptions(video=video, out=out, **{f.name: getattr(self, f.name) for f in fields(ClipOptions)})


@dataclass(frozen=True, kw_only=True)
class ProcessOptions(ClipOptions):
    """What a user asks of one ``sfb-video process`` run: the clip, its run folder and the
    :class:`ClipOptions`."""

    video: Path
    out: Path


def clip_camera(info: VideoInfo, camera: CameraConfig, focal_px: float | None) -> PinholeCamera:
    """The clip's camera: centred principal point, focal length given or from the field of view."""
    if focal_px is None:
        return PinholeCamera.from_fov(info.width, info.height, camera.fov_y_deg)
    if focal_px <= 0:
        raise SfbError(f"--focal-px must be positive, got {focal_px}")
    return PinholeCamera(focal_px, focal_px, (info.width - 1) / 2, (info.height - 1) / 2, info.width, info.height)


def on_canvas(camera: PinholeCamera, motion: CameraMotion | None) -> PinholeCamera:
    """The clip's ``camera`` as it sees a moving camera's registered frames: the reference's,
    rendering the canvas they are drawn on."""
    return camera if motion is None or motion.canvas is None else motion.canvas.camera(camera)


def _run_record(options: ProcessOptions, frames: range | None, config: Config, masks: MaskSource) -> dict:
    video = options.video.resolve()
    stat = video.stat()
    record = {
        "video": str(video),
        "video_size": stat.st_size,
        "frames": None if frames is None else [frames.start, frames.stop],
        "background": None if options.background is None else str(options.background.resolve()),
        "focal_px": options.focal_px,
        "object_diameter": options.object_diameter,
        "config": config_to_dict(config),
        "masks": masks.name,
        "masks_reason": masks.reason,
    }
    # What changes the fits, nothing else: a resumed run must not mix two kinds of fit.
    text = json.dumps({k: v for k, v in record.items() if k not in ("object_diameter", "masks_reason")}, sort_keys=True)
    record["fingerprint"] = hashlib.sha256(text.encode()).hexdigest()[:16]
    return record


@timed("export")
def export_run(folder: Path, config: Config, tsr: int, device_note: str = "cpu") -> dict:
    """Write every export of a run whose frames are fitted, ``summary.json`` last; return the summary."""
    record, statuses = read_run(folder)
    if tsr < 1:
        raise SfbError(f"--tsr must be at least 1, got {tsr}")
    video = Path(record["video"])
    info = probe(video, config.video)
    frames = None if record["frames"] is None else range(*record["frames"])
    background = None if record["background"] is None else Path(record["background"])
    saved_motion = (folder / CAMERA_MOTION).is_file() and config.camera.motion != "off"
    motion = CameraMotion.load(folder / CAMERA_MOTION) if saved_motion else None
    camera = on_canvas(clip_camera(info, config.camera, record["focal_px"]), motion)
    # tsr.mp4 shows each frame as filmed, or (stabilised) the canvas as the camera renders it.
    size = (camera.width, camera.height) if config.camera.stabilised else (info.width, info.height)
    stream = with_backgrounds(video, config.video, info.frame_count, frames, background, motion)
    results = RunResults(statuses, FolderSource(folder), config.joint)
    diameter = record["object_diameter"]
    name = printable(video.stem)
    with Recorder(folder / RECORDING, camera, name, subframes=tsr) as recorder:
        done = export_frames(folder, stream, results, camera, size, info.fps, tsr, config, diameter, recorder)
        write_csv(folder / TRAJECTORY, done.rows)
        min_explained = config.video.min_explained
        summary = summarise(record, info, results, done, motion, tsr, device_note, min_explained, OUTPUTS).to_json()
        recorder.log_run(config_to_dict(config), summary)
    write_json(folder / SUMMARY, summary)
    return summary


def check_options(options: ProcessOptions, frames: range | None, info: VideoInfo) -> None:
    """Refuse options that cannot work with this clip, before anything is written.

    Raises:
        SfbError: naming the option and what is wrong with it.
    """
    if options.object_diameter is not None and options.object_diameter <= 0:
        raise SfbError(f"--object-diameter must be positive, got {options.object_diameter}")
    if frames is not None and info.frame_count is not None and frames.start >= info.frame_count:
        raise SfbError(
            f"--frames {frames.start}:{frames.stop} starts after the clip's last frame "
            f"({info.frame_count} frames, indices 0 to {info.frame_count - 1})"
        )


def _frames_to_read(frames: range | None, frame_count: int | None) -> int | None:
    """How many frames a run reads, when that is known (for the progress bar)."""
    if frames is None:
        return frame_count
    if frame_count is None:
        return None
    return len(range(frames.start, min(frames.stop, frame_count)))


def finished_summary(options: ProcessOptions, config: Config, device: torch.device) -> dict | None:
    """The summary of the finished run in ``options.out`` when it is of this clip with this
    config and mask source (the same fingerprint): a rerun with nothing to do. None otherwise."""
    marker = read_marker(options.out)
    if options.overwrite or marker is None or not marker.get("finished") or not options.video.is_file():
        return None
    masks = choose_masks(options.masks, options.defmo_weights, config.crop, device, log=None)
    frames = select_frames(options.frames, probe(options.video, config.video).frame_count)
    if marker.get("fingerprint") != _run_record(options, frames, config, masks)["fingerprint"]:
        return None
    try:
        return json.loads((options.out / SUMMARY).read_text())
    except (OSError, ValueError):
        return None


def process_clip(
    options: ProcessOptions,
    config: Config,
    device: torch.device,
    quiet: bool = False,
    on_frame: Callable[[FrameStatus], None] | None = None,
) -> dict:
    """Run the pipeline on one clip into ``options.out`` and return its summary.

    ``on_frame`` is told each status of each frame (one per object) once the frame is final and
    written, in frame order (a resumed run's saved frames included).

    Raises:
        SfbError: bad input, bad options, an unusable output folder.
        OutputError: the outputs could not be written (full disk, folder removed mid-run);
            the frames fitted so far are kept for resuming.
    """
    check_video(options.video)
    info = probe(options.video, config.video)
    frames = select_frames(options.frames, info.frame_count)
    check_options(options, frames, info)
    camera = clip_camera(info, config.camera, options.focal_px)
    masks = choose_masks(options.masks, options.defmo_weights, config.crop, device, log=None if quiet else print_line)
    record = _run_record(options, frames, config, masks)
    # A run that failed before finishing any frame leaves nothing behind to resume.
    with open_run(
        options.out, "process", record, overwrite=options.overwrite, keep=lambda f: bool(saved_frames(f))
    ) as run:
        summary = _process(run, options, frames, config, info, camera, device, quiet, masks, on_frame)
        run.finish()
    return summary


def _process(
    run: RunFolder,
    options: ProcessOptions,
    selected: range | None,
    config: Config,
    info: VideoInfo,
    camera: PinholeCamera,
    device: torch.device,
    quiet: bool,
    masks: MaskSource,
    on_frame: Callable[[FrameStatus], None] | None = None,
) -> dict:
    save_config(run.work / CONFIG, config)
    if run.resumed and not quiet:
        where = "the unfinished replacement of" if run.replacing else "the unfinished run in"
        out = printable(str(options.out))
        print(f"resuming {where} {out} ({len(saved_frames(run.work))} frames already fitted)")
    total = _frames_to_read(selected, info.frame_count)
    motion = camera_motion(options.video, frames_read(selected, config.video), config.camera)
    if motion is not None:
        motion.save(run.work / CAMERA_MOTION)
    camera = on_canvas(camera, motion)

    def clip_frames() -> contextlib.closing[Generator[FrameWithBackground, None, None]]:
        # A new stream for each pass, closed when the pass ends: the windows pass stops reading
        # after its last window, and its suspended stream kept its background window (six 4K
        # frames and a background: 166 MB) alive through the export.
        return contextlib.closing(
            with_backgrounds(options.video, config.video, info.frame_count, selected, options.background, motion)
        )

    # disable=None: no bar when stderr is not a terminal (logs, CI).
    with tqdm(total=total, unit="frame", desc=printable(options.video.name), disable=True if quiet else None) as bar:
        counted: set[int] = set()  # the bar counts frames; a frame of several objects reports each

        def report(status: FrameStatus, result: FrameResult | None) -> None:
            if status.index not in counted:
                counted.add(status.index)
                bar.update(1)
            if on_frame is not None:
                on_frame(status)
            if result is not None:
                postfix = {"frame": status.index, "track": status.track, "start": result.start}
                bar.set_postfix(postfix | {"L_I": f"{result.losses['image']:.4f}"})

        with clip_frames() as frames:
            statuses = track_and_fit(frames, run.work, camera, config, device, masks, report)
    if not statuses:
        raise SfbError(f"{printable(str(options.video))}: no frames in the requested range")
    if config.joint.enabled:
        results = RunResults(statuses, FolderSource(run.work), config.joint)
        with tqdm(total=len(results.windows), unit="window", desc="joint fit", disable=True if quiet else None) as bar:

            def report_window(window: SavedWindow) -> None:
                bar.update(1)
                bar.set_postfix(
                    frames=f"{window.frames[0]}-{window.frames[-1]}",
                    e=f"{window.result.trajectory.exposure_fraction:.2f}",
                )

            with clip_frames() as frames:
                fit_windows(frames, run.work, results, camera, config, device, report_window)
    write_statuses(run.work, statuses)
    return export_run(run.work, config, config.video.tsr, str(device))
