"""What ``summary.json`` says of a run: frozen records, written as JSON by :meth:`Summary.to_json`."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from sfb_video.registration import CameraMotion
from sfb_video.stages.export import Exported
from sfb_video.stages.run_results import RunResults
from sfb_video.stages.types import FrameStatus, Status
from sfb_video.video import VideoInfo


@dataclass(frozen=True)
class TrackSummary:
    """One track: its fitted and merged frames, its prototype (its last frame's), its median speed
    in object sizes a second and mean ``explained``."""

    track: int
    frames: list[int]
    merged_frames: list[int]
    prototype: str
    speed_sizes_per_s: float
    explained: float


@dataclass(frozen=True)
class CameraSummary:
    """The camera's motion: whether the frames were registered, into how many references (a pan
    beyond the first view), and which frames failed to register (frame -> why)."""

    moving: bool = False
    references: int = 1
    unregistered: dict[str, str] = dataclasses.field(default_factory=dict)


@dataclass(frozen=True)
class WindowSummary:
    """One saved joint window: its frames, motion model, exposure fraction, prototype (with the
    candidates' trial losses, the trial of shapes' scores and how clearly its shape won), the
    frames it refined and stands for, and the mean L_I and ``explained`` before and after."""

    track: int
    frames: list[int]
    model: str
    bounce_frame: int | None
    exposure_fraction: float
    prototype: str
    prototype_trials: dict[str, float]
    shape_trial: dict[str, float]
    shape_margin: float | None
    refined: list[int]
    image_loss_before: float
    image_loss_after: float
    explained_before: float | None
    explained_after: float | None
    accepted: bool
    shown_frames: list[int]
    seconds: float


@dataclass(frozen=True)
class JointSummary:
    """The joint fits: how many windows were accepted and rejected, their median exposure fraction
    (accepted ones), and each saved window."""

    enabled: bool
    windows_accepted: int
    windows_rejected: int
    exposure_fraction: float | None
    windows: list[WindowSummary]


@dataclass(frozen=True)
class Summary:
    """A run: the clip, how many frames and objects were fitted and how, the outputs, every frame's
    status (with what the export found of its fit), each track, the camera and the joint fits."""

    video: str
    width: int
    height: int
    fps: float
    frames_read: int
    frames_fitted: int
    objects_fitted: int
    frames_without_object: int
    frames_with_other_movers: int
    dropped_tracks: list[int]
    cold_starts: int
    warm_starts: int
    mean_seconds_cold: float | None
    mean_seconds_warm: float | None
    mean_image_loss: float | None
    unexplained_frames: list[int]
    min_explained: float
    best_frame: int | None
    best_track: int | None
    tsr: int
    tsr_video_frames: int
    object_diameter_m: float | None
    device: str
    masks: dict[str, str]
    outputs: list[str]
    frames: list[dict[str, Any]]
    tracks: list[TrackSummary]
    camera: CameraSummary
    joint: JointSummary

    def to_json(self) -> dict[str, Any]:
        """``summary.json``'s content."""
        return dataclasses.asdict(self)


def _mean(values: list[float]) -> float | None:
    return sum(values) / len(values) if values else None


def summarise(
    record: dict,
    info: VideoInfo,
    results: RunResults,
    done: Exported,
    motion: CameraMotion | None,
    tsr: int,
    device_note: str,
    min_explained: float,
    outputs: list[str],
) -> Summary:
    """The summary of a run whose exports are written (``done``): ``record`` is its ``run.json``."""
    statuses = list(results.statuses)
    fits = list(done.fits.values())
    fitted = {key.index for key in done.fits}

    def mean(key: str, start: str | None = None) -> float | None:
        return _mean([f[key] for f in fits if start in (None, f["start"])])

    return Summary(
        video=record["video"],
        width=info.width,
        height=info.height,
        fps=info.fps,
        frames_read=len({s.index for s in statuses}),
        frames_fitted=len(fitted),
        objects_fitted=len(fits),
        frames_without_object=len({s.index for s in statuses if s.status == Status.NO_OBJECT} - fitted),
        frames_with_other_movers=len({s.index for s in statuses if "other moving object" in s.note}),
        dropped_tracks=sorted({s.track for s in statuses if s.status == Status.DROPPED and s.track is not None}),
        cold_starts=sum(f["start"] == "cold" for f in fits),
        warm_starts=sum(f["start"] == "warm" for f in fits),
        mean_seconds_cold=mean("seconds", "cold"),
        mean_seconds_warm=mean("seconds", "warm"),
        mean_image_loss=_mean([f["losses"]["image"] for f in fits]),
        unexplained_frames=sorted({k.index for k, f in done.fits.items() if f["explained"] < min_explained}),
        min_explained=min_explained,
        best_frame=None if done.best is None else done.best.index,
        best_track=None if done.best is None else done.best.track,
        tsr=tsr,
        tsr_video_frames=done.video_frames,
        object_diameter_m=record["object_diameter"],
        device=device_note,
        masks={"source": record.get("masks", "diff"), "reason": record.get("masks_reason", "")},
        outputs=outputs,
        frames=[dataclasses.asdict(s) | (done.fits.get(s.key, {}) if s.key else {}) for s in statuses],
        tracks=_tracks(statuses, done),
        camera=_camera(motion),
        joint=_joint(results),
    )


def _tracks(statuses: list[FrameStatus], done: Exported) -> list[TrackSummary]:
    rows = []
    for track in sorted({key.track for key in done.fits}):
        fits = {key.index: f for key, f in sorted(done.fits.items()) if key.track == track}
        speeds = sorted(f["speed_sizes_per_s"] for f in fits.values())
        merged = sorted(s.index for s in statuses if s.track == track and s.status == Status.MERGED)
        rows.append(
            TrackSummary(
                track,
                sorted(fits),
                merged,
                fits[max(fits)]["prototype"],
                speeds[len(speeds) // 2],
                sum(f["explained"] for f in fits.values()) / len(fits),
            )
        )
    return rows


def _camera(motion: CameraMotion | None) -> CameraSummary:
    if motion is None:
        return CameraSummary()
    unregistered = {str(i): note for i, note in sorted(motion.failed.items())}
    return CameraSummary(motion.moving, motion.references, unregistered)


def _joint(results: RunResults) -> JointSummary:
    rows = []
    for window in results.windows:
        saved = results.window(window.key)
        if saved is None:  # its fit diverged
            continue
        joint, frames = saved.result, list(window.frames)
        rows.append(
            WindowSummary(
                track=window.track,
                frames=frames,
                model=joint.trajectory.model,
                bounce_frame=None if joint.bounce is None else frames[0] + joint.bounce,
                exposure_fraction=joint.trajectory.exposure_fraction,
                prototype=joint.prototype,
                prototype_trials=joint.trials,
                shape_trial=joint.shapes,
                shape_margin=joint.shape_margin,
                refined=sorted(joint.refined),
                image_loss_before=sum(saved.before[i]["image"] for i in frames) / len(frames),
                image_loss_after=sum(joint.frame_losses(i)["image"] for i in frames) / len(frames),
                explained_before=_mean([saved.explained[i][0] for i in frames if i in saved.explained]),
                explained_after=_mean([saved.explained[i][1] for i in frames if i in saved.explained]),
                accepted=saved.accepted,
                shown_frames=results.shown_frames(window),
                seconds=joint.seconds,
            )
        )
    fractions = sorted(r.exposure_fraction for r in rows if r.accepted)
    return JointSummary(
        enabled=bool(results.windows),
        windows_accepted=sum(r.accepted for r in rows),
        windows_rejected=sum(not r.accepted for r in rows),
        exposure_fraction=fractions[len(fractions) // 2] if fractions else None,
        windows=rows,
    )
