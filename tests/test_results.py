"""The run folder's records of fits: what is saved is what is read back."""

from __future__ import annotations

from pathlib import Path

import torch

from sfb_video.fitting.window import JointResult
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model.trajectory import Trajectory
from sfb_video.results import SavedWindow, load_window, save_window, window_path


def test_a_saved_window_reads_back_with_its_shape_trial_and_margin(tmp_path: Path) -> None:
    vertices, topology = load_prototype("box")
    trajectory = Trajectory(
        first_frame=4,
        breaks=torch.tensor([0.0, 3.0]),
        anchors=torch.tensor([[0.0, 0.0, 8.0], [1.0, 0.5, 8.0]]),
        degree=1,
        rot0=torch.eye(3),
        spin=torch.tensor([0.0, 0.1, 0.0]),
        exposure_fraction=0.6,
        model="constant_velocity",
    )
    losses = {i: {"image": 0.1 * i} for i in (4, 5, 6)}
    result = JointResult(
        "box", vertices, topology, torch.rand(3, 8, 8), trajectory, losses, 0.2, [], 1.5,
        shapes={"sphere": 1.0, "box": 0.8, "disc": 0.9}, shape_margin=1 - 0.8 / 0.9,
    )  # fmt: skip
    save_window(tmp_path, SavedWindow(2, result, {i: {"image": 0.3} for i in losses}))
    back = load_window(window_path(tmp_path, 2, 4)).result
    assert back.prototype == "box" and back.shapes == result.shapes
    assert back.shape_margin == result.shape_margin
    assert torch.equal(back.vertices, vertices) and torch.equal(back.trajectory.anchors, trajectory.anchors)
