"""What the video pipeline keeps of each fitted frame, and how it is saved and loaded.

One :class:`FrameResult` per frame in which the object was fitted. It is saved once no later
frame can change it (:func:`sfb_video.run_folder.frame_path`, written atomically), which is what
lets an interrupted run resume and ``sfb-video export`` re-render without fitting again. The joint
fit of a window of a track is saved the same way, as a :class:`SavedWindow`
(:func:`sfb_video.run_folder.window_path`).
"""

from __future__ import annotations

import dataclasses
import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from sfb_video.atomic import atomic_write_bytes
from sfb_video.crop import Box
from sfb_video.errors import SfbError
from sfb_video.fitting.window import JointResult, Refined
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.mesh import MeshTopology
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.model.trajectory import Trajectory
from sfb_video.run_folder import FRAMES, WINDOWS, ensure_folder, frame_path, window_path


@dataclass(frozen=True, order=True)
class FrameKey:
    """What names one fitted object of a run: its frame's index and its track's number."""

    index: int
    track: int

    def path(self, folder: Path) -> Path:
        return frame_path(folder, self.index, self.track)


@dataclass(frozen=True, order=True)
class WindowKey:
    """What names one joint window of a run: its track's number and its first frame."""

    track: int
    first: int

    def path(self, folder: Path) -> Path:
        return window_path(folder, self.track, self.first)


@dataclass(frozen=True)
class FrameResult:
    """The fit of one frame of a clip.

    Attributes:
        index: the frame's index in the clip.
        detection_box: (x, y, w, h) box of the detected blob in the frame.
        crop_box: the box of the crop the fit worked in.
        crop_camera: the camera of that crop at its working resolution.
        state: mesh, texture and motion in the clip's camera coordinates (object sizes), in the
            time direction chosen to join the neighbouring frames.
        start: ``"cold"`` or ``"warm"``.
        prototype: the mesh prototype the fit deformed.
        losses: loss terms at the kept parameters.
        curve: the loss terms at every optimisation step of the kept prototype.
        seconds: wall time of the fit.
        mask_source: the masks the fit used: ``"diff"`` (L_D on the difference mask), ``"defmo"``
            (L_S on DeFMO's sub-frame masks), or another :class:`sfb_video.stages.masks.MaskSource`'s name.
        masks: (N, h, w) the sub-frame masks the fit used, in this result's time order, or None
            for the difference mask.
        masks_reversed: whether that order is the reverse of the masks' own (DeFMO's).
        track: the number of the object's track (several objects in one frame are several
            results, one per track).
    """

    index: int
    detection_box: Box
    crop_box: Box
    crop_camera: PinholeCamera
    state: ObjectState
    start: str
    prototype: str
    losses: dict[str, float]
    curve: list[dict[str, float]]
    seconds: float
    mask_source: str = "diff"
    masks: torch.Tensor | None = None
    masks_reversed: bool = False
    track: int = 0

    @property
    def key(self) -> FrameKey:
        return FrameKey(self.index, self.track)

    def reversed(self) -> FrameResult:
        """The same fit with its motion (and its sub-frame masks) run backwards in time."""
        state = dataclasses.replace(self.state, motion=self.state.motion.reversed())
        if self.masks is None:
            return dataclasses.replace(self, state=state)
        return dataclasses.replace(self, state=state, masks=self.masks.flip(0), masks_reversed=not self.masks_reversed)


def _motion_record(motion: Motion) -> dict[str, torch.Tensor]:
    return {k: getattr(motion, k).detach().cpu() for k in ("x0", "dx", "rot0", "omega")}


def save_result(folder: Path, result: FrameResult, followed: FrameResult | None = None) -> None:
    """Write ``result`` into the run ``folder``, atomically; with ``followed``, the fit its track
    went on from where a track that started later refitted the frame (:func:`load_followed`)."""
    record = _record(result)
    if followed is not None:
        record["followed"] = _record(followed)
    buffer = io.BytesIO()
    torch.save(record, buffer)
    ensure_folder(folder / FRAMES)
    atomic_write_bytes(frame_path(folder, result.index, result.track), buffer.getvalue())


def _record(result: FrameResult) -> dict[str, Any]:
    s = result.state
    return {
        "index": result.index,
        "detection_box": list(result.detection_box),
        "crop_box": list(result.crop_box),
        "crop_camera": dataclasses.asdict(result.crop_camera),
        "vertices": s.vertices.detach().cpu(),
        "faces": s.topology.faces.cpu(),
        "uvs": s.topology.uvs.cpu(),
        "face_uvs": s.topology.face_uvs.cpu(),
        "texture": s.texture.detach().cpu(),
        "motion": _motion_record(s.motion),
        "start": result.start,
        "prototype": result.prototype,
        "losses": dict(result.losses),
        "curve": list(result.curve),
        "seconds": result.seconds,
        "mask_source": result.mask_source,
        # 8 bits are plenty for a soft mask and keep a frame's file small.
        "masks": None if result.masks is None else (result.masks.detach().cpu() * 255).round().to(torch.uint8),
        "masks_reversed": result.masks_reversed,
        "track": result.track,
    }


def load_result(path: Path) -> FrameResult:
    """Read a result written by :func:`save_result` (tensors on the CPU)."""
    return _loaded(path, followed=False)


def load_followed(path: Path) -> FrameResult:
    """The fit a track went on from in a saved frame: the one saved with it where a later track
    refitted the frame (:func:`save_result`), else the frame's own."""
    return _loaded(path, followed=True)


def _loaded(path: Path, followed: bool) -> FrameResult:
    try:
        r = torch.load(path, map_location="cpu", weights_only=True)
        if followed:
            r = r.get("followed") or r
        topology = MeshTopology.build(r["faces"], r["uvs"], r["face_uvs"])
        state = ObjectState(r["vertices"], topology, r["texture"], Motion(**r["motion"]))
        return FrameResult(
            index=int(r["index"]),
            detection_box=tuple(r["detection_box"]),
            crop_box=tuple(r["crop_box"]),
            crop_camera=PinholeCamera(**r["crop_camera"]),
            state=state,
            start=r["start"],
            prototype=r["prototype"],
            losses=r["losses"],
            curve=r["curve"],
            seconds=float(r["seconds"]),
            mask_source=r.get("mask_source", "diff"),
            masks=None if r.get("masks") is None else r["masks"].float() / 255,
            masks_reversed=bool(r.get("masks_reversed", False)),
            track=int(r.get("track", 0)),
        )
    except (OSError, RuntimeError, KeyError, TypeError, EOFError) as exc:
        raise SfbError(f"cannot read the frame result {path}: {exc}") from None


def load_results(folder: Path) -> dict[FrameKey, FrameResult]:
    """Every object fit saved in a run ``folder``, by (frame index, track)."""
    results = (load_result(p) for p in sorted((folder / FRAMES).glob("frame_*.pt")))
    return {r.key: r for r in results}


@dataclass(frozen=True)
class SavedWindow:
    """The joint fit of one window of a track, as the run folder keeps it.

    Attributes:
        track: the track's number (:class:`sfb_video.stages.types.FrameStatus`).
        result: the joint fit; its ``losses`` name the window's frames.
        before: per frame of the window, the loss terms of its single-frame fit (the seed).
        explained: per frame, how much of its difference from the background the single-frame
            fit and the joint fit explain (:func:`sfb_video.stages.composite.fit_quality`), in that order.
        accepted: whether the joint fit stands for the window's frames (else they keep their
            single-frame fits, ``joint.max_explained_drop``).
    """

    track: int
    result: JointResult
    before: dict[int, dict[str, float]]
    explained: dict[int, tuple[float, float]] = dataclasses.field(default_factory=dict)
    accepted: bool = True

    @property
    def frames(self) -> list[int]:
        return sorted(self.result.losses)

    @property
    def key(self) -> WindowKey:
        return WindowKey(self.track, self.frames[0])


def save_window(folder: Path, window: SavedWindow) -> None:
    """Write ``window`` into the run ``folder``, atomically."""
    r, path = window.result, window.result.trajectory
    record: dict[str, Any] = {
        "track": window.track,
        "before": {int(k): dict(v) for k, v in window.before.items()},
        "explained": {int(k): tuple(v) for k, v in window.explained.items()},
        "accepted": window.accepted,
        "prototype": r.prototype,
        "vertices": r.vertices.detach().cpu(),
        "faces": r.topology.faces.cpu(),
        "uvs": r.topology.uvs.cpu(),
        "face_uvs": r.topology.face_uvs.cpu(),
        "texture": r.texture.detach().cpu(),
        "trajectory": {f.name: getattr(path, f.name) for f in dataclasses.fields(path)},
        "losses": {int(k): dict(v) for k, v in r.losses.items()},
        "loss": r.loss,
        "curve": list(r.curve),
        "seconds": r.seconds,
        "bounce": r.bounce,
        "trials": dict(r.trials),
        "shapes": dict(r.shapes),
        "shape_margin": r.shape_margin,
        "refined": {
            int(k): {"texture": v.texture.cpu(), "motion": _motion_record(v.motion), "losses": dict(v.losses)}
            for k, v in r.refined.items()
        },
    }
    buffer = io.BytesIO()
    torch.save(record, buffer)
    ensure_folder(folder / WINDOWS)
    atomic_write_bytes(window_path(folder, window.track, window.frames[0]), buffer.getvalue())


def load_window(path: Path) -> SavedWindow:
    """Read a window written by :func:`save_window` (tensors on the CPU)."""
    try:
        r = torch.load(path, map_location="cpu", weights_only=True)
        result = JointResult(
            prototype=r["prototype"],
            vertices=r["vertices"],
            topology=MeshTopology.build(r["faces"], r["uvs"], r["face_uvs"]),
            texture=r["texture"],
            trajectory=Trajectory(**r["trajectory"]),
            losses=r["losses"],
            loss=float(r["loss"]),
            curve=r["curve"],
            seconds=float(r["seconds"]),
            bounce=r["bounce"],
            trials=r["trials"],
            shapes=r.get("shapes", {}),  # saved before the footprint's trial: none
            shape_margin=r.get("shape_margin"),
            refined={
                int(k): Refined(v["texture"], Motion(**v["motion"]), v["losses"])
                for k, v in r.get("refined", {}).items()
            },
        )
        # Windows saved before the quality check have neither field, and stood for their frames.
        explained = {int(k): (float(v[0]), float(v[1])) for k, v in r.get("explained", {}).items()}
        return SavedWindow(int(r["track"]), result, r["before"], explained, bool(r.get("accepted", True)))
    except (OSError, RuntimeError, KeyError, TypeError, EOFError) as exc:
        raise SfbError(f"cannot read the window {path}: {exc}") from None


def load_windows(folder: Path) -> list[SavedWindow]:
    """Every window saved in a run ``folder``, in frame order (accepted or not)."""
    return [load_window(p) for p in sorted((folder / WINDOWS).glob("window_*.pt"))]
