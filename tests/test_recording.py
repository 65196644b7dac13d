"""The rerun recording of a clip: what lands where, on which timeline, and that it is written atomically."""

from __future__ import annotations

import dataclasses
import json
import os
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import av
import numpy as np
import pytest
import rerun as rr
import torch
from rerun.chunk import Chunk, RrdReader

from sfb_video.config import load_config
from sfb_video.errors import SfbError
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.imageio import to_uint8
from sfb_video.model.formation import exposure_times
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.recording import Recorder, shape_text
from sfb_video.recording.recorder import MASK_CLASS

CAMERA = PinholeCamera.from_fov(64, 48, 45.0)
N_SUB = 3  # TSR sub-frames per fitted frame
AV1 = 0x61763031  # rerun's VideoCodec.AV1: the fourcc "av01"
FITTED = (0, 2)  # frame 1 has no detection and no fit
BOX = (20, 10, 12, 9)
CURVE_STEPS = 4


@dataclass
class Inputs:
    state: ObjectState
    images: list[torch.Tensor]
    background: torch.Tensor
    mask: torch.Tensor
    reconstruction: torch.Tensor
    subframes: torch.Tensor
    losses: dict[str, float]
    curve: list[dict[str, float]]
    trajectory: np.ndarray


@dataclass
class Recorded:
    path: Path
    chunks: list[Chunk]
    inputs: Inputs


@pytest.fixture(scope="module", autouse=True)
def _strict_rerun() -> Iterator[None]:
    # rerun otherwise turns a malformed archetype into a warning and logs nothing.
    previous = rr.strict_mode()
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(previous)


@pytest.fixture(scope="module")
def inputs() -> Inputs:
    gen = torch.Generator().manual_seed(0)
    vertices, topology = load_prototype("sphere")
    motion = Motion(
        x0=torch.tensor([0.0, 0.0, 5.0]),
        dx=torch.tensor([0.5, 0.0, 0.0]),
        rot0=torch.eye(3),
        omega=torch.tensor([0.0, 0.0, 0.5]),
    )
    state = ObjectState(vertices, topology, torch.rand(3, 16, 16, generator=gen), motion)
    # Smooth, as a photo is: the recording's video codec keeps it within a few levels (noise it
    # would not, and no test here is about noise).
    v, u = torch.meshgrid(torch.linspace(0, 1, CAMERA.height), torch.linspace(0, 1, CAMERA.width), indexing="ij")
    background = torch.stack((0.2 + 0.6 * u, 0.8 - 0.5 * v, 0.3 + 0.2 * u * v))
    render = load_config("fast").render
    reconstruction = state.render_blurred(CAMERA, background, N_SUB * 2, render)
    subframes = state.render_subframes(CAMERA, background, N_SUB, dataclasses.replace(render, steps_per_subframe=2))
    mask = torch.zeros(CAMERA.height, CAMERA.width, dtype=torch.bool)
    mask[10:19, 20:32] = True
    return Inputs(
        state=state,
        images=[_with_square(background, 8 + 16 * i) for i in range(3)],
        background=background,
        mask=mask,
        reconstruction=reconstruction,
        subframes=subframes,
        losses={"total": 0.25, "data term": 0.125},
        curve=[{"total": 1.0 / (s + 1), "data term": 0.5 / (s + 1)} for s in range(CURVE_STEPS)],
        trajectory=np.array([[0.0, 0.0, 5.0], [0.5, 0.0, 5.0], [1.0, 0.1, 5.2]], dtype=np.float32),
    )


def _with_square(background: torch.Tensor, x: int) -> torch.Tensor:
    """``background`` with a light 10x10 square at column ``x``: a frame of a moving object."""
    image = background.clone()
    image[:, 20:30, x : x + 10] = torch.tensor([0.9, 0.9, 0.6])[:, None, None]
    return image


CONFIG = {"video": {"tsr": N_SUB}, "joint": {"window": 6}}
SUMMARY = {"frames_fitted": len(FITTED), "tracks": {"0": {"frames": list(FITTED)}}}


def record_clip(path: Path, inputs: Inputs, name: str = "clip") -> None:
    """Log three frames, the middle one without a detection or a fit, as the export logs them."""
    with Recorder(path, CAMERA, name, subframes=N_SUB) as rec:
        for i, image in enumerate(inputs.images):
            rec.log_frame(i, image, inputs.background)
            if i in FITTED:
                rec.log_detection(i, {0: BOX}, inputs.mask)
                rec.log_fit(i, 0, inputs.state, inputs.losses, inputs.curve)
                rec.log_masks(i, "diff", BOX, None)
                rec.log_subframes(i, inputs.reconstruction, inputs.subframes)
            else:
                rec.log_detection(i, {}, None)
                rec.log_subframes(i, image, [image])
            rec.log_trajectory(inputs.trajectory[: i + 1], 0)
        rec.log_run(CONFIG, SUMMARY)


@pytest.fixture(scope="module")
def recorded(inputs: Inputs, tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    path = tmp_path_factory.mktemp("rec") / "recording.rrd"
    record_clip(path, inputs)
    return Recorded(path, RrdReader(path).stream().to_chunks(), inputs)


# --------------------------------------------------------------------------------------------------
# Reading a recording back


def entity_paths(chunks: list[Chunk]) -> set[str]:
    return {c.entity_path for c in chunks}


def rows(chunks: list[Chunk], entity: str, component: str, timeline: str | None) -> list[tuple[int | None, Any]]:
    """(time on ``timeline``, value) of every row of ``entity`` where ``component`` is set, by time.

    ``timeline=None`` selects static rows; otherwise only rows on that timeline are returned.
    """
    out = []
    for chunk in chunks:
        if chunk.entity_path != entity:
            continue
        if (timeline is None) != chunk.is_static or (timeline is not None and timeline not in chunk.timeline_names):
            continue
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        times = batch.column(timeline).to_pylist() if timeline else [None] * batch.num_rows
        out += [(t, v) for t, v in zip(times, batch.column(component).to_pylist(), strict=True) if v is not None]
    return sorted(out, key=lambda tv: -1 if tv[0] is None else tv[0])


def times(chunks: list[Chunk], entity: str, component: str, timeline: str) -> list[int]:
    return [t for t, _ in rows(chunks, entity, component, timeline)]


def batch_at(chunks: list[Chunk], entity: str, component: str, timeline: str | None, time: int | None = None) -> list:
    """The instances of ``component`` in the one row of ``entity`` at ``time`` (static if ``timeline`` is None)."""
    matches = [v for t, v in rows(chunks, entity, component, timeline) if t == time]
    assert len(matches) == 1, f"{entity} {component} at {timeline}={time}: {len(matches)} rows"
    return matches[0]


def one_at(chunks: list[Chunk], entity: str, component: str, timeline: str | None, time: int | None = None) -> Any:
    """The single instance of ``component`` in the one row of ``entity`` at ``time``."""
    (value,) = batch_at(chunks, entity, component, timeline, time)
    return value


def decode(chunks: list[Chunk], entity: str, timeline: str) -> list[np.ndarray]:
    """The (H, W, 3) uint8 RGB images of ``entity``'s video samples on ``timeline``, in time order."""
    decoder = av.CodecContext.create("libdav1d", "r")
    frames = [
        f
        for _, sample in rows(chunks, entity, "VideoStream:sample", timeline)
        for f in decoder.decode(av.Packet(bytes(sample[0])))
    ]
    frames += decoder.decode(None)
    return [f.to_ndarray(format="rgb24") for f in frames]


def column_major(flat: list[float]) -> np.ndarray:
    return np.asarray(flat).reshape(3, 3).T


# --------------------------------------------------------------------------------------------------
# Content


def test_the_recording_holds_every_entity(recorded: Recorded) -> None:
    expected = {
        "/world",
        "/world/camera",
        "/world/camera/image",
        "/world/camera/image/detection",
        "/world/camera/image/mask",
        "/world/track_00/object",
        "/world/trajectory/track_00",
        "/background",
        "/reconstruction",
        "/tsr",
        "/losses/track_00/total",
        "/losses/track_00/data\\ term",
        "/fit/track_00/total",
        "/fit/track_00/data\\ term",
    }
    assert expected <= entity_paths(recorded.chunks)
    assert [e.application_id for e in RrdReader(recorded.path).recordings()] == ["sfb-video"]


def test_the_frame_timeline_holds_the_logged_frames(recorded: Recorded) -> None:
    frames = set()
    for chunk in recorded.chunks:
        if "frame" in chunk.timeline_names:
            frames |= set(chunk.to_record_batch().column("frame").to_pylist())
    assert frames == {0, 1, 2}
    assert times(recorded.chunks, "/world/camera/image", "VideoStream:sample", "frame") == [0, 1, 2]
    assert times(recorded.chunks, "/background", "VideoStream:sample", "frame") == [0, 1, 2]
    assert times(recorded.chunks, "/reconstruction", "VideoStream:sample", "frame") == [0, 1, 2]
    # No wall-clock timeline: the viewer should offer only ours.
    names = {name for chunk in recorded.chunks for name in chunk.timeline_names}
    assert names == {"frame", "subframe", "step"}


def test_images_are_av1_streams_and_masks_are_not(recorded: Recorded) -> None:
    for entity in ("/world/camera/image", "/background", "/reconstruction", "/tsr"):
        assert rows(recorded.chunks, entity, "VideoStream:codec", None) == [(None, [AV1])]
        # Decodable from the start on either timeline: the first sample is a keyframe.
        for timeline in ("frame", "subframe"):
            assert rows(recorded.chunks, entity, "VideoStream:sample", timeline), (entity, timeline)
    decoded = decode(recorded.chunks, "/background", "frame")
    assert len(decoded) == 3
    for image in decoded:
        assert np.abs(image.astype(np.float64) - to_uint8(recorded.inputs.background)).mean() < 3.0
    buffer = one_at(recorded.chunks, "/world/camera/image/mask", "SegmentationImage:buffer", "frame", 0)
    ids = np.frombuffer(bytes(buffer), dtype=np.uint8).reshape(CAMERA.height, CAMERA.width)
    assert np.array_equal(ids, recorded.inputs.mask.numpy().astype(np.uint8))
    ((_, (context,)),) = rows(recorded.chunks, "/world/camera/image", "AnnotationContext:context", None)
    colours = {c["class_id"]: c["class_description"]["info"]["color"] for c in context}
    # RGBA packed: pixels outside the mask (class 0) are fully transparent, the mask's class is not.
    assert colours[0] & 0xFF == 0 and colours[1] & 0xFF == 255


def test_detection_box_and_a_frame_without_one_clears_it(recorded: Recorded) -> None:
    entity = "/world/camera/image/detection"
    # rerun stores boxes as centres and half sizes; pixels x .. x + w - 1 span [x, x + w] in rerun.
    assert times(recorded.chunks, entity, "Boxes2D:centers", "frame") == list(FITTED)
    x, y, w, h = BOX
    assert one_at(recorded.chunks, entity, "Boxes2D:centers", "frame", 0) == [x + w / 2, y + h / 2]
    assert one_at(recorded.chunks, entity, "Boxes2D:half_sizes", "frame", 0) == [w / 2, h / 2]
    # Without a Clear the viewer would keep showing frame 0's box on frame 1.
    for cleared in (entity, "/world/camera/image/mask"):
        assert times(recorded.chunks, cleared, "Clear:is_recursive", "frame") == [1]


def test_pinhole_matches_the_camera(recorded: Recorded) -> None:
    flat = one_at(recorded.chunks, "/world/camera", "Pinhole:image_from_camera", None)
    k = column_major(flat)
    assert k[0, 0] == pytest.approx(CAMERA.fx) and k[1, 1] == pytest.approx(CAMERA.fy)
    # rerun puts pixel centres at half-integers, the project at integers.
    assert k[0, 2] == pytest.approx(CAMERA.cx + 0.5) and k[1, 2] == pytest.approx(CAMERA.cy + 0.5)
    assert one_at(recorded.chunks, "/world/camera", "Pinhole:resolution", None) == [CAMERA.width, CAMERA.height]
    assert rows(recorded.chunks, "/world", "ViewCoordinates:xyz", None)


def test_tsr_has_n_rows_per_fitted_frame_and_its_middle_one_on_the_frame_timeline(recorded: Recorded) -> None:
    # A frame without a fit shows the frame itself from its first sub-frame on, not the sub-frame
    # before it.
    expected = sorted([i * N_SUB + k for i in FITTED for k in range(N_SUB)] + [1 * N_SUB])
    assert times(recorded.chunks, "/tsr", "VideoStream:sample", "subframe") == expected
    assert times(recorded.chunks, "/tsr", "VideoStream:sample", "frame") == [0, 1, 2]
    # Each timeline decodes to its own images: every sub-frame on the subframe timeline, each
    # frame's middle one (mid-exposure, as the pose) on the frame timeline.
    subframes = recorded.inputs.subframes
    shown = {0: subframes, 1: recorded.inputs.images[1][None], 2: subframes}  # frame 1: no fit
    decoded = iter(decode(recorded.chunks, "/tsr", "subframe"))
    for i in range(3):
        truths = [to_uint8(sub) for sub in shown[i]]
        for k, image in enumerate(next(decoded) for _ in truths):
            errors = [np.abs(image.astype(np.float64) - truth).mean() for truth in truths]
            assert errors[k] == min(errors) and errors[k] < 5.0, (i, k, errors)
    assert next(decoded, None) is None
    assert len(decode(recorded.chunks, "/tsr", "frame")) == 3
    for i, image in enumerate(decode(recorded.chunks, "/tsr", "frame")):
        errors = [np.abs(image.astype(np.float64) - to_uint8(sub)).mean() for sub in shown[i]]
        assert errors[len(errors) // 2] == min(errors) and min(errors) < 5.0, (i, errors)


def test_what_is_logged_once_a_frame_shows_on_the_subframe_timeline_too(recorded: Recorded) -> None:
    # The viewer opens on the subframe timeline: the input, its detection, the reconstruction, the
    # losses and the trajectory must show there, at each frame's first sub-frame.
    every = [i * N_SUB for i in range(3)]
    fitted = [i * N_SUB for i in FITTED]
    for entity, component, expected in (
        ("/world/camera/image", "VideoStream:sample", every),
        ("/background", "VideoStream:sample", every),
        ("/reconstruction", "VideoStream:sample", every),
        ("/world/camera/image/detection", "Boxes2D:centers", fitted),
        ("/world/camera/image/mask", "SegmentationImage:buffer", fitted),
        ("/losses/track_00/total", "Scalars:scalars", fitted),
        ("/world/trajectory/track_00", "LineStrips3D:strips", every),
    ):
        assert times(recorded.chunks, entity, component, "subframe") == expected, entity


def test_masks_are_named_per_frame_and_subframe_masks_overlay_the_image(inputs: Inputs, tmp_path: Path) -> None:
    x, y, w, h = BOX
    masks = torch.zeros(2, h, w)  # at the crop's own size, here the box's
    masks[0, :, : w // 2] = 1
    masks[1, :, w // 2 :] = 1
    path = tmp_path / "masks.rrd"
    with Recorder(path, CAMERA, "masks", subframes=N_SUB) as rec:
        for i in range(3):
            rec.log_frame(i, inputs.images[i], inputs.background)
            rec.log_masks(i, "defmo, order as given" if i == 0 else "diff", BOX, masks if i == 0 else None)
            if i == 0:  # a second object in the same frame: its own entity, the first's kept
                rec.log_masks(i, "diff", BOX, masks.flip(0), track=1)
    chunks = RrdReader(path).stream().to_chunks()
    entity = "/world/camera/image/subframe_mask/track_00"
    assert times(chunks, entity, "SegmentationImage:buffer", "subframe") == [0, 1, 2]
    assert times(chunks, entity.replace("00", "01"), "SegmentationImage:buffer", "subframe") == [0, 1, 2]
    assert not times(chunks, entity, "SegmentationImage:buffer", "frame")
    # Sub-frame k of 3 shows the mask at its mid-time: masks 0, 1, 1.
    for k, half in ((0, slice(x, x + w // 2)), (1, slice(x + w // 2, x + w)), (2, slice(x + w // 2, x + w))):
        buffer = one_at(chunks, entity, "SegmentationImage:buffer", "subframe", k)
        ids = np.frombuffer(bytes(buffer), dtype=np.uint8).reshape(CAMERA.height, CAMERA.width)
        expected = np.zeros_like(ids)
        expected[y : y + h, half] = 2
        assert np.array_equal(ids, expected), k
    # Frame 1 has none and clears them; frame 2 has nothing left to clear.
    assert times(chunks, entity, "Clear:is_recursive", "subframe") == [N_SUB]
    # Said once, static, not once a frame.
    said = one_at(chunks, "/run/masks", "TextDocument:text", None)
    assert said == "- track 0: defmo, order as given, frames 0\n- track 0: diff, frames 1-2\n- track 1: diff, frames 0"
    assert not any(c.entity_path.startswith("/masks") for c in chunks)
    with (
        Recorder(tmp_path / "bad.rrd", CAMERA, "bad", subframes=N_SUB) as rec,
        pytest.raises(SfbError, match="not inside"),
    ):
        rec.log_masks(0, "defmo", (60, 40, 10, 10), masks)


def test_mesh_has_the_triangles_texcoords_and_texture_of_the_state(recorded: Recorded) -> None:
    state = recorded.inputs.state
    entity = "/world/track_00/object"
    assert times(recorded.chunks, entity, "Mesh3D:triangle_indices", "frame") == list(FITTED)
    # Stamped at each fitted frame's first sub-frame too, so the mesh shows while scrubbing sub-frames.
    assert times(recorded.chunks, entity, "Mesh3D:triangle_indices", "subframe") == [i * N_SUB for i in FITTED]
    triangles = np.asarray(batch_at(recorded.chunks, entity, "Mesh3D:triangle_indices", "frame", 0))
    positions = np.asarray(batch_at(recorded.chunks, entity, "Mesh3D:vertex_positions", "frame", 0))
    texcoords = np.asarray(batch_at(recorded.chunks, entity, "Mesh3D:vertex_texcoords", "frame", 0))
    normals = np.asarray(batch_at(recorded.chunks, entity, "Mesh3D:vertex_normals", "frame", 0))
    faces, face_uvs = state.topology.faces.numpy(), state.topology.face_uvs.numpy()
    assert triangles.shape == faces.shape
    assert texcoords.shape == (len(positions), 2) and normals.shape == positions.shape
    # Corner by corner, the mesh's positions and UVs are the state's: rerun's v runs down the image
    # like the project's, so no flip survives.
    assert np.allclose(positions[triangles], state.vertices.numpy()[faces], atol=1e-6)
    assert np.allclose(texcoords[triangles], state.topology.uvs.numpy()[face_uvs], atol=1e-6)
    # A sphere centred on the origin: smooth unit normals point outwards.
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-5)
    assert (np.sum(normals * positions, axis=1) > 0).all()
    texture = one_at(recorded.chunks, entity, "Mesh3D:albedo_texture_buffer", "frame", 0)
    assert bytes(texture) == to_uint8(state.texture).tobytes()


def test_object_pose_at_mid_exposure_and_at_each_subframe(recorded: Recorded) -> None:
    motion = recorded.inputs.state.motion
    entity = "/world/track_00/object"
    for i in FITTED:
        rot, pos = motion.at(torch.tensor([0.5]))
        t = one_at(recorded.chunks, entity, "Transform3D:translation", "frame", i)
        m = one_at(recorded.chunks, entity, "Transform3D:mat3x3", "frame", i)
        assert np.allclose(t, pos[0].numpy(), atol=1e-6)
        assert np.allclose(column_major(m), rot[0].numpy(), atol=1e-6)
        rots, poss = motion.at(exposure_times(N_SUB))
        for k in range(N_SUB):
            t = one_at(recorded.chunks, entity, "Transform3D:translation", "subframe", i * N_SUB + k)
            m = one_at(recorded.chunks, entity, "Transform3D:mat3x3", "subframe", i * N_SUB + k)
            assert np.allclose(t, poss[k].numpy(), atol=1e-6)
            assert np.allclose(column_major(m), rots[k].numpy(), atol=1e-6)
    # Exactly one pose per fitted frame on the frame timeline: sub-frame poses must not shadow it.
    assert times(recorded.chunks, entity, "Transform3D:translation", "frame") == list(FITTED)


def test_losses_and_the_optimisation_curve(recorded: Recorded) -> None:
    inputs = recorded.inputs
    assert rows(recorded.chunks, "/losses/track_00/total", "Scalars:scalars", "frame") == [(i, [0.25]) for i in FITTED]
    assert times(recorded.chunks, "/losses/track_00/data\\ term", "Scalars:scalars", "frame") == list(FITTED)
    steps = rows(recorded.chunks, "/fit/track_00/total", "Scalars:scalars", "step")
    # The second fit's curve follows the first's on the step timeline, not on top of it.
    assert steps == [
        (j * CURVE_STEPS + s, [inputs.curve[s]["total"]]) for j in range(len(FITTED)) for s in range(CURVE_STEPS)
    ]
    # On the step timeline only: on the frame timeline a fit's curve was a staircase of its last values.
    assert not times(recorded.chunks, "/fit/track_00/total", "Scalars:scalars", "frame")


def test_trajectory_grows_frame_by_frame(recorded: Recorded) -> None:
    entity = "/world/trajectory/track_00"
    assert times(recorded.chunks, entity, "LineStrips3D:strips", "frame") == [0, 1, 2]
    points = recorded.inputs.trajectory
    assert np.allclose(one_at(recorded.chunks, entity, "LineStrips3D:strips", "frame", 2), points)
    assert np.allclose(batch_at(recorded.chunks, entity, "Points3D:positions", "frame", 1), points[:2])


def test_recording_id_comes_from_the_clip_name_unless_given(tmp_path: Path) -> None:
    ids = []
    for name, given in (("a", None), ("a", None), ("b", None), ("a", "mine")):
        path = tmp_path / f"{len(ids)}.rrd"
        with Recorder(path, CAMERA, name, subframes=N_SUB, recording_id=given):
            pass
        ids.append(RrdReader(path).recordings()[0].recording_id)
    assert ids[0] == ids[1] != ids[2] and ids[3] == "mine"


# --------------------------------------------------------------------------------------------------
# Writing


def test_two_recorders_coexist_without_mixing(inputs: Inputs, tmp_path: Path) -> None:
    first, second = (
        Recorder(tmp_path / "a.rrd", CAMERA, "a", subframes=N_SUB),
        Recorder(tmp_path / "b.rrd", CAMERA, "b", subframes=N_SUB),
    )
    for i in range(3):
        first.log_frame(i, inputs.images[i], inputs.background)
        second.log_frame(10 + i, inputs.images[i], inputs.background)
    second.log_detection(10, {0: BOX}, None)
    first.close()
    second.close()
    a, b = (RrdReader(tmp_path / f"{n}.rrd").stream().to_chunks() for n in "ab")
    assert times(a, "/world/camera/image", "VideoStream:sample", "frame") == [0, 1, 2]
    assert times(b, "/world/camera/image", "VideoStream:sample", "frame") == [10, 11, 12]
    assert "/world/camera/image/detection" in entity_paths(b) - entity_paths(a)


def test_same_inputs_give_the_same_recording(recorded: Recorded, tmp_path: Path) -> None:
    path = tmp_path / "again.rrd"
    record_clip(path, recorded.inputs)
    # Row and chunk ids are random; the layout and the data are not.
    assert RrdReader(path).stream().collect().summary() == RrdReader(recorded.path).stream().collect().summary()
    again = RrdReader(path).stream().to_chunks()
    for entity, component, timeline in (
        ("/world/track_00/object", "Mesh3D:vertex_positions", "frame"),
        ("/tsr", "VideoStream:sample", "subframe"),
        ("/fit/track_00/total", "Scalars:scalars", "step"),
    ):
        assert rows(again, entity, component, timeline) == rows(recorded.chunks, entity, component, timeline)


def test_the_file_appears_only_on_close(inputs: Inputs, tmp_path: Path) -> None:
    path = tmp_path / "recording.rrd"
    rec = Recorder(path, CAMERA, "clip", subframes=N_SUB)
    rec.log_frame(0, inputs.images[0], inputs.background)
    (tmp,) = path.parent.iterdir()
    assert tmp.name.startswith(".") and tmp.name.endswith(".tmp.rrd") and not path.exists()
    rec.close()
    assert list(path.parent.iterdir()) == [path]
    rec.close()  # idempotent
    with pytest.raises(SfbError, match="closed"):
        rec.log_frame(1, inputs.images[1], inputs.background)


def test_abort_leaves_nothing(inputs: Inputs, tmp_path: Path) -> None:
    rec = Recorder(tmp_path / "recording.rrd", CAMERA, "clip", subframes=N_SUB)
    rec.log_frame(0, inputs.images[0], inputs.background)
    rec.abort()
    assert list(tmp_path.iterdir()) == []


def test_an_exception_in_the_with_block_leaves_no_file(inputs: Inputs, tmp_path: Path) -> None:
    (tmp_path / "recording.rrd").write_bytes(b"previous run")
    with (
        pytest.raises(RuntimeError, match="boom"),
        Recorder(tmp_path / "recording.rrd", CAMERA, "clip", subframes=N_SUB) as rec,
    ):
        rec.log_frame(0, inputs.images[0], inputs.background)
        raise RuntimeError("boom")
    # The previous file is untouched, and no temporary is left behind.
    assert [p.name for p in tmp_path.iterdir()] == ["recording.rrd"]
    assert (tmp_path / "recording.rrd").read_bytes() == b"previous run"


def test_wrong_image_shapes_are_clear_errors(inputs: Inputs, tmp_path: Path) -> None:
    with Recorder(tmp_path / "recording.rrd", CAMERA, "clip", subframes=N_SUB) as rec:
        with pytest.raises(SfbError, match=r"image must have shape \(3, 48, 64\)"):
            rec.log_frame(0, torch.rand(3, 10, 10), inputs.background)
        with pytest.raises(SfbError, match="subframes"):
            rec.log_subframes(0, inputs.reconstruction, inputs.subframes[0])
        with pytest.raises(SfbError, match="2 sub-frames, expected 3"):
            rec.log_subframes(0, inputs.reconstruction, inputs.subframes[:2])
        with pytest.raises(SfbError, match="log a frame"):
            rec.log_trajectory(inputs.trajectory)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root can write into read-only folders")
def test_read_only_folder_is_a_one_line_error(tmp_path: Path) -> None:
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        with pytest.raises(SfbError, match=r"cannot write .*recording\.rrd: Permission denied") as info:
            Recorder(folder / "recording.rrd", CAMERA, "clip", subframes=N_SUB)
        assert "\n" not in str(info.value)
        assert list(folder.iterdir()) == []
    finally:
        folder.chmod(0o755)


def test_unwritable_path_is_a_one_line_error(tmp_path: Path) -> None:
    # A folder that is a file: fails for root too, through the same path as a read-only folder.
    (tmp_path / "file").write_text("")
    with pytest.raises(SfbError, match=r"cannot write .*recording\.rrd: Not a directory") as info:
        Recorder(tmp_path / "file" / "recording.rrd", CAMERA, "clip", subframes=N_SUB)
    assert "\n" not in str(info.value)


# --------------------------------------------------------------------------------------------------
# The layout (blueprint)


def blueprint_rows(path: Path) -> dict[str, dict[str, Any]]:
    """Each entity of the recording's blueprint (``/view/<id>``, ``/container/<id>``, ...) ->
    its components' values (the first instance where there is one)."""
    reader = RrdReader(path)
    (store,) = reader.blueprints()
    out: dict[str, dict[str, Any]] = {}
    for chunk in reader.stream(store=store).to_chunks():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if ":" in name and not name.startswith("rerun.controls"):
                value = batch.column(name)[0].as_py()
                out.setdefault(chunk.entity_path, {})[name.split(":")[1]] = value
    return out


def shown_views(entities: dict[str, dict[str, Any]]) -> tuple[list[str], list[str]]:
    """(the views shown when the viewer opens, the views behind a tab), by display name."""
    shown: list[str] = []
    hidden: list[str] = []

    def walk(path: str, visible: bool) -> None:
        row = entities["/" + path]
        if path.startswith("view/"):
            (shown if visible else hidden).append(row["display_name"][0])
            return
        tabs = row["container_kind"][0] == 1  # rerun's ContainerKind: 1 tabs, 2 horizontal, 3 vertical
        active = (row.get("active_tab") or [None])[0]
        for inner in row["contents"]:
            walk(inner, visible and (not tabs or inner == active))

    (root,) = entities["/viewport"]["root_container"]
    walk(f"container/{uuid.UUID(bytes=bytes(root))}", True)
    return shown, hidden


def test_the_recording_opens_on_a_layout_of_what_a_person_comes_to_see(recorded: Recorded) -> None:
    entities = blueprint_rows(recorded.path)
    views = {
        row["display_name"][0]: (row["class_identifier"][0], "/" + row["space_origin"][0].lstrip("/"))
        for path, row in entities.items()
        if path.startswith("/view/") and "display_name" in row
    }
    assert views == {
        "input and detection": ("2D", "/world/camera/image"),
        "super-resolved": ("2D", "/tsr"),
        "3D": ("3D", "/world"),
        "track 0": ("TimeSeries", "/"),
        "fit curves (step timeline)": ("TimeSeries", "/fit"),
        "reconstruction": ("2D", "/reconstruction"),
        "background": ("2D", "/background"),
        "shapes": ("TextDocument", "/run/shapes"),
        "masks": ("TextDocument", "/run/masks"),
        "summary": ("TextDocument", "/run/summary"),
        "config": ("TextDocument", "/run/config"),
    }
    assert entities["/time_panel"]["timeline"] == ["subframe"]
    assert entities["/viewport"]["auto_views"] == [False]  # the viewer adds none of its own
    shown, hidden = shown_views(entities)
    assert shown == ["input and detection", "super-resolved", "3D", "track 0"]
    assert "fit curves (step timeline)" in hidden
    # Every view shown has content on the timeline it opens on (the views' own entities).
    content = {
        "input and detection": "/world/camera/image",
        "super-resolved": "/tsr",
        "3D": "/world/track_00/object",
        "track 0": "/losses/track_00/total",
    }
    # And on the frame timeline, the other one a person switches to.
    for name in shown:
        for timeline in ("subframe", "frame"):
            assert any(c.entity_path == content[name] and timeline in c.timeline_names for c in recorded.chunks), name
    assert any(c.entity_path.startswith("/fit/") and "step" in c.timeline_names for c in recorded.chunks)
    for entity in ("/run/shapes", "/run/masks", "/run/summary", "/run/config"):
        assert rows(recorded.chunks, entity, "TextDocument:text", None), entity
    assert json.loads(one_at(recorded.chunks, "/run/summary", "TextDocument:text", None)[8:-4]) == SUMMARY


def test_the_3d_view_is_framed_on_the_trajectory(recorded: Recorded) -> None:
    entities = blueprint_rows(recorded.path)
    (eye,) = [row for path, row in entities.items() if path.endswith("/EyeControls3D")]
    points = recorded.inputs.trajectory
    target = (points.min(0) + points.max(0)) / 2
    assert np.allclose(eye["look_target"][0], target, atol=1e-5)
    # Before the object, on the camera's side, and near enough that it is not a speck: the
    # camera (the origin) stands 5 object sizes away, the eye closer than twice that.
    position = np.asarray(eye["position"][0])
    assert position[2] < target[2] and np.linalg.norm(position - target) < 2 * np.linalg.norm(target)


def test_a_second_run_writes_the_same_layout(recorded: Recorded, tmp_path: Path) -> None:
    path = tmp_path / "again.rrd"
    record_clip(path, recorded.inputs)
    assert blueprint_rows(path) == blueprint_rows(recorded.path)


def test_the_replay_shows_each_windows_shape_and_how_clearly_it_won() -> None:
    windows = [
        {
            "track": 0,
            "frames": [0, 1, 2],
            "prototype": "box",
            "shape_margin": 0.12,
            "shape_trial": {"sphere": 1.0, "box": 0.88},
        },
        {"track": 0, "frames": [3, 4, 5], "prototype": "box", "shape_margin": None, "shape_trial": {}},
    ]
    rows = shape_text(windows).splitlines()
    assert rows[2] == "| 0 | 0-2 | box | +0.12 | sphere 1.00, box 0.88 |"
    assert rows[3] == "| 0 | 3-5 | box | - | no trial: the shape of the track's earlier fits |"
    assert "No joint windows" in shape_text([])


def test_a_logged_image_decodes_to_the_image_in_its_colours(tmp_path: Path) -> None:
    # Three channels apart, smooth (the codec keeps a gradient close): a swapped channel
    # or a flipped image would be off by far more than the encoding's error.
    v, u = torch.meshgrid(torch.linspace(0, 1, CAMERA.height), torch.linspace(0, 1, CAMERA.width), indexing="ij")
    image = torch.stack((0.2 + 0.7 * u, 0.9 - 0.6 * v, torch.full_like(u, 0.4)))
    path = tmp_path / "recording.rrd"
    with Recorder(path, CAMERA, "colours", subframes=N_SUB) as rec:
        rec.log_frame(0, image, image)
    (decoded,) = decode(RrdReader(path).stream().to_chunks(), "/world/camera/image", "frame")
    assert np.abs(decoded.astype(np.float64) - to_uint8(image)).mean() < 2.0


def test_a_clip_larger_than_the_view_is_recorded_shrunk_with_its_boxes_masks_and_pinhole(
    inputs: Inputs, tmp_path: Path
) -> None:
    # As a 4K clip is recorded at 1920x1080: here 64x48 into 32x24, everything 2D halved alike.
    path = tmp_path / "recording.rrd"
    with Recorder(path, CAMERA, "shrunk", subframes=N_SUB, max_view=(32, 24)) as rec:
        assert rec.shrink == 2 and rec.view_size == (32, 24)
        rec.log_frame(0, inputs.images[0], inputs.background)
        rec.log_detection(0, {0: BOX}, inputs.mask)
        rec.log_subframes(0, inputs.reconstruction, inputs.subframes)
    chunks = RrdReader(path).stream().to_chunks()
    assert one_at(chunks, "/world/camera", "Pinhole:resolution", None) == [32, 24]
    k = column_major(one_at(chunks, "/world/camera", "Pinhole:image_from_camera", None))
    assert k[0, 0] == pytest.approx(CAMERA.fx / 2) and k[0, 2] == pytest.approx((CAMERA.cx + 0.5) / 2)
    x, y, w, h = BOX
    centre = one_at(chunks, "/world/camera/image/detection", "Boxes2D:centers", "frame", 0)
    assert centre == pytest.approx([(x + w / 2) / 2, (y + h / 2) / 2])
    buffer = one_at(chunks, "/world/camera/image/mask", "SegmentationImage:buffer", "frame", 0)
    ids = np.frombuffer(bytes(buffer), dtype=np.uint8).reshape(24, 32)
    # Class where at least half of each 2x2 block is (the nearest pixel would shift it).
    half_or_more = inputs.mask.numpy().reshape(24, 2, 32, 2).mean(axis=(1, 3)) >= 0.5
    assert np.array_equal(ids, half_or_more.astype(np.uint8) * MASK_CLASS)
    (image,) = decode(chunks, "/world/camera/image", "frame")
    half = to_uint8(inputs.images[0]).reshape(24, 2, 32, 2, 3).mean(axis=(1, 3))
    assert image.shape == (24, 32, 3) and np.abs(image - half).mean() < 5.0
    # The 3D pose of the pinhole's image plane is unchanged: a point projects to the same place.
    point = np.array([0.3, -0.2, 4.0])
    full = np.array(
        [CAMERA.fx * point[0] / point[2] + CAMERA.cx + 0.5, CAMERA.fy * point[1] / point[2] + CAMERA.cy + 0.5]
    )
    assert (k @ point)[:2] / point[2] == pytest.approx(full / 2)


def test_a_size_the_shrink_does_not_divide_is_scaled_per_axis(inputs: Inputs, tmp_path: Path) -> None:
    # 65x49 into at most 32x24: f = 3, 22x16; boxes and the pinhole by 22/65 and 16/49, not 1/3.
    camera = PinholeCamera.from_fov(65, 49, 45.0)
    image = torch.nn.functional.interpolate(inputs.images[0][None], size=(49, 65), mode="bilinear")[0]
    path = tmp_path / "recording.rrd"
    with Recorder(path, camera, "odd", subframes=1, max_view=(32, 24)) as rec:
        assert rec.shrink == 3 and rec.view_size == (22, 16)
        rec.log_frame(0, image, image)
        rec.log_detection(0, {0: (13, 7, 26, 14)}, None)
    chunks = RrdReader(path).stream().to_chunks()
    sx, sy = 22 / 65, 16 / 49
    assert one_at(chunks, "/world/camera", "Pinhole:resolution", None) == [22, 16]
    k = column_major(one_at(chunks, "/world/camera", "Pinhole:image_from_camera", None))
    assert k[0, 2] == pytest.approx((camera.cx + 0.5) * sx) and k[1, 1] == pytest.approx(camera.fy * sy)
    centre = one_at(chunks, "/world/camera/image/detection", "Boxes2D:centers", "frame", 0)
    assert centre == pytest.approx([26 * sx, 14 * sy])
    (decoded,) = decode(chunks, "/world/camera/image", "frame")
    assert decoded.shape == (16, 22, 3)
