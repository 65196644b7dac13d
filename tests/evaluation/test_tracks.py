"""The evaluation scores what ``process`` runs: both build their tracks with the pipeline's
tracker, here on a fast swing where the evaluation's own rule (fits within two diameters of
each other) used to cut the track the pipeline follows into pieces."""

from __future__ import annotations

from pathlib import Path

import torch

from sfb_video.config import load_config
from sfb_video.demo import write_clip_video
from sfb_video.evaluation.runner import run_sequence
from sfb_video.evaluation.synthetic_set import SyntheticSequence
from sfb_video.results import load_results
from sfb_video.stages.process import ProcessOptions, clip_camera, process_clip
from sfb_video.stages.read import probe
from sfb_video.stages.run_results import read_run
from sfb_video.stages.tracking.prediction import join_gap, predict, ray_gap
from sfb_video.synth import ClipSpec, generate_clip

CPU = torch.device("cpu")


def test_the_evaluation_and_process_build_the_same_tracks(tmp_path: Path) -> None:
    # One turn in 3 frames at 3 sizes a frame: the streak curves away from a straight guess.
    spec = ClipSpec(
        num_frames=6,
        swing_period=3.0,
        seed=7,
        width=240,
        height=180,
        size_px_range=(12, 13),
        speed_range=(3.0, 3.2),
        num_subframes=4,
    )
    clip = generate_clip(spec)
    video = tmp_path / "swing.mp4"
    write_clip_video(clip, video)
    config = load_config("fast", ["joint.enabled=false", f"video.exposure_fraction={spec.exposure_fraction}"])
    out = tmp_path / "run"
    process_clip(ProcessOptions(video=video, out=out, masks="diff"), config, CPU, quiet=True)
    _, statuses = read_run(out)
    processed = [s.track for s in statuses]

    sequence = SyntheticSequence("synthetic", "swing", tmp_path, spec.num_subframes, spec.num_frames, clip)
    scored = [r.track for r in run_sequence(sequence, config, "video", CPU)]
    assert scored == processed
    assert len(set(processed)) < len(processed)  # frames were joined into tracks

    # The rule the evaluation had, on process's own fits: it would have cut where the tracker joined.
    fits = {k.index: r for k, r in load_results(out).items()}  # one object
    camera = clip_camera(probe(video, config.video), config.camera, None)
    e = config.video.exposure_fraction
    old_rule = [
        min(join_gap(fits[i - 1], fits[i], camera, e), ray_gap(fits[i - 1], fits[i], camera))
        < 2 * predict(fits[i - 1].state.motion, camera).diameter
        for i in range(1, spec.num_frames)
    ]
    tracker_joined = [processed[i] == processed[i - 1] for i in range(1, spec.num_frames)]
    assert old_rule != tracker_joined
