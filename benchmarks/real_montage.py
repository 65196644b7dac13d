"""Real footage, looked at: each clip's input frames beside the super-resolved sub-frames.

    python -m benchmarks.real_montage [--clip falling_pen:0:8 ...] [--config default] [--set KEY=VALUE ...] [--out DIR]

Processes each clip's frame range (``name:start:stop`` of ``../shared/data/clips``) as
``process`` does, then writes ``DIR/<name>.png``: per fitted frame, its input around the
detection and the ``--tsr`` sub-frames of ``tsr.mp4`` over the same box (a row per object of a
frame, with ``--set video.max_objects=0`` for several), and prints each
window's shape (the joint fit's prototype and the shape trial's residuals). There is no truth:
the picture is the check (a pen long and thin, a ball round, no streak left behind).

``--shake SEED`` first shakes the clip as a hand holds a phone (up to 6 px and 1 degree a frame,
:mod:`sfb_video.synth.shake`) and shows each frame's tiles where the object is in that frame:
the background should stay as filmed (not smeared), the object sharp.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import torch

from sfb_video.config import load_config
from sfb_video.imageio import to_uint8, write_image
from sfb_video.registration import CameraMotion
from sfb_video.run_folder import CAMERA_MOTION
from sfb_video.stages.process import ProcessOptions, process_clip
from sfb_video.synth.shake import shake_frames, shake_transforms
from sfb_video.video import VideoReader, VideoWriter

CLIPS = Path(__file__).resolve().parents[2] / "shared" / "data" / "clips"
DEFAULT = ("falling_pen:0:8", "circle_fast:8:16")
TILE_PX = 120


def _frames(path: Path) -> list[np.ndarray]:
    """Every frame of a video as (H, W, 3) uint8 RGB."""
    with VideoReader(path) as reader:
        return [to_uint8(f) for f in reader]


def _tile(image: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    x, y, w, h = box
    crop = image[y : y + h, x : x + w].astype(np.float32) / 255
    return cv2.resize(crop, (round(w * TILE_PX / h), TILE_PX), interpolation=cv2.INTER_NEAREST)


def _shaken(clip: Path, seed: int, out: Path) -> Path:
    """``clip`` shaken by :func:`sfb_video.synth.shake.shake_transforms`, as an .mp4 in ``out``."""
    frames = np.stack(_frames(clip))
    size = (frames.shape[2], frames.shape[1])
    moves = shake_transforms(len(frames), size, seed, max_shift_px=6.0, max_turn_deg=1.0)
    path = out / f"{clip.stem}_shaken.mp4"
    with VideoWriter(path, 30.0, *size) as video:
        for frame in shake_frames(frames, moves):
            video.write(frame)
    return path


def _in_frame(box: tuple[int, int, int, int], to_canvas: np.ndarray | None) -> tuple[int, int, int, int]:
    """A box on the canvas taken into the frame's own (same size)."""
    if to_canvas is None:
        return box
    x, y, w, h = box
    centre = np.array([[[x + w / 2, y + h / 2]]])
    u, v = cv2.perspectiveTransform(centre, np.linalg.inv(to_canvas))[0, 0]
    return max(0, round(u - w / 2)), max(0, round(v - h / 2)), w, h


def montage(
    name: str, start: int, stop: int, config_name: str, out: Path, tsr: int, shake: int | None, overrides: list[str]
) -> None:
    clip = CLIPS / f"{name}.avi" if (CLIPS / f"{name}.avi").is_file() else CLIPS / f"{name}.mp4"
    if shake is not None:
        out.mkdir(parents=True, exist_ok=True)
        clip, name = _shaken(clip, shake, out), f"{name}_shaken"
    run = out / name
    config = load_config(config_name, [f"video.tsr={tsr}", *overrides])
    options = ProcessOptions(video=clip, out=run, frames=f"{start}:{stop}", overwrite=True, masks="diff")
    process_clip(options, config, torch.device("cpu"), quiet=True)
    summary = json.loads((run / "summary.json").read_text())
    motion = CameraMotion.load(run / CAMERA_MOTION) if (run / CAMERA_MOTION).is_file() else None
    inputs, sub = _frames(clip), _frames(run / "tsr.mp4")
    rows = []
    for frame in summary["frames"]:
        if frame.get("status") != "fitted" or frame.get("box") is None:
            continue
        registration = None if motion is None else motion.of(frame["index"])
        x, y, w, h = _in_frame(tuple(frame["box"]), None if registration is None else motion.to_canvas(registration))
        pad = max(w, h) // 3
        box = (max(0, x - pad), max(0, y - pad), w + 2 * pad, h + 2 * pad)
        k = frame["index"] - start
        tiles = [_tile(inputs[frame["index"]], box)] + [_tile(sub[k * tsr + j], box) for j in range(tsr)]
        height = min(t.shape[0] for t in tiles)
        rows.append(np.concatenate([t[:height] for t in tiles], axis=1))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 2), (0, width - r.shape[1]), (0, 0)), constant_values=1.0) for r in rows]
    write_image(out / f"{name}.png", np.concatenate(rows, axis=0))
    for window in summary.get("joint", {}).get("windows", []):
        shapes = " ".join(f"{k}={v:.2f}" for k, v in window.get("shape_trial", {}).items())
        print(
            f"{name} frames {window['frames'][0]}-{window['frames'][-1]}: {window['prototype']}"
            f" (accepted {window['accepted']}, explained {window['explained_before']:.2f} ->"
            f" {window['explained_after']:.2f}) trial: {shapes}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clip", action="append", help="name:start:stop (repeatable)")
    parser.add_argument("--config", default="default")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--tsr", type=int, default=4)
    parser.add_argument("--out", type=Path, default=Path("runs/real-montage"))
    parser.add_argument("--shake", type=int, metavar="SEED", help="shake each clip first (a handheld camera)")
    args = parser.parse_args()
    for spec in args.clip or DEFAULT:
        name, start, stop = spec.split(":")
        montage(name, int(start), int(stop), args.config, args.out, args.tsr, args.shake, args.set)
        print(f"wrote {args.out / name}{'' if args.shake is None else '_shaken'}.png")


if __name__ == "__main__":
    main()
