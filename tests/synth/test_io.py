"""Clip folders: the layout, atomic writes and an exact round trip."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from sfb_video.errors import SfbError
from sfb_video.synth import ClipSpec, SyntheticClip, generate_clip, load_clip, save_clip, write_clip

SPEC = ClipSpec(
    width=96,
    height=72,
    num_frames=2,
    num_subframes=2,
    sub_exposures=4,
    max_step_px=0.0,
    size_px_range=(10.0, 14.0),
    speed_range=(1.2, 1.5),
    noise_sigma=0.01,
    shape="box",
    texture_size=32,
    absent_frames=(1,),
    seed=3,
)


def _assert_same_clip(a: SyntheticClip, b: SyntheticClip) -> None:
    assert a.spec == b.spec and a.camera == b.camera
    assert a.scene.background_name == b.scene.background_name
    np.testing.assert_array_equal(a.frames, b.frames)
    np.testing.assert_array_equal(a.scene.background, b.scene.background)
    ma, mb = a.scene.mesh, b.scene.mesh
    assert ma.name == mb.name
    assert torch.equal(ma.vertices, mb.vertices)
    assert torch.equal(ma.topology.faces, mb.topology.faces)
    assert torch.equal(ma.topology.uvs, mb.topology.uvs)
    assert torch.equal(ma.topology.face_uvs, mb.topology.face_uvs)
    np.testing.assert_array_equal(ma.texture, mb.texture)
    for field in dataclasses.fields(a.scene.trajectory):
        np.testing.assert_array_equal(getattr(a.scene.trajectory, field.name), getattr(b.scene.trajectory, field.name))
    for ta, tb in zip(a.truth, b.truth, strict=True):
        assert (ta.index, ta.present, ta.bbox, ta.radius_px) == (tb.index, tb.present, tb.bbox, tb.radius_px)
        np.testing.assert_array_equal(ta.subframes, tb.subframes)
        np.testing.assert_array_equal(ta.masks, tb.masks)
        if ta.centres is None:
            assert tb.centres is None
        else:
            np.testing.assert_array_equal(ta.centres, tb.centres)
        for field in dataclasses.fields(ta.motion):
            np.testing.assert_array_equal(getattr(ta.motion, field.name), getattr(tb.motion, field.name))


def test_save_and_load_round_trip_exactly(tmp_path: Path) -> None:
    clip = generate_clip(SPEC)
    root = save_clip(clip, tmp_path / "clip")
    assert (root / "frames" / "0001.png").is_file()
    assert (root / "gt" / "subframes" / "0000_01.png").is_file()
    assert (root / "gt" / "masks" / "0001_00.png").is_file()
    assert (root / "gt" / "mesh.obj").is_file() and (root / "gt" / "texture.png").is_file()
    assert not list(root.rglob("*.tmp"))
    meta = json.loads((root / "gt.json").read_text())
    assert [f["present"] for f in meta["frames"]] == [True, False]
    assert meta["frames"][1]["bbox_xywh"] is None
    _assert_same_clip(load_clip(root), clip)


def test_a_swing_round_trips(tmp_path: Path) -> None:
    spec = dataclasses.replace(SPEC, absent_frames=(), swing_period=4.0, speed_range=(1.0, 1.1))
    clip = generate_clip(spec)
    assert clip.scene.trajectory.swing is not None
    _assert_same_clip(load_clip(save_clip(clip, tmp_path / "clip")), clip)


def test_streaming_writer_matches_the_in_memory_clip(tmp_path: Path) -> None:
    root = write_clip(SPEC, tmp_path / "streamed")
    _assert_same_clip(load_clip(root), generate_clip(SPEC))


def test_incomplete_folder_is_refused(tmp_path: Path) -> None:
    (tmp_path / "frames").mkdir()
    with pytest.raises(SfbError, match=r"gt\.json"):
        load_clip(tmp_path)
