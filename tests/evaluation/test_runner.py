"""The evaluation runner's joint windows: a window whose fit diverged is left out with a note,
as the pipeline leaves it out, and any other error is raised, not taken for divergence."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from sfb_video.config import load_config
from sfb_video.errors import DivergenceError
from sfb_video.evaluation import runner
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.stages.types import FrameStatus


def _joint_rows(monkeypatch: pytest.MonkeyPatch, error: Exception) -> list[runner.FrameRow]:
    def fit(*args: object) -> None:
        raise error

    monkeypatch.setattr(runner, "fit_track_window", fit)
    monkeypatch.setattr(runner, "window_frame", lambda *args: None)
    monkeypatch.setattr(runner, "estimate_subframes", lambda *args: None)
    monkeypatch.setattr(runner, "score_frame", lambda *args: {"tiou": 0.5, "psnr": 20.0, "ssim": 0.5})
    image = np.zeros((8, 8, 3))
    frames = [SimpleNamespace(index=i, image=image, background=image, box=(0, 0, 4, 4)) for i in range(3)]
    fitted = {i: (frames[i], SimpleNamespace(start="warm", prototype="sphere"), 1.0) for i in range(3)}
    statuses = [FrameStatus(i, "fitted", (0, 0, 4, 4), track=0) for i in range(3)]
    sequence = SimpleNamespace(dataset="synthetic", name="seq")
    camera = PinholeCamera.from_fov(8, 8, 45.0)
    args = (sequence, statuses, fitted, [], camera, load_config("fast"), torch.device("cpu"), None, None)
    return runner._joint_rows(*args)  # type: ignore[arg-type]


def test_a_diverged_window_keeps_its_frames_single_fits_and_says_so(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    rows = _joint_rows(monkeypatch, DivergenceError("the joint fit diverged"))
    assert [(r.frame, r.status, r.track) for r in rows] == [(0, "warm", 0), (1, "warm", 0), (2, "warm", 0)]
    assert "seq: joint fit of frames 0-2 skipped: the joint fit diverged" in capsys.readouterr().err


def test_any_other_error_of_a_window_is_raised(monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(RuntimeError, match="CUDA out of memory"):
        _joint_rows(monkeypatch, RuntimeError("CUDA out of memory"))


def test_the_baselines_score_the_blurred_frame_and_the_background_as_every_subframe() -> None:
    rng = np.random.default_rng(0)
    background = rng.uniform(0.2, 0.4, (24, 32, 3))
    image = background.copy()
    image[8:16, 10:22] = 0.9
    # A still object: every sub-frame is the frame itself, the truth the 'Im' baseline matches.
    subframes = np.repeat(image[None], 2, axis=0)
    frames = [SimpleNamespace(index=0, box=(6, 5, 20, 14), image=image, background=background, subframes=subframes)]
    sequence = SimpleNamespace(dataset="synthetic", name="seq", frames=lambda: iter(frames))
    rows = runner.baseline_rows(sequence)  # type: ignore[arg-type]
    im, bg = rows
    assert (im.mode, bg.mode) == ("Im", "Bg") and math.isnan(im.tiou)
    assert im.psnr == 100.0 and im.ssim == pytest.approx(1.0)  # equal to the truth on the box
    box_mse = np.mean((background[5:19, 6:26] - subframes[:, 5:19, 6:26]) ** 2)
    assert bg.psnr == pytest.approx(-10 * math.log10(box_mse), rel=1e-5) and bg.psnr < 20
