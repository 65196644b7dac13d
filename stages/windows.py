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

Every export then reads a frame's state from the window that covers it best (the one whose
middle is nearest, :func:`frame_windows`), where that window was accepted and explains the frame
not much worse than its single-frame fit; else from the frame's single-frame fit
(:func:`shown_windows`).
"""

from __future__ import annotations

import dataclasses
import sys
from collections import Counter
from collections.abc import Callable, Collection, Iterator, Mapping
from pathlib import Path

import cv2
import numpy as np
import torch

from sfb_video.config import Config
from sfb_video.crop import Box, box_mask, box_union, make_crop, masks_onto
from sfb_video.errors import DivergenceError
from sfb_video.fitting.path import Seed
from sfb_video.fitting.window import WindowFrame, fit_window, refine_frames
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.model.scene import ObjectState
from sfb_video.results import (
    FrameResult,
    SavedWindow,
    load_result,
    load_window,
    save_window,
)
from sfb_video.run_folder import frame_path, window_path
from sfb_video.stages.composite import fit_quality, object_radius, path_mask
from sfb_video.stages.detect import parallel
from sfb_video.stages.types import FrameStatus, FrameWithBackground, Window
from sfb_video.timing import timed


def track_windows(statuses: list[FrameStatus], size: int, overlap: int) -> list[Window]:
    """The windows of every track of two fitted frames or more, by first frame (then track).

    Args:
        statuses: every frame's objects' statuses, in frame order.
        size: frames per window; overlap: frames a window shares with the previous one.
    """
    runs: list[Window] = []
    last: dict[int, Window] = {}  # track -> its latest run
    for s in statuses:
        if s.status != "fitted" or s.track is None:
            continue
        run = last.get(s.track)
        if run is not None and run[1][-1] == s.index - 1:
            run[1].append(s.index)
        else:
            last[s.track] = (s.track, [s.index])
            runs.append(last[s.track])
    windows: list[Window] = []
    for track, frames in runs:
        if len(frames) < 2:
            continue
        starts = list(range(0, max(1, len(frames) - overlap), size - overlap))
        starts = sorted({min(s, max(0, len(frames) - size)) for s in starts})
        windows += [(track, frames[s : s + size]) for s in starts]
    return sorted(windows, key=window_key)


def window_key(window: Window) -> tuple[int, int]:
    """(first frame, track): what names a window in a run folder."""
    return window[1][0], window[0]


def frame_windows(windows: list[Window]) -> dict[tuple[int, int], tuple[int, int]]:
    """(frame index, track) -> the key of the track's window that covers the frame with the most
    frames on both sides (its middle nearest; the later window on a tie)."""
    owner: dict[tuple[int, int], tuple[float, tuple[int, int]]] = {}
    for track, frames in windows:
        middle = (frames[0] + frames[-1]) / 2
        for index in frames:
            distance = abs(index - middle)
            if (index, track) not in owner or distance <= owner[index, track][0]:
                owner[index, track] = (distance, (frames[0], track))
    return {key: first for key, (_, first) in owner.items()}


def shown_windows(
    windows: list[Window], trusted: Mapping[tuple[int, int], Collection[int]]
) -> dict[tuple[int, int], tuple[int, int]]:
    """:func:`frame_windows` of every window fitted (``windows``), less the frames that their
    window may not stand for (``trusted``: window key -> those it may, :func:`trusted_frames`;
    none for a window not there): such a frame keeps its single-frame fit. A neighbour window
    that also covers it was never judged there (only on the frames it stands for), and its pose
    there may be far off."""
    return {key: first for key, first in frame_windows(windows).items() if key[0] in trusted.get(first, ())}


def trusted_frames(window: SavedWindow, max_drop: float, held: Collection[int] = ()) -> set[int]:
    """The frames whose outputs ``window``'s joint fit may show: none where the window was not
    accepted; else each frame but those it explains more than ``max_drop`` worse than their
    single-frame fits. A window is accepted on its frames' mean, and a gain on one frame (which
    takes in its neighbours' pixels) can hide a fit that lies off its streak on another. The
    frames whose pose the window ``held`` (their streak touched another object's,
    :func:`fit_track_window`) are its own also where it explains less, as long as it explains at
    least half as much as the single-frame fit: that fit, drawn to the other object's pixels,
    explains more and lies off (the crossing of ``benchmarks.multi_object``: 0.53 against the
    window's 0.32), but a window that loses more has lost the object (falling_three's objects
    landing in the bowl: 0.36 against 0.06)."""
    if not window.accepted:
        return set()
    explained = window.explained

    def kept(i: int) -> bool:
        if i not in explained:
            return True
        before, after = explained[i]
        bar = before - max_drop
        return after >= (min(bar, before / 2) if i in held else bar)

    return {i for i in window.frames if kept(i)}


def previous_window(
    windows: list[Window], done: dict[tuple[int, int], SavedWindow], track: int, first: int
) -> SavedWindow | None:
    """The last accepted window of ``track`` before the one that starts at frame ``first``, or
    None."""
    earlier = [window_key(w) for w in windows if w[0] == track and w[1][0] < first]
    return next((done[k] for k in reversed(earlier) if k in done and done[k].accepted), None)


def with_joint(result: FrameResult, window: SavedWindow) -> FrameResult:
    """Frame ``result`` with the window's object and pose in place of its single-frame fit."""
    joint = window.result
    return dataclasses.replace(
        result,
        state=joint.state(result.index),
        prototype=joint.prototype,
        losses=joint.frame_losses(result.index),
        curve=joint.curve,
    )


def shared_boxes(
    parts: dict[tuple[int, int], tuple[int, int, int, int]],
) -> dict[tuple[int, int], tuple[int, int, int, int]]:
    """Per (frame, track) whose streak touched others' (its box a ``part`` of their shared blob),
    the box of the whole blob: the union of the parts' boxes of that frame that touch it, in
    turn. A part can be a sliver where two streaks lie one over the other; the window's crop
    around it would cut off the object's streak (the others' are left out, :func:`others_region`)."""
    out = {}
    for (index, track), box in parts.items():
        union = box
        grown = True
        while grown:
            grown = False
            for (i, _), other in parts.items():
                if i == index and _touch(union, other) and box_union(union, other) != union:
                    union, grown = box_union(union, other), True
        out[index, track] = union
    return out


def touched_blobs(
    statuses: list[FrameStatus],
) -> tuple[dict[tuple[int, int], tuple[int, int, int, int]], set[tuple[int, int]]]:
    """Per (frame index, track) whose streak touched others' (dropped tracks' too), the box of
    their whole blob (:func:`shared_boxes`); and the fitted objects whose blob still holds
    another fitted object. A track dropped as too short
    (:func:`~sfb_video.stages.track.short_tracks_dropped`) gives its share of a blob back:
    falling_three's frame 10, a two-frame track born of a streak cut off at the frame's edge
    took the lower half of the pale end's streak; held as touched, the pale end's window saw
    half its streak, and the neighbour's window the other half."""
    blobs = shared_boxes({(s.index, s.track): s.box for s in statuses if s.touched and s.box is not None})
    fitted = [key for s in statuses if s.status == "fitted" and (key := (s.index, s.track)) in blobs]
    holding = Counter((index, blobs[index, track]) for index, track in fitted)
    return blobs, {(index, track) for index, track in fitted if holding[index, blobs[index, track]] > 1}


def _touch(a: tuple[int, int, int, int], b: tuple[int, int, int, int], gap: int = 2) -> bool:
    return (
        a[0] <= b[0] + b[2] + gap
        and b[0] <= a[0] + a[2] + gap
        and a[1] <= b[1] + b[3] + gap
        and b[1] <= a[1] + a[3] + gap
    )


def window_frame(
    frame: FrameWithBackground,
    box: tuple[int, int, int, int],
    result: FrameResult,
    camera: PinholeCamera,
    config: Config,
    device: torch.device,
) -> WindowFrame:
    """The frame's crop around its detection ``box`` as its single-frame fit made it (the box's
    pixels stand for the detected blob), with the fit's sub-frame masks drawn on it."""
    blob = box_mask(box, frame.pixels.shape[1:])
    pixels, background = frame.pixels.to(device), frame.background_pixels.to(device)
    crop = make_crop(pixels, background, box, camera, config.crop, blob.to(device))
    masks = None if result.masks is None else result.masks.to(device)
    if masks is not None and crop.box != result.crop_box:  # a touched frame's whole blob (shared_boxes)
        masks = masks_onto(masks, result.crop_box, crop)
    return WindowFrame(frame.index, crop, masks)


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

    def beside(self, other: ObjectPath) -> bool:
        """Whether ``other`` runs beside this path (:func:`~sfb_video.stages.detect.parallel`,
        not across it) and within it: at least half its centre's path inside this one's ``mask``."""
        if self.direction is None or other.direction is None or not parallel(self.direction, other.direction):
            return False
        centre = other.distance < 0.5
        on_frame = int(centre.sum())  # none: its centre's path lies off the frame
        return on_frame > 0 and int((centre & self.mask).sum()) >= 0.5 * on_frame


def object_paths(
    results: dict[int, FrameResult], camera: PinholeCamera, boxes: dict[int, Box] | None = None
) -> dict[int, ObjectPath]:
    """Per track, the :class:`ObjectPath` of its object fitted in one frame (``results``, by
    track) in ``camera``'s image; ``boxes``: its blob's box where not the fit's detection box (a
    blob shared with a track since dropped, :func:`touched_blobs`)."""
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


def others_region(track: int, paths: dict[int, ObjectPath], apart: Collection[int] = ()) -> torch.Tensor:
    """(H, W) bool where the other tracks of a frame put their objects (their ``paths``,
    :func:`object_paths`): what a window of ``track`` should not try to explain
    (:meth:`~sfb_video.stages.types.FrameWithBackground.without`). ``apart``: the tracks whose
    streaks touched no other's in the frame (their blobs were their own, or split apart).

    Where another path overlaps this track's own, the overlap stays this object's: where the
    other's streak passes across this one's, a hole in it would cost the fit more than the
    other's streak does. But a fitted path's capsule is as wide as the object's furthest vertex,
    often far wider than its streak, and a poor single-frame fit's runs on past its streak: it
    can hold a neighbour's streak whole (falling_three's frame 11: the window took the
    neighbours in and drew the three as one smear). So where neither streak touched another's,
    the overlap is this object's only inside its blob's box (its streak lies there), and there,
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
            if own.beside(other):
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
        shown: the members whose outputs come from this window (:func:`frame_windows`); None:
            every member. The others are shown from a neighbour, so refining them is wasted.
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
        i: (_quality(single(i).state, crops[i], config), _quality(result.state(i), crops[i], config)) for i in shown
    }
    drop = sum(b - a for b, a in explained.values()) / len(explained)
    return SavedWindow(track, result, before, explained, drop <= config.joint.max_explained_drop)


def _quality(state: ObjectState, frame: WindowFrame, config: Config) -> float:
    crop = frame.crop
    # A single-frame fit is loaded on the CPU; the crop is where the fit runs.
    state = state.to(crop.image.device)
    return fit_quality(state, crop.image, crop.background, crop.camera, config.detect, config.render)


@timed("joint")
def fit_windows(
    frames: Iterator[FrameWithBackground],
    folder: Path,
    statuses: list[FrameStatus],
    camera: PinholeCamera,
    config: Config,
    device: torch.device,
    report: Callable[[SavedWindow], None] | None = None,
) -> list[SavedWindow]:
    """Fit every window of every track jointly, saving each into the run ``folder``; windows
    already saved there are reused (the clip is not read at all when all are).

    Args:
        frames: the clip's frames and backgrounds, in order (read only as far as needed).
        statuses: every frame's status, as :func:`sfb_video.stages.track.track_and_fit` returned them.

    Returns:
        every window's fit, in frame order (a window whose fit diverged is left out).
    """
    windows = track_windows(statuses, config.joint.window, config.joint.overlap)
    done: dict[tuple[int, int], SavedWindow] = {}
    for window in windows:
        path = window_path(folder, window[0], window[1][0])
        if path.is_file():
            done[window_key(window)] = load_window(path)
    pending = [w for w in windows if window_key(w) not in done]
    boxes = {(s.index, s.track): s.box for s in statuses if s.status == "fitted"}
    shared, touched = touched_blobs(statuses)
    boxes |= {k: b for k, b in shared.items() if k in boxes and b != boxes[k]}
    fitted: dict[int, list[int]] = {}  # frame index -> its fitted tracks
    for index, track in boxes:
        if track is not None:
            fitted.setdefault(index, []).append(track)
    owner = frame_windows(windows)

    def single(key: tuple[int, int]) -> FrameResult:
        return load_result(frame_path(folder, *key))

    crops: dict[tuple[int, int], WindowFrame] = {}
    needed: dict[int, set[int]] = {}  # frame index -> the tracks whose crops it gives
    for track, members in pending:
        for index in members:
            needed.setdefault(index, set()).add(track)
    # A window is fitted once its last frame is read; several tracks' windows may wait at once.
    for frame in frames if pending else ():
        keys = [(frame.index, t) for t in sorted(needed.get(frame.index, ()))]
        results = {t: single((frame.index, t)) for t in fitted[frame.index]} if keys else {}
        own_boxes = {t: box for t in results if (box := boxes[frame.index, t]) is not None}
        paths = object_paths(results, camera, own_boxes) if len(results) > 1 else {}
        apart = {t for t in paths if (frame.index, t) not in touched}
        for key in keys:
            box = boxes[key]
            assert box is not None  # a fitted object has its detection
            # Several objects in the frame: the others show the background.
            seen = frame.without(others_region(key[1], paths, apart)) if paths else frame
            crops[key] = window_frame(seen, box, results[key[1]], camera, config, device)
        ready = [w for w in pending if all((i, w[0]) in crops for i in w[1])]
        for track, members in ready:
            pending.remove((track, members))
            previous = previous_window(windows, done, track, members[0])
            own = {i: crops[i, track] for i in members}
            try:
                shown = [i for i in members if owner[i, track] == window_key((track, members))]
                window = fit_track_window(
                    track,
                    members,
                    own,
                    lambda i, t=track: single((i, t)),
                    previous,
                    camera,
                    config,
                    shown,
                    touched={i for i in members if (i, track) in touched},
                )
            except DivergenceError as exc:
                # Non-finite from the first step: the frames keep their single-frame fits.
                print(f"joint fit of frames {members[0]}-{members[-1]} skipped: {exc}", file=sys.stderr)
            else:
                save_window(folder, window)
                done[window_key((track, members))] = window
                if report is not None:
                    report(window)
        if ready:
            keep = {(i, t) for t, m in pending for i in m}
            crops = {k: c for k, c in crops.items() if k in keep}
        if not pending:
            break
    return [done[window_key(w)] for w in windows if window_key(w) in done]
