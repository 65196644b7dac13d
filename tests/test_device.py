"""The whole pipeline on the device ``--device`` names: ``pytest --device cuda tests/test_device.py``.

The rest of the suite runs on the CPU; here a clip goes through ``process`` on the device asked
for (the CPU by default, 9 s; skipped when CUDA is asked for and absent), the joint fit and its
spin search included. A window whose inputs sit on two devices raises
inside its fit and is left out of the summary as diverged, so a silent fall back to the
single-frame results fails this test.
"""

from __future__ import annotations

from pathlib import Path

import torch

from sfb_video.config import load_config
from sfb_video.demo import demo_clip, demo_config, write_clip_video
from sfb_video.results import load_results
from sfb_video.stages.process import ProcessOptions, process_clip


def test_a_clip_is_processed_on_the_device_joint_fit_and_spin_search_included(
    tmp_path: Path, device: torch.device
) -> None:
    config = demo_config(load_config("fast", ["joint.spin_magnitudes=[60.0]", "joint.spin_axes=4"]))
    clip = demo_clip(config)
    video = tmp_path / "clip.mp4"
    write_clip_video(clip, video)
    summary = process_clip(ProcessOptions(video=video, out=tmp_path / "run"), config, device, quiet=True)
    assert summary["device"] == str(device)
    assert [f["status"] for f in summary["frames"]] == ["fitted"] * config.demo.frames
    windows = summary["joint"]["windows"]
    assert len(windows) == 1 and windows[0]["frames"] == list(range(config.demo.frames)), windows
    assert abs(summary["joint"]["exposure_fraction"] - clip.spec.exposure_fraction) < 0.1
    for result in load_results(tmp_path / "run").values():
        assert torch.isfinite(result.state.vertices).all()
