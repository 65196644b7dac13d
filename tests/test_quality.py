"""Long quality runs (``pytest -m slow``): the default preset on the default demo clip.

The thresholds come from the benchmark runs named beside them (the same clips and preset), a
margin short of what they measured, so that a regression in detection, warm starts or the time
direction shows here before it shows to users.
"""

from __future__ import annotations

import statistics
from pathlib import Path

import pytest
import torch

from sfb_video.config import load_config
from sfb_video.demo import demo_clip, demo_config, score_run, write_clip_video
from sfb_video.stages.process import ProcessOptions, process_clip

# Measured by benchmarks.video on this clip: mean TIoU 0.813, PSNR 19.7 dB over its 8 frames.
MIN_TIOU, MIN_PSNR = 0.75, 18.5


@pytest.mark.slow
def test_default_preset_on_the_demo_clip(tmp_path: Path) -> None:
    config = demo_config(load_config("default"))
    clip = demo_clip(config)
    video = tmp_path / "clip.mp4"
    write_clip_video(clip, video)
    summary = process_clip(ProcessOptions(video=video, out=tmp_path / "run"), config, torch.device("cpu"), quiet=True)
    assert summary["frames_fitted"] == config.demo.frames
    scores = score_run(tmp_path / "run", clip, config)
    assert statistics.mean(s.tiou for s in scores.values()) >= MIN_TIOU
    assert statistics.mean(s.psnr for s in scores.values()) >= MIN_PSNR
