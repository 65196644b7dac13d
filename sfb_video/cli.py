"""The ``sfb-video`` command line: a preset plus dotted overrides, one subcommand per job.

Errors a user can act on (bad input, bad config, unwritable output) print one line and exit
with status 2; a clip in which no moving object is found exits with 3 (its outputs are still
written); Ctrl-C exits with 130 and leaves no half-written output.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from sfb_video import __version__
from sfb_video.checks import SfbError
from sfb_video.config import load_config, save_config

if TYPE_CHECKING:
    from sfb_video.config import Config
    from stages.masks import MaskSource

NOTHING_FOUND = 3
"""Exit status of a run that finished but found no moving object in any frame."""


def resolve_device(name: str) -> torch.device:
    """``auto`` picks CUDA when present, else the CPU; an unavailable device is an error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise SfbError(f"device {name!r} requested but CUDA is not available; use --device cpu")
    try:
        return torch.device(name)
    except RuntimeError:
        raise SfbError(f"unknown device {name!r}; use auto, cpu or cuda") from None


class OutputFolder:
    """A run folder written in a hidden sibling and moved into place only when complete."""

    def __init__(self, path: Path, overwrite: bool) -> None:
        # Checked up front, so a long job does not end in an error it could have shown first.
        self.path = path
        if path.exists() and not overwrite:
            raise SfbError(f"output folder {path} already exists; pass --overwrite to replace it")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SfbError(f"cannot write to output folder {path}: {exc.strerror}") from None
        if not os.access(path.parent, os.W_OK):
            raise SfbError(f"cannot write to output folder {path}: permission denied")

    def __enter__(self) -> Path:
        self.tmp = Path(tempfile.mkdtemp(dir=self.path.parent, prefix=f".{self.path.name}.partial-"))
        return self.tmp

    def __exit__(self, exc_type: object, exc: object, tb: object) -> None:
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return
        if self.path.exists():
            old = self.path.with_name(f".{self.path.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            self.path.rename(old)
            self.tmp.rename(self.path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            self.tmp.rename(self.path)


def cmd_demo(args: argparse.Namespace) -> int:
    from sfb_video.demo import demo_clip, demo_config, score_run, score_table, write_clip_video
    from stages.process import ProcessOptions, process_clip

    config = demo_config(load_config(args.config, args.set))
    device = resolve_device(args.device)
    out = Path(args.out)
    video = out.with_name(f"{out.name}-clip.mp4")
    if not args.quiet:
        print(f"generating a {config.demo.frames}-frame clip of a {config.demo.shape} -> {video}")
    clip = demo_clip(config)
    try:
        write_clip_video(clip, video)
    except OSError as exc:
        raise SfbError(f"cannot write the demo clip {video}: {exc}") from None
    options = ProcessOptions(
        video=video, out=out, overwrite=args.overwrite, masks=args.masks, defmo_weights=_defmo_weights(args)
    )
    summary = process_clip(options, config, device, quiet=args.quiet)
    if not args.quiet:
        _print_summary(out, summary)
        print("\naccuracy against the generated ground truth (TSR sub-frames, FMO benchmark measures):\n")
        print(score_table(score_run(out, clip, config)))
    return 0


def _defmo_weights(args: argparse.Namespace) -> Path | None:
    return None if args.defmo_weights is None else Path(args.defmo_weights)


def _mask_source(args: argparse.Namespace, config: Config, device: torch.device) -> MaskSource:
    from stages.masks import choose_masks, print_line

    return choose_masks(args.masks, _defmo_weights(args), config.crop, device, log=None if args.quiet else print_line)


def _parse_box(text: str | None) -> tuple[int, int, int, int] | None:
    if text is None:
        return None
    try:
        x, y, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise SfbError(f"--box must be x,y,width,height in pixels, got {text!r}") from None
    return x, y, w, h


def cmd_fit(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from sfb_video.crop import find_object_box, make_crop
    from sfb_video.export import write_fit
    from sfb_video.fitter import NoObjectError, fit_frame
    from sfb_video.geometry.camera import PinholeCamera
    from sfb_video.imageio import read_image
    from stages.background import FrameWithBackground

    config = load_config(args.config, args.set)
    device = resolve_device(args.device)
    image, background = read_image(args.image), read_image(args.background)
    if image.shape != background.shape:
        raise SfbError(f"image {args.image} and background {args.background} differ in size")
    camera = PinholeCamera.from_fov(image.shape[2], image.shape[1], config.camera.fov_y_deg)
    box = _parse_box(args.box) or find_object_box(image, background, config.crop.detect_threshold)
    if box is None:
        raise NoObjectError(f"no object: {args.image} does not differ from its background")
    frame = FrameWithBackground(0, image.to(device), background.to(device))
    crop = make_crop(frame.image, frame.background, box, camera, config.crop)
    out = Path(args.out or f"runs/{Path(args.image).stem}")
    folder = OutputFolder(out, args.overwrite)
    masks = _mask_source(args, config, device).masks(frame, box, crop, config.render.time_steps)
    steps = config.fit.iterations * len(config.fit.prototypes)
    # disable=None: no bar when stderr is not a terminal (logs, CI).
    with tqdm(total=steps, desc="fit", unit="step", disable=True if args.quiet else None, leave=False) as bar:

        def on_step(step: int, losses: dict[str, float]) -> None:
            bar.update(1)
            bar.set_postfix(L_I=f"{losses['image']:.4f}")

        fit = fit_frame(crop, config.fit, config.render, masks=masks, on_step=on_step)
    with folder as tmp:
        write_fit(tmp, fit, crop, args.tsr, config.render, masks)
        save_config(tmp / "config.yaml", config)
    if not args.quiet:
        print(
            f"wrote {out}/: prototype {fit.prototype}, L_I {fit.losses['image']:.4f}, "
            f"{fit.iterations} steps in {fit.seconds:.1f} s; mesh.glb, tsr.png, reconstruction.png, "
            f"{'masks.png, ' if masks is not None else ''}fit.json"
        )
    return 0


def _parse_frames(text: str | None) -> range | None:
    if text is None:
        return None
    start, sep, stop = text.partition(":")
    try:
        frames = range(int(start or 0), int(stop)) if sep else range(int(start), int(start) + 1)
    except ValueError:
        raise SfbError(f"--frames must be START:STOP (frame indices, STOP excluded), got {text!r}") from None
    if frames.start < 0 or len(frames) == 0:
        raise SfbError(f"--frames {text!r} selects no frames")
    return frames


def _print_summary(out: Path, summary: dict) -> None:
    print(
        f"wrote {out}/: {summary['frames_fitted']} of {summary['frames_read']} frames fitted "
        f"({summary['cold_starts']} cold, {summary['warm_starts']} warm), "
        f"{summary['frames_without_object']} without the object"
    )
    rows = [f for f in summary["frames"] if f["status"] == "fitted"]
    if rows:
        print("| frame | start | prototype | L_I | s | speed (sizes/s) |")
        print("|---:|---|---|---:|---:|---:|")
        for f in rows:
            print(
                f"| {f['index']} | {f['start']} | {f['prototype']} | {f['losses']['image']:.4f} | "
                f"{f['seconds']:.1f} | {f['speed_sizes_per_s']:.1f} |"
            )
    print("tsr.mp4, trajectory.csv, meshes/, recording.rrd (sfb-video replay), summary.json")


def cmd_process(args: argparse.Namespace) -> int:
    from stages.process import ProcessOptions, process_clip

    overrides = list(args.set) + ([f"video.tsr={args.tsr}"] if args.tsr is not None else [])
    config = load_config(args.config, overrides)
    video = Path(args.video)
    options = ProcessOptions(
        video=video,
        out=Path(args.out or f"runs/{video.stem}"),
        frames=_parse_frames(args.frames),
        background=None if args.background is None else Path(args.background),
        focal_px=args.focal_px,
        object_diameter=args.object_diameter,
        overwrite=args.overwrite,
        masks=args.masks,
        defmo_weights=_defmo_weights(args),
    )
    if not video.is_file():
        raise SfbError(f"video not found: {video}")
    summary = process_clip(options, config, resolve_device(args.device), quiet=args.quiet)
    if not args.quiet:
        _print_summary(options.out, summary)
    if summary["frames_fitted"] == 0:
        if not args.quiet:
            print(f"no moving object found in any of the {summary['frames_read']} frames")
        return NOTHING_FOUND
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from stages.process import export_run

    folder = Path(args.run)
    if not (folder / "config.yaml").is_file():
        raise SfbError(f"{folder} is not an sfb-video run folder (no config.yaml)")
    config = load_config(folder / "config.yaml", args.set)
    tsr = args.tsr if args.tsr is not None else config.video.tsr
    summary = export_run(folder, config, tsr)
    if args.novel_views is not None:
        from stages.novel_views import write_novel_views

        write_novel_views(folder, config, args.novel_views, args.views)
    if not args.quiet:
        _print_summary(folder, summary)
    return 0


def _eval_sequences(args: argparse.Namespace) -> list:
    from sfb_video.evaluation.datasets import list_sequences
    from sfb_video.evaluation.synthetic_set import ensure_set, list_synthetic

    root = Path(args.root)
    if args.dataset == "synthetic":
        ensure_set(root, quiet=args.quiet)
        sequences = list_synthetic(root)
    else:
        sequences = list_sequences(root, args.dataset)
    if args.sequence:
        known = {s.name for s in sequences}
        unknown = [name for name in args.sequence if name not in known]
        if unknown:
            raise SfbError(f"no sequence {unknown[0]!r} in {root}; there are: {', '.join(sorted(known))}")
        sequences = [s for s in sequences if s.name in args.sequence]
    return sequences


def cmd_eval(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from sfb_video.evaluation.runner import MODES, run_sequence
    from sfb_video.evaluation.tables import markdown, summarise, write_tables

    config = load_config(args.config, args.set)
    device = resolve_device(args.device)
    if args.max_frames is not None and args.max_frames < 1:
        raise SfbError(f"--max-frames must be at least 1, got {args.max_frames}")
    sequences = _eval_sequences(args)
    masks = _mask_source(args, config, device)
    modes = MODES if args.mode == "both" else (args.mode,)
    out = Path(args.out or f"runs/eval-{args.dataset}")
    _fresh_folder(out, args.overwrite)
    save_config(out / "config.yaml", config)
    runs = [(s, m) for s in sequences for m in modes]
    frames = sum(min(s.num_frames, args.max_frames or s.num_frames) for s, _ in runs)
    rows = []
    # disable=None: no bar when stderr is not a terminal (logs, CI).
    with tqdm(total=frames, desc="eval", unit="frame", disable=True if args.quiet else None) as bar:
        for done, (sequence, mode) in enumerate(runs, start=1):
            bar.set_postfix(sequence=sequence.name, mode=mode)
            rows += run_sequence(
                sequence, config, mode, device, args.max_frames, on_frame=lambda _: bar.update(1), masks=masks
            )
            # Tables after every sequence: an interrupted evaluation keeps what it finished, marked.
            note = "" if done == len(runs) else f"Incomplete: {done} of {len(runs)} sequence runs finished.\n\n"
            write_tables(out, rows, f"{note}Sub-frame masks: {masks.name} ({masks.reason}).\n\n")
    if not args.quiet:
        print(markdown(summarise(rows)))
        print(f"wrote {out}/: table.md, sequences.csv, frames.csv, config.yaml")
    return 0


def _fresh_folder(path: Path, overwrite: bool) -> None:
    """Create ``path`` for outputs written file by file; an existing one only with ``overwrite``."""
    if path.exists() and any(path.iterdir()) and not overwrite:
        raise SfbError(f"output folder {path} already exists; pass --overwrite to replace it")
    try:
        if path.exists():
            shutil.rmtree(path)
        path.mkdir(parents=True)
    except OSError as exc:
        raise SfbError(f"cannot write to output folder {path}: {exc.strerror}") from None


def cmd_replay(args: argparse.Namespace) -> int:
    import subprocess

    path = Path(args.run)
    path = path / "recording.rrd" if path.is_dir() else path
    if not path.is_file():
        raise SfbError(f"no recording at {path}; run sfb-video process first")
    viewer = shutil.which("rerun")
    if viewer is None:
        raise SfbError("the rerun viewer is not on PATH; install rerun-sdk into this environment")
    return subprocess.call([viewer, str(path)])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sfb-video", description="Shape from Blur for videos of fast moving objects.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--config", default="default", help="preset name in configs/ or a YAML path")
    common.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config field")
    common.add_argument("--device", default="auto", help="auto (CUDA if present), cpu or cuda")
    common.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    common.add_argument("--quiet", action="store_true", help="print nothing on success")
    common.add_argument(
        "--masks",
        choices=["auto", "defmo", "diff"],
        default="auto",
        help="sub-frame masks for the fit: DeFMO's (L_S; defmo downloads its weights if missing), "
        "the difference image (L_D), or auto: DeFMO when its weights are here, else diff",
    )
    common.add_argument(
        "--defmo-weights", metavar="FOLDER", help="folder with DeFMO's encoder_best.pt, rendering_best.pt"
    )
    demo = sub.add_parser("demo", parents=[common], help="generate a short clip with ground truth and process it")
    demo.add_argument("--out", default="runs/demo", help="output folder")
    demo.set_defaults(func=cmd_demo)
    fit = sub.add_parser("fit", parents=[common], help="recover the shape and motion in one blurred image")
    fit.add_argument("--image", required=True, help="the blurred frame")
    fit.add_argument("--background", required=True, help="the same view without the object")
    fit.add_argument("--box", help="object box x,y,width,height (default: the largest blob of |I - B|)")
    fit.add_argument("--tsr", type=int, default=8, help="sub-frames to render for temporal super-resolution")
    fit.add_argument("--out", help="output folder (default: runs/<image name>)")
    fit.set_defaults(func=cmd_fit)
    process = sub.add_parser("process", parents=[common], help="recover shape and motion in every frame of a clip")
    process.add_argument("video", help="the clip (any format FFmpeg reads)")
    process.add_argument("--out", help="run folder (default: runs/<clip name>)")
    process.add_argument("--tsr", type=int, help="sub-frames per frame in tsr.mp4 (default: video.tsr, 8)")
    process.add_argument("--frames", help="only frames START:STOP (STOP excluded), e.g. 10:40")
    process.add_argument("--background", help="a background image instead of the running median")
    process.add_argument("--object-diameter", type=float, help="the object's diameter in metres, for metric output")
    process.add_argument("--focal-px", type=float, help="focal length in pixels (default: from camera.fov_y_deg)")
    process.set_defaults(func=cmd_process)
    base = argparse.ArgumentParser(add_help=False)
    base.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config field")
    base.add_argument("--quiet", action="store_true", help="print nothing on success")
    export = sub.add_parser("export", parents=[base], help="re-render the outputs of a run without fitting again")
    export.add_argument("run", help="a run folder written by sfb-video process")
    export.add_argument("--tsr", type=int, help="sub-frames per frame in tsr.mp4")
    export.add_argument(
        "--novel-views", nargs="*", type=int, metavar="FRAME", help="turntables of these frames' meshes (default: best)"
    )
    export.add_argument("--views", type=int, default=36, help="turntable views per frame")
    export.set_defaults(func=cmd_export)
    evaluate = sub.add_parser("eval", parents=[common], help="score the method on a benchmark dataset")
    evaluate.add_argument("--dataset", required=True, choices=["tbd", "tbd3d", "falling", "synthetic"])
    evaluate.add_argument(
        "--root", required=True, help="the dataset's folder (synthetic: generated there on first use)"
    )
    evaluate.add_argument("--out", help="output folder (default: runs/eval-<dataset>)")
    evaluate.add_argument("--mode", choices=["per-frame", "video", "both"], default="both")
    evaluate.add_argument("--sequence", action="append", help="only this sequence (repeatable)")
    evaluate.add_argument("--max-frames", type=int, help="only the first N frames of each sequence")
    evaluate.set_defaults(func=cmd_eval)
    replay = sub.add_parser("replay", help="open a run's recording in the rerun viewer")
    replay.add_argument("run", help="a run folder or a .rrd file")
    replay.set_defaults(func=cmd_replay)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except SfbError as exc:
        print(f"sfb-video: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if args.command == "process":
            note = "frames finished so far are kept; run the same command again to resume"
        elif args.command == "eval":
            note = "the tables hold the sequences finished so far, marked incomplete"
        else:
            note = "no partial output was left"
        print(f"sfb-video: interrupted; {note}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
