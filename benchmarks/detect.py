"""Detection against the truth on generated clips that reproduce real footage's failures.

    python -m benchmarks.detect [--frames 8] [--config default] [--set KEY=VALUE ...]

Each scenario is a generated 320x240 clip with ground truth (the tight box of every pixel the
object touches during each exposure); two movers, and a slow mover beside a fast one, are a
second generated object composited into the first clip by its coverage. Frames stream through
the pipeline's own detection: the running-median background, the difference mask, the
slow-mover test against the frames two before and two after, the blob choice without a
prediction (as a track's first frame is found).
A detection counts as found when its box overlaps the true box with IoU >= 0.5. Per scenario:
recall (found / frames that show the object), precision (found / detections), the mean box
IoU of the detections in frames that show the object. Targets (issue 19): recall and precision
>= 0.95, mean box IoU >= 0.8. Where ../shared/data is beside the checkout, a last row pastes
the real aerobie's streak (a large, faint disc) along a path over its own background.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
from pathlib import Path

import cv2
import numpy as np
import torch

from sfb_video.config import Config, load_config
from sfb_video.stages.background import running_median
from sfb_video.stages.detect import choose_blob, moving_mask
from sfb_video.stages.track import with_neighbours
from sfb_video.stages.types import Frame
from sfb_video.synth import ClipSpec, SyntheticClip, generate_clip
from sfb_video.synth.pasted import paste_streak

BASE = ClipSpec(
    width=320,
    height=240,
    num_frames=8,
    exposure_fraction=0.8,
    num_subframes=4,
    sub_exposures=16,
    texture_size=64,
    size_px_range=(18.0, 24.0),
    speed_range=(1.2, 1.6),
)

SCENARIOS: dict[str, dict] = {
    "plain": {},
    "faint (contrast 0.25)": {"contrast": 0.25},
    "dark to bright": {"split_background": True},
    "behind a fence": {"fence_period_px": 16},
    "bounce": {"bounce_time": 3.9, "gravity": 0.05},
    "circular swing": {"swing_period": 6.0},
    "large, slow for its size": {"size_px_range": (40.0, 44.0), "speed_range": (1.0, 1.1), "num_frames": 6},
    "two movers": {"second": ({"shape": "box", "seed": 7}, True)},
    "a slow mover beside": {
        "second": (
            {"shape": "box", "seed": 5, "size_px_range": (60.0, 70.0), "speed_range": (0.1, 0.15), "min_streak": 0.0},
            False,
        )
    },
}
"""Scenario name -> the fields that differ from :data:`BASE`; ``second``: a second object's
fields and whether it is a target too (another fast mover) or must not be found (a slow one)."""


def _add_object(frames: np.ndarray, other: SyntheticClip) -> np.ndarray:
    """(F, H, W, 3) uint8 ``frames`` with ``other``'s object composited in by its coverage:
    each of its frames less its own background where the object covers it."""
    out = frames.astype(np.float64)
    background = other.scene.background.astype(np.float64)
    for k, truth in enumerate(other.truth):
        cover = truth.masks.mean(0)[..., None]
        out[k] = out[k] * (1 - cover) + other.frames[k].astype(np.float64) - (1 - cover) * background
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def box_iou(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """IoU of two (x, y, w, h) pixel boxes."""
    ix = max(0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / float(a[2] * a[3] + b[2] * b[3] - inter)


def score_frames(pixels: np.ndarray, truth: list[list[tuple[int, int, int, int]]], config: Config) -> dict[str, float]:
    """Detect every frame of (F, H, W, 3) uint8 ``pixels``: recall, precision and mean box IoU
    against ``truth``, per frame the boxes of the objects to find (empty: none; a detection of
    any of them counts)."""
    frames = (Frame(k, torch.from_numpy(np.ascontiguousarray(f.transpose(2, 0, 1)))) for k, f in enumerate(pixels))
    stream = running_median(frames, config.video.background_window)
    present = found = detections = 0
    ious = []
    for frame, mask, neighbours in with_neighbours(stream, config):
        boxes = truth[frame.index]
        detection = choose_blob(frame.index, moving_mask(mask, neighbours, config.detect), None, config.detect)
        present += bool(boxes)
        detections += detection is not None
        if boxes and detection is not None:
            iou = max(box_iou(detection.box, box) for box in boxes)
            ious.append(iou)
            found += iou >= 0.5
    return {
        "frames": len(pixels),
        "present": present,
        "detections": detections,
        "recall": found / max(present, 1),
        "precision": found / max(detections, 1),
        "iou": statistics.fmean(ious) if ious else 0.0,
    }


def score_scenario(spec: ClipSpec, config: Config, second: tuple[dict, bool] | None = None) -> dict[str, float]:
    """:func:`score_frames` of the clip ``spec`` makes (with a ``second`` object, see
    :data:`SCENARIOS`)."""
    clip = generate_clip(spec)
    pixels, others = clip.frames, []
    if second is not None:
        other = generate_clip(dataclasses.replace(spec, **second[0]))
        pixels = _add_object(pixels, other)
        others = [other] if second[1] else []
    truth = [
        [b for b in (t.bbox, *(o.truth[t.index].bbox for o in others)) if b is not None] if t.present else []
        for t in clip.truth
    ]
    return score_frames(pixels, truth, config)


PAIRS = Path(__file__).resolve().parents[2] / "shared" / "data" / "pairs"


def aerobie_clip(frames: int = 8) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:
    """The real aerobie's streak (../shared/data/pairs) pasted along an arc over its
    background, 45 px a frame: its ~70 px streaks overlap from frame to frame (large and slow
    for its size), not two frames apart. Frames and the streak's box in each."""
    image, background = (cv2.imread(str(PAIRS / f"aerobie_{n}.png"))[..., ::-1] for n in ("im", "bgr"))
    offsets = [(-60 + 45 * k, round(10 * (k - 3.5) ** 2 / 12)) for k in range(frames)]
    return paste_streak(np.ascontiguousarray(image), np.ascontiguousarray(background), offsets)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=BASE.num_frames)
    parser.add_argument("--config", default="default")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    config = load_config(args.config, args.set)
    rows = []
    for name, fields in SCENARIOS.items():
        own = {k: v for k, v in fields.items() if k != "second"}
        spec = dataclasses.replace(BASE, **({"num_frames": args.frames} | own))
        rows.append((name, score_scenario(spec, config, fields.get("second"))))
    if PAIRS.is_dir():
        pixels, boxes = aerobie_clip(args.frames)
        rows.append(("real aerobie pasted along a path (960x400)", score_frames(pixels, [[b] for b in boxes], config)))
    print(f"preset {args.config} {' '.join(args.set)}; generated clips 320x240\n")
    print("| scenario | frames | with object | detections | recall | precision | mean box IoU |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for name, r in rows:
        print(
            f"| {name} | {r['frames']} | {r['present']} | {r['detections']} | {r['recall']:.2f} | "
            f"{r['precision']:.2f} | {r['iou']:.2f} |"
        )
    total = {k: sum(r[k] for _, r in rows) for k in ("present", "detections")}
    mean = {k: statistics.fmean(r[k] for _, r in rows) for k in ("recall", "precision", "iou")}
    print(
        f"| **all** | {sum(r['frames'] for _, r in rows)} | {total['present']} | {total['detections']} | "
        f"{mean['recall']:.2f} | {mean['precision']:.2f} | {mean['iou']:.2f} |"
    )


if __name__ == "__main__":
    main()
