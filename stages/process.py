"""The whole pipeline for one clip: read -> background -> detect -> fit, then export.

Every fitted frame is saved to the run folder as soon as it is done; a run that stops (Ctrl-C,
a crash) resumes from there when started again with the same clip and config. The exports are
written last, from the saved results, and ``summary.json`` is the last file of all: a folder
with it is complete, one without it is a run in progress.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import shutil
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from sfb_video.checks import SfbError
from sfb_video.config import Config, config_to_dict, save_config
from sfb_video.export import write_json
from sfb_video.fitter import NoObjectError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.results import FrameResult, load_result, result_path, save_result, saved_frames
from sfb_video.video import VideoInfo
from stages.background import FrameWithBackground, with_backgrounds
from stages.detect import Detection, choose_blob, difference_mask, moving_mask
from stages.export import Exported, export_frames, write_csv
from stages.fit import continue_motion, fit_detection, join, predict
from stages.masks import MaskSource, choose_masks, print_line
from stages.read import probe

RUN_FILE = "run.json"
DETECTIONS_FILE = "detections.json"
SUMMARY_FILE = "summary.json"


@dataclass(frozen=True)
class ProcessOptions:
    """What a user asks of one ``sfb-video process`` run.

    Attributes:
        video: the clip.
        out: the run folder.
        frames: only these frame indices (all when None).
        background: a background image instead of the estimated one.
        focal_px: the camera's focal length in pixels (else from ``camera.fov_y_deg``).
        object_diameter: the object's real diameter in metres, for metric positions and speeds.
        overwrite: replace a finished run in ``out``.
        masks: ``auto``, ``defmo`` or ``diff``: which sub-frame masks the fits use
            (:func:`stages.masks.choose_masks`).
        defmo_weights: a folder with DeFMO's weights (default: torch hub's cache).
    """

    video: Path
    out: Path
    frames: range | None = None
    background: Path | None = None
    focal_px: float | None = None
    object_diameter: float | None = None
    overwrite: bool = False
    masks: str = "auto"
    defmo_weights: Path | None = None


@dataclass(frozen=True)
class FrameStatus:
    """What happened to one frame: ``fitted``, ``no_object`` or ``failed`` (with the reason)."""

    index: int
    status: str
    box: tuple[int, int, int, int] | None = None
    note: str = ""


StepReport = Callable[[FrameStatus, FrameResult | None], None]


def clip_camera(info: VideoInfo, config: Config, focal_px: float | None) -> PinholeCamera:
    """The clip's camera: centred principal point, focal length given or from the field of view."""
    if focal_px is None:
        return PinholeCamera.from_fov(info.width, info.height, config.camera.fov_y_deg)
    if focal_px <= 0:
        raise SfbError(f"--focal-px must be positive, got {focal_px}")
    return PinholeCamera(focal_px, focal_px, (info.width - 1) / 2, (info.height - 1) / 2, info.width, info.height)


def _run_record(options: ProcessOptions, config: Config, masks: MaskSource) -> dict:
    video = options.video.resolve()
    stat = video.stat()
    record = {
        "video": str(video),
        "video_size": stat.st_size,
        "frames": None if options.frames is None else [options.frames.start, options.frames.stop],
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


def prepare_folder(options: ProcessOptions, config: Config, masks: MaskSource) -> bool:
    """Create, resume or replace the run folder; True when earlier results are resumed.

    Raises:
        SfbError: a finished run without ``overwrite``; a folder that is not a run; a run of
            another clip or config; an unwritable folder.
    """
    out, record = options.out, _run_record(options, config, masks)
    run_file = out / RUN_FILE
    resume = False
    if out.exists():
        if not out.is_dir():
            raise SfbError(f"output path {out} exists and is not a folder")
        is_run = run_file.is_file()
        if any(out.iterdir()) and not is_run:
            raise SfbError(f"output folder {out} exists and is not an sfb-video run; choose another --out")
        if (out / SUMMARY_FILE).exists() and not options.overwrite:
            raise SfbError(f"output folder {out} holds a finished run; pass --overwrite to replace it")
        if is_run and options.overwrite:
            shutil.rmtree(out)
        elif is_run:
            old = json.loads(run_file.read_text())
            if old.get("fingerprint") != record["fingerprint"]:
                raise SfbError(
                    f"output folder {out} holds an unfinished run of another clip, config or mask source; "
                    "pass --overwrite to start again"
                )
            resume = True
    try:
        (out / "frames").mkdir(parents=True, exist_ok=True)
        write_json(run_file, record)
    except OSError as exc:
        raise SfbError(f"cannot write to output folder {out}: {exc.strerror or exc}") from None
    return resume


def _with_neighbours(
    frames: Iterator[FrameWithBackground], config: Config
) -> Iterator[tuple[FrameWithBackground, torch.Tensor, list[torch.Tensor]]]:
    """Each frame with its difference mask and those of the frames two before and two after.

    Two frames apart, not one: an FMO's streaks in consecutive frames can overlap (it moves
    little more than its size while the shutter is open), but never two frames apart, while a
    slow mover still covers much the same pixels. Where those frames do not exist (a clip's
    ends, a clip of three frames or fewer), the nearest ones are used instead.
    """
    history: deque[torch.Tensor] = deque(maxlen=2)  # masks of frames t - 2 and t - 1
    ahead: deque[tuple[FrameWithBackground, torch.Tensor]] = deque()  # frame t and up to two after

    def emit() -> tuple[FrameWithBackground, torch.Tensor, list[torch.Tensor]]:
        frame, mask = ahead.popleft()
        after = [m for _, m in ahead]
        near = ([history[0]] if history else []) + ([after[-1]] if after else [])
        history.append(mask)
        return frame, mask, near

    for frame in frames:
        ahead.append((frame, difference_mask(frame.image, frame.background, config.detect)))
        if len(ahead) == 3:
            yield emit()
    while ahead:
        yield emit()


def _follow(
    index: int,
    mask: torch.Tensor,
    neighbours: list[torch.Tensor],
    previous: FrameResult | None,
    may_flip: bool,
    camera: PinholeCamera,
    config: Config,
) -> tuple[Detection | None, FrameResult | None]:
    """Find the object of frame ``index``, near where the track's last frame predicts it.

    The prediction continues ``previous``'s motion; when its time direction is not known yet
    (``may_flip``: the first frame of a track), both directions are tried and the one whose
    prediction lands nearer its detection is kept.

    Returns:
        the detection (None when there is no object) and ``previous`` in the direction that
        predicted it (None when there was no track or the object was found away from it).
    """
    options = [] if previous is None else [previous, previous.reversed()] if may_flip else [previous]
    moving = moving_mask(mask, neighbours, config.detect)
    best: tuple[float, Detection, FrameResult] | None = None
    for option in options:
        prediction = predict(continue_motion(option.state.motion, 1, config.video.exposure_fraction), camera)
        found = choose_blob(index, moving, prediction, config.detect)
        if found is not None:
            x, y, w, h = found.box
            distance = math.hypot(x + w / 2 - prediction.centre[0], y + h / 2 - prediction.centre[1])
            if best is None or distance < best[0]:
                best = (distance, found, option)
    if best is not None:
        return best[1], best[2]
    return choose_blob(index, moving, None, config.detect), None


def track_and_fit(
    options: ProcessOptions,
    config: Config,
    info: VideoInfo,
    camera: PinholeCamera,
    device: torch.device,
    masks: MaskSource | None = None,
    report: StepReport | None = None,
) -> list[FrameStatus]:
    """Detect and fit every frame, saving each result; earlier saved results are reused.

    ``masks`` gives each fit its sub-frame masks (None: the difference mask).

    Returns:
        the status of every frame read.
    """
    saved = saved_frames(options.out)
    statuses: list[FrameStatus] = []
    previous: FrameResult | None = None  # the last fitted frame of the current track
    track_length = 0
    frames = with_backgrounds(options.video, config.video, info.frame_count, options.frames, options.background)
    for frame, mask, neighbours in _with_neighbours(frames, config):
        if previous is not None and frame.index - previous.index != 1:
            previous, track_length = None, 0
        detection, followed = _follow(frame.index, mask, neighbours, previous, track_length == 1, camera, config)
        if followed is None:
            previous, track_length = None, 0  # nothing near the prediction: a new track
        elif followed is not previous:
            previous = followed  # the track's first frame, now known to run the other way
            save_result(options.out, previous)
        if detection is None:
            status, result = FrameStatus(frame.index, "no_object"), None
        else:
            loaded = load_result(result_path(options.out, frame.index)) if frame.index in saved else None
            result = loaded
            try:
                if result is None:
                    start = previous if config.video.warm_start else None
                    result = fit_detection(frame, detection, camera, config, start, device, masks)
                status = FrameStatus(frame.index, "fitted", detection.box)
            except NoObjectError as exc:
                status, result = FrameStatus(frame.index, "no_object", detection.box, str(exc)), None
        if result is not None:
            if previous is not None:
                before, result = join(previous, result, camera, config.video.exposure_fraction, track_length == 1)
                if before is not previous:
                    save_result(options.out, before)
            if result is not loaded:
                save_result(options.out, result)
            previous, track_length = result, track_length + 1
        else:
            previous, track_length = None, 0
        statuses.append(status)
        if report is not None:
            report(status, result)
    if not statuses:
        raise SfbError(f"{options.video}: no frames in the requested range")
    return statuses


def write_statuses(folder: Path, statuses: list[FrameStatus]) -> None:
    """Save what happened to every frame (``detections.json``), for the exports to read."""
    write_json(folder / DETECTIONS_FILE, [dataclasses.asdict(s) for s in statuses])


def read_run(folder: Path) -> tuple[dict, list[FrameStatus]]:
    """The run record and frame statuses of a run folder whose fitting has finished."""
    try:
        record = json.loads((folder / RUN_FILE).read_text())
        rows = json.loads((folder / DETECTIONS_FILE).read_text())
    except FileNotFoundError:
        raise SfbError(f"{folder} is not a run folder whose frames are all fitted (run sfb-video process)") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise SfbError(f"cannot read the run in {folder}: {exc}") from None
    return record, [
        FrameStatus(r["index"], r["status"], None if r["box"] is None else tuple(r["box"]), r["note"]) for r in rows
    ]


def export_run(folder: Path, config: Config, tsr: int, device_note: str = "cpu") -> dict:
    """Write every export of a run whose frames are fitted, ``summary.json`` last; return the summary."""
    record, statuses = read_run(folder)
    if tsr < 1:
        raise SfbError(f"--tsr must be at least 1, got {tsr}")
    video = Path(record["video"])
    info = probe(video, config.video)
    camera = clip_camera(info, config, record["focal_px"])
    frames = None if record["frames"] is None else range(*record["frames"])
    background = None if record["background"] is None else Path(record["background"])
    stream = with_backgrounds(video, config.video, info.frame_count, frames, background)
    boxes = {s.index: s.box for s in statuses}
    diameter = record["object_diameter"]
    done = export_frames(folder, stream, boxes, camera, info.fps, tsr, config, video.stem, diameter)
    write_csv(folder / "trajectory.csv", done.rows)
    summary = _summary(record, info, statuses, done, tsr, device_note)
    write_json(folder / SUMMARY_FILE, summary)
    return summary


def _summary(
    record: dict, info: VideoInfo, statuses: list[FrameStatus], done: Exported, tsr: int, device_note: str
) -> dict:
    frames = [dataclasses.asdict(s) | done.fits.get(s.index, {}) for s in statuses]
    fits = list(done.fits.values())

    def mean(key: str, start: str | None = None) -> float | None:
        values = [f[key] for f in fits if start in (None, f["start"])]
        return sum(values) / len(values) if values else None

    return {
        "video": record["video"],
        "width": info.width,
        "height": info.height,
        "fps": info.fps,
        "frames_read": len(statuses),
        "frames_fitted": len(fits),
        "frames_without_object": sum(s.status == "no_object" for s in statuses),
        "cold_starts": sum(f["start"] == "cold" for f in fits),
        "warm_starts": sum(f["start"] == "warm" for f in fits),
        "mean_seconds_cold": mean("seconds", "cold"),
        "mean_seconds_warm": mean("seconds", "warm"),
        "mean_image_loss": None if not fits else sum(f["losses"]["image"] for f in fits) / len(fits),
        "best_frame": done.best,
        "tsr": tsr,
        "tsr_video_frames": done.video_frames,
        "object_diameter_m": record["object_diameter"],
        "device": device_note,
        "masks": {"source": record.get("masks", "diff"), "reason": record.get("masks_reason", "")},
        "outputs": ["tsr.mp4", "trajectory.csv", "meshes/", "recording.rrd", "summary.json"],
        "frames": frames,
    }


def process_clip(options: ProcessOptions, config: Config, device: torch.device, quiet: bool = False) -> dict:
    """Run the pipeline on one clip into ``options.out`` and return its summary.

    Raises:
        SfbError: bad input, bad options, an unusable output folder.
    """
    if config.video.tsr < 1:
        raise SfbError(f"--tsr must be at least 1, got {config.video.tsr}")
    if not 0 < config.video.exposure_fraction <= 1:
        raise SfbError(f"video.exposure_fraction must be in (0, 1], got {config.video.exposure_fraction}")
    if options.object_diameter is not None and options.object_diameter <= 0:
        raise SfbError(f"--object-diameter must be positive, got {options.object_diameter}")
    info = probe(options.video, config.video)
    camera = clip_camera(info, config, options.focal_px)
    masks = choose_masks(options.masks, options.defmo_weights, config.crop, device, log=None if quiet else print_line)
    created = not options.out.exists()
    resumed = prepare_folder(options, config, masks)
    try:
        return _process(options, config, info, camera, device, quiet, resumed, masks)
    except BaseException:
        # A run that failed before finishing any frame leaves nothing behind to resume.
        if created and not any((options.out / "frames").glob("*.pt")):
            shutil.rmtree(options.out, ignore_errors=True)
        raise


def _process(
    options: ProcessOptions,
    config: Config,
    info: VideoInfo,
    camera: PinholeCamera,
    device: torch.device,
    quiet: bool,
    resumed: bool,
    masks: MaskSource,
) -> dict:
    save_config(options.out / "config.yaml", config)
    saved = len(saved_frames(options.out)) if resumed else 0
    if resumed and not quiet:
        print(f"resuming the unfinished run in {options.out} ({saved} frames already fitted)")
    total = len(options.frames) if options.frames is not None else info.frame_count
    # disable=None: no bar when stderr is not a terminal (logs, CI).
    with tqdm(total=total, unit="frame", desc=options.video.name, disable=True if quiet else None) as bar:

        def report(status: FrameStatus, result: FrameResult | None) -> None:
            bar.update(1)
            if result is not None:
                bar.set_postfix(frame=status.index, start=result.start, L_I=f"{result.losses['image']:.4f}")

        statuses = track_and_fit(options, config, info, camera, device, masks, report)
    write_statuses(options.out, statuses)
    return export_run(options.out, config, config.video.tsr, str(device))
