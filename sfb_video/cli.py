"""The ``sfb-video`` command line: a preset plus dotted overrides, one subcommand per job.

Errors a user can act on (bad input, bad config, unwritable output) print one line and exit
with status 2; Ctrl-C exits with 130 and leaves no half-written output.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import torch
import yaml

from sfb_video import __version__
from sfb_video.checks import SfbError
from sfb_video.config import Config, config_to_dict, load_config
from sfb_video.imageio import atomic_write_bytes, write_image


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


def write_config(path: Path, config: Config) -> None:
    """Save the resolved config beside a run's outputs, so the run can be replayed."""
    atomic_write_bytes(path, yaml.safe_dump(config_to_dict(config), sort_keys=False).encode())


def cmd_demo(args: argparse.Namespace) -> int:
    from sfb_video.demo import run_demo

    config = load_config(args.config, args.set)
    result = run_demo(config, resolve_device(args.device))
    with OutputFolder(Path(args.out), args.overwrite) as folder:
        write_image(folder / "blurred.png", result.blurred)
        write_image(folder / "background.png", result.background)
        write_image(folder / "subframes.png", torch.cat(list(result.subframes), dim=2))
        write_config(folder / "config.yaml", config)
    if not args.quiet:
        print(
            f"wrote {args.out}/: blurred.png (one exposure), subframes.png ({len(result.subframes)} sharp sub-frames)"
        )
    return 0


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

    config = load_config(args.config, args.set)
    device = resolve_device(args.device)
    image, background = read_image(args.image), read_image(args.background)
    if image.shape != background.shape:
        raise SfbError(f"image {args.image} and background {args.background} differ in size")
    camera = PinholeCamera.from_fov(image.shape[2], image.shape[1], config.camera.fov_y_deg)
    box = _parse_box(args.box) or find_object_box(image, background, config.crop.detect_threshold)
    if box is None:
        raise NoObjectError(f"no object: {args.image} does not differ from its background")
    crop = make_crop(image.to(device), background.to(device), box, camera, config.crop)
    out = Path(args.out or f"runs/{Path(args.image).stem}")
    folder = OutputFolder(out, args.overwrite)
    steps = config.fit.iterations * len(config.fit.prototypes)
    # disable=None: no bar when stderr is not a terminal (logs, CI).
    with tqdm(total=steps, desc="fit", unit="step", disable=True if args.quiet else None, leave=False) as bar:

        def on_step(step: int, losses: dict[str, float]) -> None:
            bar.update(1)
            bar.set_postfix(L_I=f"{losses['image']:.4f}")

        fit = fit_frame(crop, config.fit, config.render, on_step=on_step)
    with folder as tmp:
        write_fit(tmp, fit, crop, args.tsr, config.render)
        write_config(tmp / "config.yaml", config)
    if not args.quiet:
        print(
            f"wrote {out}/: prototype {fit.prototype}, L_I {fit.losses['image']:.4f}, "
            f"{fit.iterations} steps in {fit.seconds:.1f} s; mesh.glb, tsr.png, reconstruction.png, fit.json"
        )
    return 0


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
    demo = sub.add_parser("demo", parents=[common], help="render a prototype tumbling through one exposure")
    demo.add_argument("--out", default="runs/demo", help="output folder")
    demo.set_defaults(func=cmd_demo)
    fit = sub.add_parser("fit", parents=[common], help="recover the shape and motion in one blurred image")
    fit.add_argument("--image", required=True, help="the blurred frame")
    fit.add_argument("--background", required=True, help="the same view without the object")
    fit.add_argument("--box", help="object box x,y,width,height (default: the largest blob of |I - B|)")
    fit.add_argument("--tsr", type=int, default=8, help="sub-frames to render for temporal super-resolution")
    fit.add_argument("--out", help="output folder (default: runs/<image name>)")
    fit.set_defaults(func=cmd_fit)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except SfbError as exc:
        print(f"sfb-video: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sfb-video: interrupted; no partial output was left", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
