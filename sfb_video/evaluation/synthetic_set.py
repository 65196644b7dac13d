"""Our synthetic benchmark sets: fixed multi-frame clips with full 3D ground truth.

``synthetic``: five clips, one per shape the generator draws (ball, box, pen, ring, key), with
different speeds and spins. ``synthetic-hard``: longer clips closer to real footage: exposure
fractions from 0.3 to 1.0, 8-12 frames, gravity arcs, a bounce, a faint low-contrast object,
one behind a mesh fence and one crossing from a dark to a bright background. ``shapes``: the
labelled shape benchmark, eight clips per class of object (ball, box, elongated, disc, ring)
over textures, sizes, spins, shutters and a fence, on which the choice of shape is judged
(:func:`shape_specs`). Each clip is fixed
by its seed so the sets and their scores can be reproduced. The set
is written once into a folder (one sub-folder per clip, in ``sfb_video.synth.io``'s layout) and
read back as sequences that the evaluation runs like the benchmark's own.

The background a method is given is the clip's noise-free background: the generator knows it,
and a running median over six frames would only add its own error to the method's.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from sfb_video.atomic import atomic_write_bytes
from sfb_video.config import CameraConfig
from sfb_video.errors import SfbError
from sfb_video.evaluation.datasets import BenchmarkFrame
from sfb_video.registration import register_frames
from sfb_video.stages.background import fixed_background
from sfb_video.stages.register import onto_canvas, registered, usable
from sfb_video.stages.types import Frame
from sfb_video.synth import ClipSpec, SyntheticClip
from sfb_video.synth.io import load_clip, write_clip
from sfb_video.synth.shake import from_first, shake_frames, shake_transforms

SET_FILE = "set.json"
"""Written last into the set's folder: the specs, so a folder is known complete and current."""


def benchmark_specs() -> dict[str, ClipSpec]:
    """The set, by sequence name: 6 frames of 320x240, 8 sub-frames each."""
    common = {"num_frames": 6, "size_px_range": (26.0, 34.0), "exposure_fraction": 0.8}
    return {
        "ball": ClipSpec(shape="ball", speed_range=(1.3, 1.6), rotation_deg_range=(20.0, 50.0), seed=101, **common),
        "box": ClipSpec(shape="box", speed_range=(1.0, 1.3), rotation_deg_range=(30.0, 60.0), seed=102, **common),
        "pen": ClipSpec(shape="pen", speed_range=(1.0, 1.2), rotation_deg_range=(15.0, 40.0), seed=103, **common),
        "ring": ClipSpec(shape="ring", speed_range=(1.4, 1.8), rotation_deg_range=(30.0, 60.0), seed=104, **common),
        "key": ClipSpec(shape="key", speed_range=(1.6, 2.0), rotation_deg_range=(40.0, 80.0), seed=105, **common),
    }


def hard_specs() -> dict[str, ClipSpec]:
    """The harder set, by sequence name: 8-10 frames of 640x480, 8 sub-frames each."""
    frame = {"width": 640, "height": 480, "rotation_deg_range": (20.0, 40.0)}
    return {
        "ball_arc": ClipSpec(
            shape="ball",
            num_frames=10,
            exposure_fraction=0.5,
            speed_range=(1.0, 1.1),
            gravity=0.06,
            size_px_range=(20.0, 26.0),
            seed=201,
            **frame,
        ),
        "ball_bounce": ClipSpec(
            shape="ball",
            num_frames=10,
            exposure_fraction=0.7,
            speed_range=(1.0, 1.2),
            bounce_time=4.85,
            size_px_range=(22.0, 28.0),
            seed=202,
            **frame,
        ),
        "box_short_shutter": ClipSpec(
            shape="box",
            num_frames=8,
            exposure_fraction=0.3,
            speed_range=(1.0, 1.1),
            size_px_range=(18.0, 22.0),
            seed=203,
            **frame,
        ),
        "pen_open_shutter": ClipSpec(
            shape="pen",
            num_frames=8,
            exposure_fraction=1.0,
            speed_range=(1.2, 1.5),
            gravity=0.04,
            size_px_range=(26.0, 32.0),
            seed=204,
            **frame,
        ),
        "ball_faint": ClipSpec(
            shape="ball",
            num_frames=8,
            exposure_fraction=0.8,
            speed_range=(1.2, 1.5),
            contrast=0.3,
            size_px_range=(24.0, 30.0),
            seed=205,
            **frame,
        ),
        "ring_fence": ClipSpec(
            shape="ring",
            num_frames=8,
            exposure_fraction=0.6,
            speed_range=(1.0, 1.2),
            fence_period_px=16,
            size_px_range=(24.0, 30.0),
            seed=206,
            **frame,
        ),
        "box_dark_to_bright": ClipSpec(
            shape="box",
            num_frames=10,
            exposure_fraction=0.8,
            speed_range=(1.0, 1.3),
            split_background=True,
            size_px_range=(24.0, 30.0),
            seed=207,
            **frame,
        ),
    }


SHAPE_CLASSES = {"ball": ("ball",), "box": ("box",), "elongated": ("pen", "key"), "disc": ("disc",), "ring": ("ring",)}
"""The shape benchmark's classes, each with the generator's shapes it holds."""

PROTOTYPE_CLASSES = {
    "sphere": "ball",
    "sphere_large": "ball",
    "box": "box",
    "capsule": "elongated",
    "disc": "disc",
    "torus": "ring",
}
"""The class of the shape benchmark that each of the fitter's prototypes stands for."""

_OWN_STYLE = {"ball": "seam", "box": "checker", "pen": "stripes", "key": "mixed", "disc": "spokes", "ring": "checker"}
"""Per shape, the texture its kind of object often shows (a tennis ball's seam, a disc's spokes)."""


def shape_specs() -> dict[str, ClipSpec]:
    """The labelled shape benchmark, by sequence name (``<class>_<variant>``): eight sequences per
    class of :data:`SHAPE_CLASSES` (the elongated class alternating pens and keys), one per
    variant: a small plain object; stripes on a half-open shutter; the shape's own look (a
    seam, spokes) on an open one; a faint one; one behind a fence; a short shutter with a fast
    spin; a large one (70-80 px); a falling arc of 8 frames. 6-8 frames each, mostly of
    640x480, over photos drawn by the seed; the exposure is not told."""
    variants: dict[str, dict] = {
        "plain": {
            "texture_style": "plain",
            "size_px_range": (15.0, 20.0),
            "exposure_fraction": 0.8,
            "speed_range": (1.2, 1.5),
            "rotation_deg_range": (20.0, 40.0),
            "width": 320,
            "height": 240,
        },
        "stripes": {
            "texture_style": "stripes",
            "size_px_range": (24.0, 30.0),
            "exposure_fraction": 0.5,
            "speed_range": (1.0, 1.2),
            "rotation_deg_range": (40.0, 80.0),
        },
        "own": {
            "size_px_range": (30.0, 36.0),
            "exposure_fraction": 1.0,
            "speed_range": (1.0, 1.3),
            "rotation_deg_range": (10.0, 30.0),
        },
        "faint": {
            "texture_style": "patches",
            "contrast": 0.3,
            "size_px_range": (26.0, 32.0),
            "exposure_fraction": 0.7,
            "speed_range": (1.1, 1.4),
            "rotation_deg_range": (30.0, 60.0),
        },
        "fence": {
            "texture_style": "mixed",
            "fence_period_px": 16,
            "size_px_range": (28.0, 34.0),
            "exposure_fraction": 0.6,
            "speed_range": (1.0, 1.2),
            "rotation_deg_range": (20.0, 40.0),
        },
        "short": {
            "texture_style": "patches",
            "size_px_range": (20.0, 26.0),
            "exposure_fraction": 0.3,
            "speed_range": (1.0, 1.1),
            "rotation_deg_range": (60.0, 120.0),
        },
        "large": {
            "size_px_range": (70.0, 80.0),
            "exposure_fraction": 0.9,
            "speed_range": (1.0, 1.1),
            "rotation_deg_range": (20.0, 50.0),
        },
        "arc": {
            "texture_style": "stripes",
            "size_px_range": (44.0, 52.0),
            "exposure_fraction": 0.7,
            "speed_range": (1.0, 1.1),
            "rotation_deg_range": (30.0, 90.0),
            "gravity": 0.04,
            "num_frames": 8,
        },
    }
    specs = {}
    for c, (name, shapes) in enumerate(SHAPE_CLASSES.items()):
        for v, (variant, fields) in enumerate(variants.items()):
            shape = shapes[v % len(shapes)]
            settings = {"width": 640, "height": 480, "num_frames": 6, "texture_style": _OWN_STYLE[shape]} | fields
            specs[f"{name}_{variant}"] = ClipSpec(shape=shape, seed=300 + 10 * c + v, **settings)
    return specs


def shape_class(name: str) -> str:
    """The class (of :data:`SHAPE_CLASSES`) of the shape benchmark's sequence ``name``."""
    return name.rsplit("_", 1)[0]


SETS = {"synthetic": benchmark_specs, "synthetic-hard": hard_specs, "shapes": shape_specs}
"""Dataset name -> its specs."""


def _specs_record(specs: dict[str, ClipSpec]) -> dict:
    return {name: spec.to_dict() for name, spec in specs.items()}


def ensure_set(root: Path, specs: dict[str, ClipSpec] | None = None, quiet: bool = False) -> None:
    """Generate the set into ``root`` unless it already holds exactly this set.

    Raises:
        SfbError: when ``root`` holds something else (it is never overwritten).
    """
    specs = benchmark_specs() if specs is None else specs
    marker = root / SET_FILE
    if marker.is_file():
        # Compared as specs: a field added to ClipSpec since (at its default) changes nothing.
        saved = {name: ClipSpec.from_dict(d) for name, d in json.loads(marker.read_text()).items()}
        if saved != specs:
            raise SfbError(f"{root} holds a different synthetic set; give another --root or delete it")
        return
    # Clip folders alone are an earlier generation cut short: generation starts over on them.
    strangers = [p.name for p in root.iterdir() if p.name not in specs] if root.exists() else []
    if strangers:
        raise SfbError(f"{root} is not empty and holds no synthetic set (found {strangers[0]}); give a new --root")
    if not quiet:
        print(f"generating the synthetic benchmark set ({len(specs)} clips) into {root}")
    for name, spec in specs.items():
        write_clip(spec, root / name)
    atomic_write_bytes(marker, json.dumps(_specs_record(specs), indent=1).encode())


@dataclass(frozen=True)
class SyntheticSequence:
    """One clip of the set, read as the evaluation reads a benchmark sequence.

    Attributes:
        clip: the whole clip with its 3D truth (small: a few frames).
        told_exposure: whether the method is told the clip's exposure fraction (the first set);
            else it starts from the config's and must find it (the harder set).
    """

    dataset: str
    name: str
    folder: Path
    num_subframes: int
    num_frames: int
    clip: SyntheticClip
    told_exposure: bool = True
    shaken: bool = False

    def frames(self) -> Iterator[BenchmarkFrame]:
        """The frames in which the object is seen, with the truth the benchmark would hand over.

        ``shaken``: the clip as a handheld camera films it (:func:`shaken_frames`), registered
        to its first frame as the pipeline registers a moving camera; the truth stays in the
        first frame's (the still clip's) coordinates, where the frames are then fitted.
        """
        background = self.clip.scene.background.astype(np.float64) / 255
        images = shaken_frames(self.clip) if self.shaken else self.clip.frames
        for truth, frame in zip(self.clip.truth, images, strict=True):
            if truth.bbox is None or frame is None:
                continue
            yield BenchmarkFrame(
                sequence=self.name,
                index=truth.index,
                image=frame.astype(np.float64) / 255,
                background=background,
                subframes=truth.subframes.astype(np.float64) / 255,
                centres=truth.centres,
                radius=round(truth.radius_px),
                box=truth.bbox,
            )


def shaken_frames(clip: SyntheticClip) -> list[np.ndarray | None]:
    """``clip``'s frames shaken by a hand (up to 6 px and 1 degree a frame, seeded by the clip;
    the first frame held still), then registered to the first and brought into its coordinates
    (:mod:`sfb_video.registration`), the pixels a frame does not cover taken from the clip's
    background. None for a frame that did not register (it is not fitted, and scores 0)."""
    size = (clip.spec.width, clip.spec.height)
    moves = from_first(shake_transforms(len(clip.frames), size, clip.spec.seed, max_shift_px=6.0, max_turn_deg=1.0))
    tensors = [torch.from_numpy(np.ascontiguousarray(f)).permute(2, 0, 1) for f in shake_frames(clip.frames, moves)]
    motion = register_frames(enumerate(tensors), CameraConfig())
    background = torch.from_numpy(np.ascontiguousarray(clip.scene.background)).permute(2, 0, 1)
    canvas = motion.canvas
    assert canvas is not None
    frames = registered((Frame(k, t) for k, t in enumerate(tensors)), motion)
    paired = fixed_background(frames, *onto_canvas(background, motion))
    # Scored against the still truth: the first frame's view, cut from the canvas.
    view = (slice(None), slice(canvas.top, canvas.top + size[1]), slice(canvas.left, canvas.left + size[0]))
    return [f.pixels[view].permute(1, 2, 0).numpy() if usable(f) else None for f in paired]


def list_synthetic(root: Path | str, dataset: str = "synthetic", shaken: bool = False) -> list[SyntheticSequence]:
    """The clips of a set folder, in name order, named as sequences of ``dataset`` (``shaken``:
    as a handheld camera films them, :func:`shaken_frames`)."""
    root = Path(root)
    if not (root / SET_FILE).is_file():
        raise SfbError(f"{root} holds no synthetic set ({SET_FILE} is missing)")
    names = sorted(json.loads((root / SET_FILE).read_text()))
    sequences = []
    for name in names:
        clip = load_clip(root / name)
        sequences.append(
            SyntheticSequence(
                dataset,
                name,
                root / name,
                clip.spec.num_subframes,
                clip.spec.num_frames,
                clip,
                dataset == "synthetic",
                shaken,
            )
        )
    return sequences
