"""The ``sfb-video`` command line: a preset plus dotted overrides, one subcommand per job.

Errors a user can act on (bad input, bad options or config) print one line and exit with
status 2; a clip in which no moving object is found exits with 3 (its outputs are still
written); outputs that cannot be written (a full disk, a folder removed or made read-only
mid-run) exit with 4, keeping what can be resumed; Ctrl-C exits with 130. No command leaves a
half-written output that looks complete (:mod:`sfb_video.run_folder`).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from sfb_video import __version__
from sfb_video.config import load_config, save_config
from sfb_video.devices import resolve_device
from sfb_video.errors import ConfigError, OutputError, SfbError, printable
from sfb_video.interrupts import kernel_call, sigint_outside_kernels
from sfb_video.run_folder import CONFIG, open_export, open_run
from sfb_video.stages.read import parse_frames

if TYPE_CHECKING:
    from sfb_video.config import Config
    from sfb_video.stages.masks import MaskSource
    from sfb_video.stages.process import ClipOptions

BAD_INPUT = 2
"""Exit status of bad input, options or config (one line on stderr)."""
NOTHING_FOUND = 3
"""Exit status of a run that finished but found no moving object in any frame."""
OUTPUT_FAILED = 4
"""Exit status of a run whose outputs could not be written (full disk, folder gone, no permission)."""
CLIPS_FAILED = 5
"""Exit status of a batch in which at least one clip failed (the others finished; see batch.csv)."""
INTERRUPTED = 130


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors: ``sfb-video process: error: argument --tsr: ... (see --help)``."""

    def error(self, message: str) -> typing.NoReturn:
        print(f"{self.prog}: error: {message} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(BAD_INPUT)


def at_least(low: float, kind: type = int) -> typing.Callable[[str], float]:
    """An argparse type: a number of ``kind`` no smaller than ``low`` (one check, every flag)."""

    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid {kind.__name__} value: {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be at least {low}, got {text}")
        return value

    return parse


def frame_selection(text: str) -> str:
    """An argparse type: a ``--frames`` selection, checked here and resolved against the clip."""
    try:
        parse_frames(text)
    except SfbError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def clip_options(args: argparse.Namespace) -> ClipOptions:
    """The per-clip options of ``process`` and ``batch`` (:func:`clip_arguments`)."""
    from sfb_video.stages.process import ClipOptions

    return ClipOptions(
        frames=args.frames,
        background=None if args.background is None else Path(args.background).absolute(),
        focal_px=args.focal_px,
        object_diameter=args.object_diameter,
        overwrite=args.overwrite,
        masks=args.masks,
        # Absolute, as the background: a Ray worker does not start in this process's folder.
        defmo_weights=None if args.defmo_weights is None else Path(args.defmo_weights).absolute(),
    )


STABILISED = "a moving camera's tsr.mp4 in its reference frame's coordinates (held still), not each frame's own"


def clip_arguments() -> argparse.ArgumentParser:
    """The argparse parent of the per-clip flags, shared by ``process`` and ``batch``."""
    clip = argparse.ArgumentParser(add_help=False)
    clip.add_argument("--tsr", type=at_least(1), help="sub-frames per frame in tsr.mp4 (default: video.tsr, 8)")
    clip.add_argument(
        "--frames",
        type=frame_selection,
        help="only frames START:STOP (STOP excluded; negative counts from the end), e.g. 10:40, -30:",
    )
    clip.add_argument("--background", help="a background image instead of the running median")
    clip.add_argument("--object-diameter", type=float, help="the object's diameter in metres, for metric output")
    clip.add_argument("--focal-px", type=float, help="focal length in pixels (default: from camera.fov_y_deg)")
    clip.add_argument("--stabilised", action="store_true", help=STABILISED)
    clip.add_argument(
        "--max-objects",
        type=at_least(0),
        help="track at most N objects at once, 0: every fast mover (default: video.max_objects, 0)",
    )
    return clip


def cmd_demo(args: argparse.Namespace) -> int:
    from sfb_video.demo import demo_clip, demo_config, score_run, score_table, write_clip_video
    from sfb_video.stages.process import ProcessOptions, process_clip

    config = demo_config(load_config(args.config, args.set))
    device = resolve_device(args.device)
    out = Path(args.out)
    video = out.with_name(f"{out.name}-clip.mp4")
    if not args.quiet:
        print(f"generating a {config.demo.frames}-frame clip of a {config.demo.shape} -> {video}")
    clip = demo_clip(config)
    try:
        video.parent.mkdir(parents=True, exist_ok=True)
        write_clip_video(clip, video)
    except (OSError, SfbError) as exc:
        raise SfbError(f"cannot write the demo clip: {getattr(exc, 'strerror', None) or exc}") from None
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
    from sfb_video.stages.masks import choose_masks, print_line

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
    from sfb_video.errors import NoObjectError
    from sfb_video.fitting.frame import fit_frame, planned_steps
    from sfb_video.geometry.camera import PinholeCamera
    from sfb_video.imageio import read_image
    from sfb_video.mesh_files import write_fit
    from sfb_video.stages.background import FrameWithBackground

    config = load_config(args.config, args.set)
    device = resolve_device(args.device)
    image, background = read_image(args.image), read_image(args.background)
    if image.shape != background.shape:
        raise SfbError(f"image {args.image} and background {args.background} differ in size")
    camera = PinholeCamera.from_fov(image.shape[2], image.shape[1], config.camera.fov_y_deg)
    box = _parse_box(args.box) or find_object_box(image, background, config.crop.region_threshold)
    if box is None:
        raise NoObjectError(f"no object: {args.image} does not differ from its background")
    frame = FrameWithBackground(0, image.to(device), background.to(device))
    crop = make_crop(frame.image, frame.background, box, camera, config.crop)
    out = Path(args.out or f"runs/{Path(args.image).stem}")
    inputs = {"image": str(Path(args.image).resolve()), "background": str(Path(args.background).resolve())}
    with open_run(out, "fit", inputs | {"box": list(box), "tsr": args.tsr}, overwrite=args.overwrite) as run:
        masks = _mask_source(args, config, device).masks(frame, box, crop, config.render.time_steps)
        steps = planned_steps(config.fit, len(config.fit.prototypes))
        # disable=None: no bar when stderr is not a terminal (logs, CI).
        with tqdm(total=steps, desc="fit", unit="step", disable=True if args.quiet else None, leave=False) as bar:

            def on_step(step: int, losses: dict[str, float]) -> None:
                bar.update(1)
                bar.set_postfix(L_I=f"{losses['image']:.4f}")

            fit = fit_frame(crop, config.fit, config.render, masks=masks, on_step=on_step)
        write_fit(run.work, fit, crop, args.tsr, config.render, masks)
        save_config(run.work / CONFIG, config)
        run.finish()
    if not args.quiet:
        print(
            f"wrote {printable(str(out))}/: prototype {fit.prototype}, L_I {fit.losses['image']:.4f}, "
            f"{fit.iterations} steps in {fit.seconds:.1f} s; mesh.glb, tsr.png, reconstruction.png, "
            f"{'masks.png, ' if masks is not None else ''}fit.json"
        )
    return 0


def _print_summary(out: Path, summary: dict) -> None:
    print(
        f"wrote {printable(str(out))}/: {summary['frames_fitted']} of {summary['frames_read']} frames fitted "
        f"({summary['cold_starts']} cold, {summary['warm_starts']} warm), "
        f"{summary['frames_without_object']} without the object"
    )
    rows = [f for f in summary["frames"] if f["status"] == "fitted"]
    if rows:
        print("| track | frame | start | prototype | L_I | explained | s | speed (sizes/s) |")
        print("|---:|---:|---|---|---:|---:|---:|---:|")
        for f in sorted(rows, key=lambda f: (f["track"], f["index"])):
            print(
                f"| {f['track']} | {f['index']} | {f['start']} | {f['prototype']} | {f['losses']['image']:.4f} | "
                f"{f['explained']:.2f} | {f['seconds']:.1f} | {f['speed_sizes_per_s']:.1f} |"
            )
    others = summary["frames_with_other_movers"]
    if others:
        print(
            f"note: {others} frame(s) showed more moving objects than video.max_objects (--max-objects) "
            "lets be tracked; see the frames' notes in summary.json"
        )
    unexplained = summary["unexplained_frames"]
    if unexplained:
        shown = ", ".join(str(i) for i in unexplained[:12]) + (", ..." if len(unexplained) > 12 else "")
        print(
            f"warning: {len(unexplained)} frame(s) look unexplained (the fit explains less than "
            f"{summary['min_explained']:.0%} of the frame's difference around the object): {shown}; "
            "look at them in recording.rrd"
        )
    print("tsr.mp4, trajectory.csv, meshes/, recording.rrd (sfb-video replay), summary.json")


def _process_config(args: argparse.Namespace) -> Config:
    """The config of ``process`` and ``batch``: the preset, ``--set`` and ``--tsr``."""
    overrides = list(args.set) + ([f"video.tsr={args.tsr}"] if args.tsr is not None else [])
    overrides += [f"video.max_objects={args.max_objects}"] if args.max_objects is not None else []
    return load_config(args.config, overrides + (["camera.stabilised=true"] if args.stabilised else []))


def cmd_process(args: argparse.Namespace) -> int:
    from sfb_video.stages.process import process_clip

    config = _process_config(args)
    video = Path(args.video)
    options = clip_options(args).for_clip(video, Path(args.out or f"runs/{video.stem}"))
    summary = process_clip(options, config, resolve_device(args.device), quiet=args.quiet)
    if not args.quiet:
        _print_summary(options.out, summary)
    if summary["frames_fitted"] == 0:
        if not args.quiet:
            print(f"no moving object found in any of the {summary['frames_read']} frames")
        return NOTHING_FOUND
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from sfb_video import batch
    from sfb_video.cluster import INSTALL, Resources, ray_installed
    from sfb_video.stages.read import probe

    config = _process_config(args)
    clips, notes = batch.gather_clips(args.inputs)
    if not clips:
        raise SfbError("no clips to process: " + "; ".join(notes))
    use_ray = ray_installed()
    if args.ray_address is not None and not use_ray:
        raise SfbError(f"--ray-address needs Ray, which is not installed; {INSTALL}")
    local = args.ray_address is None
    if use_ray and local and args.gpus_per_clip > 0 and not torch.cuda.is_available():
        raise SfbError("--gpus-per-clip: torch sees no GPU on this machine, so a local Ray could run no clip")
    say = (lambda line: None) if args.quiet else (lambda line: print(line, file=sys.stderr))
    for note in notes:
        say(f"note: {note}")
    if not use_ray:
        say(f"note: Ray is not installed: the {len(clips)} clip(s) run one after another here; {INSTALL} to go wider")
    out = Path(args.out)
    cpus = args.cpus_per_clip or (1 if use_ray else torch.get_num_threads())
    plan = batch.BatchPlan(
        jobs=batch.plan_jobs(clips, out),
        options=clip_options(args),
        config=config,
        device=args.device,
        out=out,
        resources=Resources(cpus, args.gpus_per_clip),
        max_retries=args.max_retries,
        ray_address=None if args.ray_address == "local" else args.ray_address,
        use_ray=use_ray,
    )
    total_frames = None
    if args.frames is None:
        counts = []
        for job in plan.jobs:
            try:
                counts.append(probe(job.video, config.video).frame_count)
            except (SfbError, OSError):
                counts.append(0)
        total_frames = None if None in counts else sum(counts)
    hide = True if args.quiet else None  # None: no bars when stderr is not a terminal (logs, CI)
    with (
        tqdm(total=len(plan.jobs), desc="clips", unit="clip", disable=hide, position=0) as clips_bar,
        tqdm(total=total_frames, desc="frames", unit="frame", disable=hide, position=1) as frames_bar,
    ):

        def on_row(_: int, row: batch.ClipRow) -> None:
            clips_bar.update(1)

        def on_frames(done: int) -> None:
            frames_bar.update(done - frames_bar.n)

        def on_retry(job: batch.ClipJob, why: str) -> None:
            clips_bar.write(f"{printable(job.name)}: its worker died ({why}); starting it again")

        rows = batch.run_batch(plan, on_row, on_frames, on_retry)
    failed = [r for r in rows if r.status == batch.FAILED]
    if not args.quiet:
        print(batch.table(rows))
        empty = sum(r.status == batch.NO_OBJECT for r in rows)
        print(
            f"wrote {printable(str(out))}/: one run folder per clip, batch.csv, batch.json; "
            f"{len(rows) - len(failed) - empty} done, {empty} without a moving object, {len(failed)} failed"
        )
    for row in failed:
        print(f"sfb-video: error: {printable(row.clip)}: {row.error}", file=sys.stderr)
    return CLIPS_FAILED if failed else 0


def cmd_export(args: argparse.Namespace) -> int:
    from sfb_video.run_folder import saved_frames
    from sfb_video.stages.novel_views import write_novel_views
    from sfb_video.stages.process import export_run

    with open_export(Path(args.run)) as run:
        try:
            load_config(run.work / CONFIG)
        except ConfigError as exc:
            # A run folder made by another version: a key since deleted (video.background_tolerance).
            where = printable(str(run.path / CONFIG))
            raise ConfigError(f"{where}: {exc}; made by another version of sfb-video? process the clip again") from None
        config = load_config(run.work / CONFIG, args.set + (["camera.stabilised=true"] if args.stabilised else []))
        fitted = {index for index, _ in saved_frames(run.work)}
        missing = [f for f in args.novel_views or [] if f not in fitted]
        if missing:
            raise SfbError(f"frame {missing[0]} was not fitted; fitted frames: {sorted(fitted)}")
        summary = export_run(run.work, config, args.tsr if args.tsr is not None else config.video.tsr)
        if args.novel_views is not None:
            write_novel_views(run.work, config, args.novel_views, args.views)
        run.finish()
    if not args.quiet:
        _print_summary(run.path, summary)
    return 0


def _eval_sequences(args: argparse.Namespace) -> list:
    from sfb_video.evaluation.datasets import list_sequences
    from sfb_video.evaluation.synthetic_set import SETS, ensure_set, list_synthetic

    root = Path(args.root)
    if args.shaken and args.dataset not in SETS:
        raise SfbError(f"--shaken is for the generated sets ({', '.join(SETS)}), not {args.dataset}")
    if args.dataset in SETS:
        ensure_set(root, SETS[args.dataset](), quiet=args.quiet)
        sequences = list_synthetic(root, args.dataset, args.shaken)
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

    from sfb_video.evaluation.montage import Montages
    from sfb_video.evaluation.runner import MODES, baseline_rows, run_sequence
    from sfb_video.evaluation.tables import TABLE, markdown, summarise, write_tables

    config = load_config(args.config, args.set)
    device = resolve_device(args.device)
    modes = MODES if args.mode == "all" else (args.mode,)
    out = Path(args.out or f"runs/eval-{args.dataset}")
    record = {
        "dataset": args.dataset,
        "root": str(Path(args.root).resolve()),
        "modes": ["video", *modes] if modes == ("joint",) else list(modes),
        "sequences": args.sequence,
        "max_frames": args.max_frames,
        "shaken": args.shaken,
    }
    rows = []
    # An interrupted evaluation in a new folder keeps the tables it finished, marked incomplete.
    with open_run(out, "eval", record, overwrite=args.overwrite, keep=lambda f: (f / TABLE).is_file()) as run:
        sequences = _eval_sequences(args)
        masks = _mask_source(args, config, device)
        # The benchmark's baselines, to read every sequence's score against (no fitting).
        rows = [row for s in sequences for row in baseline_rows(s, args.max_frames)]
        # The joint mode's seeds are the video mode's fits: one run scores both.
        both = "joint" in modes
        runs = [(s, m) for s in sequences for m in modes if not (both and m == "video")]
        frames = sum(
            min(s.num_frames, args.max_frames or s.num_frames) * (2 if both and m == "joint" else 1) for s, m in runs
        )
        save_config(run.work / CONFIG, config)
        note = f"Sub-frame masks: {masks.name} ({masks.reason}).\n\n"
        # disable=None: no bar when stderr is not a terminal (logs, CI).
        with tqdm(total=frames, desc="eval", unit="frame", disable=True if args.quiet else None) as bar:
            if args.ray_address is not None:
                fitted, errors = _eval_on_ray(args, config, runs, both, bar)
                rows += fitted
                if errors:
                    left = f"Incomplete: {len(errors)} job(s) failed; the first: {errors[0]}.\n\n"
                    write_tables(run.work, rows, left + note)
                    raise SfbError(f"{len(errors)} evaluation job(s) failed; the first: {errors[0]}")
                write_tables(run.work, rows, note)
                runs = []  # all fitted on Ray
            for done, (sequence, mode) in enumerate(runs, start=1):
                bar.set_postfix(sequence=sequence.name, mode=mode)
                montages = Montages()
                rows += run_sequence(
                    sequence,
                    config,
                    mode,
                    device,
                    args.max_frames,
                    on_frame=lambda _: bar.update(1),
                    masks=masks,
                    with_video=both,
                    on_images=montages.add_frame,
                )
                montages.write(run.work / "montages")
                left = "" if done == len(runs) else f"Incomplete: {done} of {len(runs)} sequence runs finished.\n\n"
                write_tables(run.work, rows, left + note)
        run.finish()
    if not args.quiet:
        print(markdown(summarise(rows)))
        pictures = ", montages/ (true sub-frames above ours)" if args.ray_address is None else ""
        print(f"wrote {printable(str(out))}/: table.md, sequences.csv, frames.csv, config.yaml{pictures}")
    return 0


def _eval_on_ray(
    args: argparse.Namespace, config: Config, runs: list, both: bool, bar: typing.Any
) -> tuple[list, list[str]]:
    """The rows of an evaluation's ``runs`` fitted on Ray, in the order a local run gives them,
    and the errors of the jobs that failed (their rows are missing)."""
    from sfb_video.cluster import Outcome, Resources, connected, run_on_ray
    from sfb_video.evaluation.jobs import plan_jobs, run_job

    jobs = plan_jobs(runs, args.max_frames)
    results: list[list | None] = [None] * len(jobs)
    errors: list[str] = []

    def done(i: int, outcome: Outcome) -> None:
        if outcome.error:
            errors.append(f"{jobs[i].sequence.name} ({jobs[i].mode}): {outcome.error}")
            return
        results[i] = outcome.value
        bar.update(len(outcome.value))

    args_of = [(job, config, args.device, args.masks, _defmo_weights(args), both) for job in jobs]
    with connected(None if args.ray_address == "local" else args.ray_address):
        run_on_ray(run_job, args_of, Resources(args.cpus_per_task, args.gpus_per_task), args.max_retries, done)
    return [row for rows in results for row in rows or []], errors


def cmd_replay(args: argparse.Namespace) -> int:
    from sfb_video.replay import replay

    return replay(Path(args.run), web=args.web, web_port=args.web_port, data_port=args.data_port, bind=args.bind)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="sfb-video", description="Shape from Blur for videos of fast moving objects.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--config", default="default", help="preset name (default, fast) or a YAML path")
    common.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config field")
    common.add_argument("--device", default="auto", help="auto (CUDA if present), cpu or cuda")
    common.add_argument("--overwrite", action="store_true", help="replace an existing output folder of sfb-video's")
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
    fit.add_argument("--tsr", type=at_least(1), default=8, help="sub-frames to render for temporal super-resolution")
    fit.add_argument("--out", help="output folder (default: runs/<image name>)")
    fit.set_defaults(func=cmd_fit)
    clip = clip_arguments()
    process = sub.add_parser(
        "process", parents=[common, clip], help="recover shape and motion in every frame of a clip"
    )
    process.add_argument("video", help="the clip (any format FFmpeg reads)")
    process.add_argument("--out", help="run folder (default: runs/<clip name>)")
    process.set_defaults(func=cmd_process)
    batch = sub.add_parser(
        "batch", parents=[common, clip], help="process many clips, one run folder each, in parallel on Ray"
    )
    batch.add_argument("inputs", nargs="+", metavar="INPUT", help="clips, folders of clips, or .txt lists of clips")
    batch.add_argument("--out", default="runs", help="folder of the clips' run folders and batch.csv (default: runs)")
    batch.add_argument(
        "--ray-address",
        help="join a running Ray cluster (auto: the one `ray start` runs on this machine; HOST:PORT); "
        "default: a local Ray sized to this machine",
    )
    batch.add_argument(
        "--cpus-per-clip", type=at_least(1), help="CPUs (torch threads) per clip (default: 1 on Ray, all without it)"
    )
    batch.add_argument(
        "--gpus-per-clip", type=at_least(0, float), default=0.0, help="GPUs per clip (e.g. 0.5: two clips a GPU)"
    )
    batch.add_argument(
        "--max-retries",
        type=at_least(0),
        default=3,
        help="restarts of a clip whose worker died (killed, out of memory)",
    )
    batch.set_defaults(func=cmd_batch)
    base = argparse.ArgumentParser(add_help=False)
    base.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override a config field")
    base.add_argument("--quiet", action="store_true", help="print nothing on success")
    export = sub.add_parser("export", parents=[base], help="re-render the outputs of a run without fitting again")
    export.add_argument("run", help="a run folder written by sfb-video process")
    export.add_argument("--tsr", type=at_least(1), help="sub-frames per frame in tsr.mp4")
    export.add_argument("--stabilised", action="store_true", help=STABILISED)
    export.add_argument(
        "--novel-views", nargs="*", type=int, metavar="FRAME", help="turntables of these frames' meshes (default: best)"
    )
    export.add_argument("--views", type=at_least(2), default=36, help="turntable views per frame")
    export.set_defaults(func=cmd_export)
    evaluate = sub.add_parser("eval", parents=[common], help="score the method on a benchmark dataset")
    evaluate.add_argument(
        "--dataset", required=True, choices=["tbd", "tbd3d", "falling", "synthetic", "synthetic-hard", "shapes"]
    )
    evaluate.add_argument(
        "--root", required=True, help="the dataset's folder (synthetic: generated there on first use)"
    )
    evaluate.add_argument("--out", help="output folder (default: runs/eval-<dataset>)")
    evaluate.add_argument(
        "--mode",
        choices=["per-frame", "video", "joint", "all"],
        default="all",
        help="joint also scores the video mode (its seeds are the video mode's fits)",
    )
    evaluate.add_argument("--sequence", action="append", help="only this sequence (repeatable)")
    evaluate.add_argument("--max-frames", type=at_least(1), help="only the first N frames of each sequence")
    evaluate.add_argument(
        "--shaken", action="store_true", help="synthetic sets: as a handheld camera films them, registered first"
    )
    evaluate.add_argument(
        "--ray-address",
        help="fit the sequences (video, joint) or frames (per-frame) on Ray: local, auto or HOST:PORT",
    )
    evaluate.add_argument("--cpus-per-task", type=at_least(1), default=1, help="CPUs (torch threads) per job on Ray")
    evaluate.add_argument("--gpus-per-task", type=at_least(0, float), default=0.0, help="GPUs per job on Ray")
    evaluate.add_argument("--max-retries", type=at_least(0), default=3, help="restarts of a job whose worker died")
    evaluate.set_defaults(func=cmd_eval)
    replay = sub.add_parser("replay", help="open a run's recording in the rerun viewer")
    replay.add_argument("run", help="a run folder or a .rrd file")
    replay.add_argument("--web", action="store_true", help="serve rerun's web viewer from this machine (no display)")
    replay.add_argument("--web-port", type=int, default=9090, help="port of the web viewer's page (with --web)")
    replay.add_argument(
        "--data-port", type=int, default=9876, help="port the recording file is served from (with --web)"
    )
    replay.add_argument(
        "--bind", default="127.0.0.1", help="address to serve on (with --web; 0.0.0.0: every address, the network too)"
    )
    replay.set_defaults(func=cmd_replay)
    return parser


# Options whose value may start with "-" (argparse would take "--frames -10:" for two options).
_DASH_VALUES = ("--frames",)


def _attach_dash_values(argv: list[str]) -> list[str]:
    out: list[str] = []
    for arg in argv:
        if out and out[-1] in _DASH_VALUES and arg[:1] == "-" and (arg[1:2].isdigit() or arg[1:2] == ":"):
            out[-1] = f"{out[-1]}={arg}"
        else:
            out.append(arg)
    return out


_INTERRUPTED = {
    "process": "frames fitted so far are kept (a run being replaced stays as it was); "
    "run the same command again to resume",
    "demo": "frames fitted so far are kept; run the same command again to resume",
    "eval": "a new output folder keeps the tables of the sequences finished so far; a replaced one stays as it was",
    "batch": "clips finished so far are kept, and the frames fitted so far; run the same command again to resume",
}


def main(argv: Sequence[str] | None = None) -> int:
    # rerun's own log lines (a failed file write, before our one-line error) would break the
    # one-line promise; RUST_LOG=warn brings them back.
    os.environ.setdefault("RUST_LOG", "off")
    args = build_parser().parse_args(_attach_dash_values(list(sys.argv[1:] if argv is None else argv)))
    try:
        with sigint_outside_kernels():
            with kernel_call():
                # trimesh's imports catch BaseException (its optional parts): a Ctrl-C there was
                # lost and the command ran to the end. Held here, it is raised after the import;
                # here, not lazily, because the commands import it at many places.
                import trimesh  # noqa: F401
            return args.func(args)
    except OutputError as exc:
        resumable = args.command in ("process", "demo")
        kept = "; frames fitted so far are kept: run the same command again to resume" if resumable else ""
        print(f"sfb-video: error: {printable(str(exc))}{kept}", file=sys.stderr)
        return OUTPUT_FAILED
    except SfbError as exc:
        print(f"sfb-video: error: {printable(str(exc))}", file=sys.stderr)
        return BAD_INPUT
    except OSError as exc:
        # What no check foresaw (a device error, a file vanishing under a reader): still one line.
        where = f": {printable(str(exc.filename))}" if exc.filename else ""
        print(f"sfb-video: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return OUTPUT_FAILED
    except KeyboardInterrupt:
        note = _INTERRUPTED.get(args.command, "no partial output was left")
        print(f"sfb-video: interrupted; {note}", file=sys.stderr)
        return INTERRUPTED


def run() -> typing.NoReturn:
    """The console command (started by :func:`sfb_video.entry.run_command`): :func:`main`'s
    exit status as the process's, whenever Ctrl-C comes.

    Once main has returned, every output is whole and closed, and the process ends at once
    (``os._exit``) with main's status, Ctrl-C ignored: Python's own shutdown (torch's and numba's
    teardown, most of a second) turned a Ctrl-C into death by the signal, its parent seeing -2
    instead of 130 or 0, and so did a Ctrl-C during main that an extension's embedded code had
    seen first (CPython then re-raises the signal at exit even though main handled it).
    """
    code: int | None = None
    try:
        code = main()
    except KeyboardInterrupt:  # between main's own handler and the line below
        if code is None:
            code = INTERRUPTED
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    for stream in (sys.stdout, sys.stderr):  # C libraries' own buffers: none writes to them today
        with contextlib.suppress(OSError, ValueError):  # a closed pipe: nothing more to say
            stream.flush()
    os._exit(INTERRUPTED if code is None else code)


if __name__ == "__main__":
    run()
