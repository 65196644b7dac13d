"""Stage 4b, joint: the single-frame fits of each track -> one mesh, texture and trajectory per
window of the track (:mod:`sfb_video.fitting.window`).

A track's fitted frames are cut into windows of ``joint.window`` frames that slide by
``window - overlap`` (a short track is one window; the last window ends at the track's end). The
clip is streamed once more and each window is fitted as soon as its last frame has been read,
from crops rebuilt as the single-frame fits made them (but that the other objects fitted in a
frame show the background there: :func:`others_region`), so memory holds one window's crops
whatever the clip's length. A window's fit is saved into the run folder when done: the
unit a resumed run reuses. The first window of a track chooses a shape among
``joint.prototypes`` from its streaks and starts its fit from that shape alone; each
later window starts from its predecessor's mesh, texture and poses on the frames they share, so
a track keeps one shape. Each window's frames are then refined from its fit (``joint.refine``;
those whose streak touched another object's, for their texture only).

Which fit each frame's outputs then show, the window's or the single-frame one, is
:class:`~sfb_video.stages.run_results.RunResults`' rule.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable, Collection, Iterator
from pathlib import Path

import cv2
import numpy as np
import torch

from sfb_video.config import Config, CropConfig, DetectConfig, RenderConfig
from sfb_video.crop import Box, box_mask, make_crop, masks_onto
from sfb_video.errors import DivergenceError
from sfb_video.fitting.path import Seed
from sfb_video.fitting.window import WindowFrame, fit_window, refine_frames
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.scene import ObjectState
from sfb_video.results import FrameKey, FrameResult, SavedWindow, save_window
from sfb_video.stages.composite import fit_quality, object_radius, path_mask
from sfb_video.stages.run_results import RunResults
from sfb_video.stages.side_by_side import parallel
from sfb_video.stages.types import FrameWithBackground
from sfb_video.timing import timed


def window_frame(
    frame: FrameWithBackground,
    box: tuple[int, int, int, int],
    result: FrameResult,
    camera: PinholeCamera,
    crop: CropConfig,
    device: torch.device,
) -> WindowFrame:
    """The frame's crop around its detection ``box`` as its single-frame fit made it (the box's
    pixels stand for the detected blob), with the fit's sub-frame masks drawn on it."""
    blob = box_mask(box, frame.pixels.shape[1:])
    pixels, background = frame.pixels.to(device), frame.background_pixels.to(device)
    made = make_crop(pixels, background, box, camera, crop, blob.to(device))
    masks = None if result.masks is None else result.masks.to(device)
    # A touched frame's whole blob (run_results.shared_boxes) makes another box; the box's own
    # pixels for a blob can make another working size (the crop bound reads the object's width).
    if masks is not None and (made.box != result.crop_box or masks.shape[-2:] != made.image.shape[1:]):
        masks = masks_onto(masks, result.crop_box, made)
    return WindowFrame(frame.index, made, masks)


@dataclasses.dataclass(frozen=True, eq=False)
class ObjectPath:
    """Where one object fitted in a frame can be (``mask``, (H, W) bool,
    :func:`~sfb_video.stages.composite.path_mask`), each pixel's distance from its projected
    centre's path (``distance``, (H, W) float32 pixels), and that path's (2,) unit ``direction``
    in the image (None for an object that hardly moves), and its detected blob's ``box``, (H, W)
    bool."""

    mask: torch.Tensor
    distance: torch.Tensor
    direction: np.ndarray | None
    box: torch.Tensor

    def beside(self, other: ObjectPath, parallel_deg: float) -> bool:
        """Whether ``other`` runs beside this path (within ``parallel_deg`` of it, not across it)
        and within it: at least half its centre's path inside this one's ``mask``."""
        if self.direction is None or other.direction is None:
            return False
        if not parallel(self.direction, other.direction, parallel_deg):
            return False
        centre = other.distance < 0.5
        on_frame = int(centre.sum())  # none: its centre's path lies off the frame
        return on_frame > 0 and int((centre & self.mask).sum()) >= 0.5 * on_frame


def object_paths(
    results: dict[int, FrameResult], camera: PinholeCamera, boxes: dict[int, Box] | None = None
) -> dict[int, ObjectPath]:
    """Per track, the :class:`ObjectPath` of its object fitted in one frame (``results``, by
    track) in ``camera``'s image; ``boxes``: its blob's box where not the fit's detection box (a
    blob shared with a track since dropped, :func:`~sfb_video.stages.run_results.touched_blobs`)."""
    paths = {}
    for track, result in results.items():
        motion = result.state.motion
        mask = path_mask(motion, object_radius(result.state, camera), camera)
        centre = path_mask(motion, 0.5, camera)
        distance = cv2.distanceTransform((~centre).astype(np.uint8), cv2.DIST_L2, 3)
        uv, _ = camera.project(motion.at(torch.tensor([0.0, 1.0]))[1])
        step = (uv[1] - uv[0]).detach().cpu().double().numpy()
        length = float(np.linalg.norm(step))
        direction = step / length if length >= 1 else None
        box = box_mask((boxes or {}).get(track, result.detection_box), mask.shape)
        paths[track] = ObjectPath(torch.from_numpy(mask), torch.from_numpy(distance), direction, box)
    return paths


def others_region(
    track: int, paths: dict[int, ObjectPath], parallel_deg: float, apart: Collection[int] = ()
) -> torch.Tensor:
    """(H, W) bool where the other tracks of a frame put their objects (their ``paths``,
    :func:`object_paths`): what a window of ``track`` should not try to explain
    (:meth:`~sfb_video.stages.types.FrameWithBackground.without`). ``apart``: the tracks whose
    streaks touched no other's in the frame (their blobs were their own, or split apart).

    Where another path overlaps this track's own, the overlap stays this object's: where the
    other's streak passes across this one's, a hole in it would cost the fit more than the
    other's streak does. But a fitted path's capsule is as wide as the object's furthest vertex,
    often far wider than its streak, and a poor single-frame fit's runs on past its streak: it
    can hold a neighbour's streak whole (the window would draw both as one smear). So where
    neither streak touched another's, the overlap is this object's only inside its blob's box (its
    streak lies there), and there,
    for a neighbour that runs beside its path and lies within it (:meth:`ObjectPath.beside`),
    only the pixels nearer its own centre's path; and the neighbour's box outside this one's is
    the neighbour's, where its fit's path does not cover its streak. Not where two streaks touch
    (two objects crossing): a single-frame fit's path can come out beside the other's though
    the objects cross, and its centre then takes this object's streak away.
    """
    own = paths[track]
    region = torch.zeros_like(own.mask)
    for t, other in paths.items():
        if t == track:
            continue
        kept = own.mask
        if track in apart and t in apart:
            kept = kept & own.box
            if own.beside(other, parallel_deg):
                kept = kept & (own.distance <= other.distance)
            region |= other.box & ~own.box
        region |= other.mask & ~kept
    return region


def fit_track_window(
    track: int,
    members: list[int],
    crops: dict[int, WindowFrame],
    single: Callable[[int], FrameResult],
    previous: SavedWindow | None,
    camera: PinholeCamera,
    config: Config,
    shown: Collection[int] | None = None,
    touched: Collection[int] = (),
) -> SavedWindow:
    """Fit one window of a track jointly.

    Its seeds are its predecessor's poses on the frames they share and the single-frame fits
    elsewhere; the predecessor's shape starts the fit, and only a track's first window (no
    predecessor) runs the shape trial of ``joint.prototypes``; then each frame the window stands
    for is refined from the joint fit (``joint.refine``), and the window is accepted on those.

    Args:
        track: the track's number; members: the window's frame indices, consecutive.
        crops: each member's crop (and sub-frame masks).
        single: frame index -> its single-frame fit.
        previous: the track's previous window, or None.
        shown: the members whose outputs come from this window
            (:meth:`~sfb_video.stages.run_results.RunResults.stands_for`); None: every member.
            The others are shown from a neighbour, so refining them is wasted.
        touched: the members whose streak touched another object's: refined for their texture
            only, on the window's pose.
    """
    seeds, shape_from, before = [], None, {}
    for index in members:
        fit = single(index)
        before[index] = fit.losses
        if previous is not None and index in previous.result.losses:
            joint = previous.result
            seed = Seed(index, joint.state(index), joint.prototype, joint.frame_losses(index)["image"])
            shape_from = shape_from or seed
        else:
            seed = Seed(index, fit.state, fit.prototype, fit.losses["image"])
        seeds.append(seed)
    result = fit_window(
        [crops[i] for i in members],
        seeds,
        camera,
        config.fit,
        config.joint,
        config.render,
        config.video.exposure_fraction,
        prototypes=() if previous is not None else config.joint.prototypes,
        shape_from=shape_from,
    )
    # A window that stands for none of its frames (wholly inside its neighbours) is still
    # judged, on all of them: its fit seeds the next window.
    shown = [i for i in members if shown is None or i in shown] or list(members)
    if config.joint.refine != "off":
        steps = min(config.fit.warm_iterations, config.joint.refine_iterations)
        frames = [crops[i] for i in shown]
        # A frame whose streak touches another object's holds both objects' pixels, and a pose
        # fitted to that frame alone is drawn to the other's: the window's pose there, held by
        # its other frames, is the surer. Its texture is still the frame's own.
        pose = config.joint.refine == "pose"
        result = refine_frames(result, frames, config.fit, config.render, pose, steps, held=touched)
    explained = {
        i: (
            _quality(single(i).state, crops[i], config.detect, config.render),
            _quality(result.state(i), crops[i], config.detect, config.render),
        )
        for i in shown
    }
    drop = sum(b - a for b, a in explained.values()) / len(explained)
    return SavedWindow(track, result, before, explained, drop <= config.joint.max_explained_drop)


def _quality(state: ObjectState, frame: WindowFrame, detect: DetectConfig, render: RenderConfig) -> float:
    crop = frame.crop
    # A single-frame fit is loaded on the CPU; the crop is where the fit runs.
    state = state.to(crop.image.device)
    return fit_quality(state, crop.image, crop.background, crop.camera, detect, render)


@timed("joint")
def fit_windows(
    frames: Iterator[FrameWithBackground],
    folder: Path,
    results: RunResults,
    camera: PinholeCamera,
    config: Config,
    device: torch.device,
    report: Callable[[SavedWindow], None] | None = None,
) -> list[SavedWindow]:
    """Fit every window of every track jointly, saving each into the run ``folder``; windows
    already saved there are reused (the clip is not read at all when all are).

    Args:
        frames: the clip's frames and backgrounds, in order (read only as far as needed).
        results: the run's statuses and saved fits, read from ``folder``.

    Returns:
        every window's fit, in frame order (a window whose fit diverged is left out).
    """
    done = {w.key: saved for w in results.windows if (saved := results.window(w.key)) is not None}
    pending = [w for w in results.windows if w.key not in done]
    touched = results.holding
    crops: dict[FrameKey, WindowFrame] = {}
    needed: dict[int, set[int]] = {}  # frame index -> the tracks whose crops it gives
    for window in pending:
        for index in window.frames:
            needed.setdefault(index, set()).add(window.track)

    # A window is fitted once its last frame is read; several tracks' windows may wait at once.
    for frame in frames if pending else ():
        keys = [FrameKey(frame.index, t) for t in sorted(needed.get(frame.index, ()))]
        fitted = results.fitted(frame.index) if keys else []
        singles = {key.track: results.single(key) for key, _ in fitted}
        # A touched object's crop holds its whole blob (its box a part of it may be a sliver).
        boxes = {key.track: results.blobs.get(key, s.box) for key, s in fitted}
        own_boxes = {t: box for t, box in boxes.items() if box is not None}
        paths = object_paths(singles, camera, own_boxes) if len(singles) > 1 else {}
        apart = {t for t in paths if FrameKey(frame.index, t) not in touched}
        for key in keys:
            box = boxes[key.track]
            assert box is not None  # a fitted object has its detection
            # Several objects in the frame: the others show the background.
            seen = frame.without(others_region(key.track, paths, config.detect.parallel_deg, apart)) if paths else frame
            crops[key] = window_frame(seen, box, singles[key.track], camera, config.crop, device)
        ready = [w for w in pending if all(FrameKey(i, w.track) in crops for i in w.frames)]
        for window in ready:
            pending.remove(window)
            members = list(window.frames)
            try:
                saved = fit_track_window(
                    window.track,
                    members,
                    {i: crops[FrameKey(i, window.track)] for i in members},
                    lambda i, t=window.track: results.single(FrameKey(i, t)),
                    results.previous(window),
                    camera,
                    config,
                    results.stands_for(window),
                    touched=results.held(window),
                )
            except DivergenceError as exc:
                # Non-finite from the first step: the frames keep their single-frame fits.
                print(f"joint fit of frames {members[0]}-{members[-1]} skipped: {exc}", file=sys.stderr)
            else:
                save_window(folder, saved)
                results.source.add_window(window.key, saved)  # the next window's predecessor: not read again
                done[window.key] = saved
                if report is not None:
                    report(saved)
        if ready:
            keep = {FrameKey(i, w.track) for w in pending for i in w.frames}
            crops = {k: c for k, c in crops.items() if k in keep}
        if not pending:
            break
    return [done[w.key] for w in results.windows if w.key in done]
