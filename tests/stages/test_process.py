"""Reading a finished run folder back as its outputs show it."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from sfb_video.config import load_config
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.results import FrameResult, save_result
from sfb_video.run_folder import DETECTIONS, MARKER, window_path
from sfb_video.stages import process
from sfb_video.stages.types import FrameStatus

CAMERA = PinholeCamera.from_fov(320, 240, 45.0)


def test_each_frame_is_read_back_as_the_export_shows_it(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    # Windows of frames 0-3, 2-5 and 4-7; the middle one diverged and was not saved. Its frames
    # (3 and 4) keep their single-frame fits, as in tsr.mp4: read back from the saved windows
    # alone, they came from the neighbours, whose poses there were never judged. A dropped
    # track's frame is not in the outputs.
    config = load_config("fast", ["joint.window=4", "joint.overlap=2"])
    vertices, topology = load_prototype("sphere")
    state = ObjectState(
        vertices,
        topology,
        torch.rand(3, 8, 8),
        Motion(torch.tensor([0.0, 0.0, 5.0]), torch.zeros(3), torch.eye(3), torch.zeros(3)),
    )
    statuses = [FrameStatus(i, "fitted", (0, 0, 4, 4), track=0) for i in range(8)]
    statuses.append(FrameStatus(3, "dropped", (9, 9, 4, 4), track=1))
    for s in statuses:
        result = FrameResult(
            s.index, s.box, s.box, CAMERA, state, "cold", "sphere", {"image": 0.1}, [], 1.0, track=s.track
        )
        save_result(tmp_path, result)
    (tmp_path / MARKER).write_text(json.dumps({"kind": "run"}))
    (tmp_path / DETECTIONS).write_text(json.dumps([dataclasses.asdict(s) for s in statuses]))
    for first in (0, 4):
        path = window_path(tmp_path, 0, first)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.touch()
    # Accepted windows, judged on none of their frames (every frame of theirs trusted).
    saved = {"accepted": True, "explained": {}, "frames": range(8)}
    monkeypatch.setattr(process, "load_window", lambda path: SimpleNamespace(name=path.name, **saved))
    monkeypatch.setattr(process, "with_joint", lambda result, window: window.name)
    results = process.final_results(tmp_path, config)
    assert set(results) == {(i, 0) for i in range(8)}
    first, last = window_path(tmp_path, 0, 0).name, window_path(tmp_path, 0, 4).name
    assert [results[i, 0] for i in (0, 1, 2, 5, 6, 7)] == [first] * 3 + [last] * 3
    assert all(isinstance(results[i, 0], FrameResult) for i in (3, 4))
