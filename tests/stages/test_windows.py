"""Fitting a track's windows: the motion model chosen from the single-frame fits, the frames each
window is handed, refined and judged on, and the other objects of its frames left out."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from sfb_video.config import Config, DetectConfig, JointConfig, load_config
from sfb_video.errors import DivergenceError
from sfb_video.fitting.path import Seed, choose_motion
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.geometry.prototypes import load_prototype
from sfb_video.model.motion import Motion
from sfb_video.model.scene import ObjectState
from sfb_video.results import FrameKey
from sfb_video.stages import windows
from sfb_video.stages.run_results import FolderSource, RunResults
from sfb_video.stages.types import FrameStatus, FrameWithBackground

CAMERA = PinholeCamera.from_fov(320, 240, 45.0)
E = 0.6
PARALLEL = DetectConfig().parallel_deg


class _Saved:
    """A run folder's saved fits as ``single`` makes them (by key); no window saved yet."""

    def __init__(self, single: Callable[[FrameKey], object] = lambda key: SimpleNamespace(track=key.track)) -> None:
        self.make = single

    def single(self, key: FrameKey) -> object:
        return self.make(key)

    def window(self, key: object) -> None:
        return None

    def add_window(self, key: object, window: object) -> None:
        pass


def _results(statuses: list[FrameStatus], config: Config, source: object | None = None) -> RunResults:
    return RunResults(statuses, source or _Saved(), config.joint)  # type: ignore[arg-type]


def _seeds(path: list[torch.Tensor]) -> list[Seed]:
    """Seeds whose streak ends lie on ``path``: pairs (start, end) of each frame's exposure."""
    vertices, topology = load_prototype("sphere")
    seeds = []
    for k in range(len(path) // 2):
        x0, x1 = path[2 * k], path[2 * k + 1]
        state = ObjectState(
            vertices, topology, torch.full((3, 8, 8), 0.5), Motion(x0, x1 - x0, torch.eye(3), torch.zeros(3))
        )
        seeds.append(Seed(k, state, "sphere", 0.05))
    return seeds


def _ends(position, frames: int) -> list[torch.Tensor]:
    return [position(k + tau * E) for k in range(frames) for tau in (0.0, 1.0)]


def test_a_gravity_arc_is_one_smooth_piece() -> None:
    def arc(t: float) -> torch.Tensor:
        return torch.tensor([-2.5 + 0.9 * t, -1.0 + 0.05 * t * t, 10.0])

    model, bounce = choose_motion(_seeds(_ends(arc, 6)), 0, 6.0, CAMERA, E, JointConfig())
    assert (model, bounce) == ("constant_acceleration", None)


def test_a_bounce_is_found_in_the_gap_where_the_path_breaks() -> None:
    def bouncing(t: float) -> torch.Tensor:
        # Falls until t = 2.8 (in the gap after frame 2), then rises.
        return torch.tensor([-2.5 + 0.9 * t, 1.5 - 0.8 * abs(t - 2.8), 10.0])

    model, bounce = choose_motion(_seeds(_ends(bouncing, 6)), 0, 6.0, CAMERA, E, JointConfig())
    assert model == "bounce"
    assert bounce is not None and 2 + E < bounce < 3


def test_a_configured_model_is_used_as_is() -> None:
    def arc(t: float) -> torch.Tensor:
        return torch.tensor([-2.5 + 0.9 * t, 0.0, 10.0])

    config = JointConfig(motion="constant_velocity")
    assert choose_motion(_seeds(_ends(arc, 4)), 0, 4.0, CAMERA, E, config) == ("constant_velocity", None)


def test_only_a_divergence_skips_a_window_and_any_other_error_is_raised(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = load_config("fast")
    statuses = [FrameStatus(i, "fitted", (0, 0, 4, 4), track=0) for i in range(3)]
    frames = [FrameWithBackground(i, torch.zeros(3, 8, 8), torch.zeros(3, 8, 8)) for i in range(3)]
    camera = PinholeCamera.from_fov(8, 8, 45.0)
    monkeypatch.setattr(windows, "window_frame", lambda *args: None)
    results = _results(statuses, config)

    def fails_with(error: Exception) -> None:
        def fit(*args: object, **kwargs: object) -> None:
            raise error

        monkeypatch.setattr(windows, "fit_track_window", fit)

    fails_with(DivergenceError("the joint fit diverged"))
    assert windows.fit_windows(iter(frames), tmp_path, results, camera, config, torch.device("cpu")) == []
    assert "frames 0-2 skipped: the joint fit diverged" in capsys.readouterr().err
    for error in (RuntimeError("CUDA out of memory"), RuntimeError("Expected all tensors to be on the same device")):
        fails_with(error)
        with pytest.raises(RuntimeError, match=str(error)):
            windows.fit_windows(iter(frames), tmp_path, results, camera, config, torch.device("cpu"))


def _devices(*tensors: torch.Tensor) -> set[str]:
    return {t.device.type for t in tensors}


def test_a_window_scores_its_single_frame_fits_on_its_crops_device(tmp_path: Path, monkeypatch) -> None:
    # Issue 35: process loads the single-frame fits on the CPU (load_result) while a window's
    # crops are on the fitting device; on a GPU a state and a crop on two devices raise. The
    # meta device stands in for the GPU: every state fit_quality is handed must be on it.
    from sfb_video.crop import Crop
    from sfb_video.fitting.window import WindowFrame
    from sfb_video.results import FrameResult, load_result, save_result

    meta = torch.device("meta")
    camera = PinholeCamera.from_fov(64, 48, 45.0)
    vertices, topology = load_prototype("sphere")
    motion = Motion(torch.tensor([0.0, 0.0, 5.0]), torch.tensor([0.5, 0.0, 0.0]), torch.eye(3), torch.zeros(3))
    state = ObjectState(vertices, topology, torch.rand(3, 8, 8), motion)
    box = (0, 0, 64, 48)
    for index in (0, 1):
        save_result(tmp_path, FrameResult(index, box, box, camera, state, "cold", "sphere", {"image": 0.1}, [], 1.0))
    image = torch.zeros(3, 48, 64, device=meta)
    mask = torch.zeros(48, 64, dtype=torch.bool, device=meta)
    crops = {i: WindowFrame(i, Crop((0, 0, 64, 48), camera, image, image, mask.float(), mask)) for i in (0, 1)}

    class Joint:  # what fit_track_window reads of a window's joint fit
        def state(self, index: int) -> ObjectState:
            return state.to(meta)

    seen: list[set[str]] = []

    def quality(state: ObjectState, image: torch.Tensor, background: torch.Tensor, *_: object) -> float:
        seen.append(_devices(state.vertices, state.texture, state.motion.x0, image, background))
        return 0.5

    monkeypatch.setattr(windows, "fit_window", lambda *args, **kwargs: Joint())
    monkeypatch.setattr(windows, "fit_quality", quality)
    config = load_config("fast", ['joint.refine="off"'])
    single = lambda i: load_result(tmp_path / "frames" / f"frame_{i:05d}_track_00.pt")  # noqa: E731
    saved = windows.fit_track_window(0, [0, 1], crops, single, None, camera, config)
    assert saved.accepted and len(seen) == 4
    assert all(devices == {"meta"} for devices in seen), seen


def test_each_window_is_handed_the_frames_it_stands_for(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    # A frame two windows share is shown from one of them: only that one refines and judges it.
    config = load_config("fast")
    statuses = [FrameStatus(i, "fitted", (0, 0, 4, 4), track=0) for i in range(10)]
    frames = [FrameWithBackground(i, torch.zeros(3, 8, 8), torch.zeros(3, 8, 8)) for i in range(10)]
    monkeypatch.setattr(windows, "window_frame", lambda *args: None)
    monkeypatch.setattr(windows, "save_window", lambda *args: None)
    handed: dict[int, list[int]] = {}

    def fit(track: int, members: list[int], *args: object, **kwargs: object) -> object:
        handed[members[0]] = list(args[-1])  # type: ignore[call-overload]
        return type("Saved", (), {"accepted": True})()

    monkeypatch.setattr(windows, "fit_track_window", fit)
    windows.fit_windows(iter(frames), tmp_path, _results(statuses, config), CAMERA, config, torch.device("cpu"))
    assert handed == {0: [0, 1, 2, 3, 4], 4: [5, 6, 7, 8, 9]}


def test_a_window_refines_and_is_judged_on_the_frames_it_is_shown_for(monkeypatch: pytest.MonkeyPatch) -> None:
    vertices, topology = load_prototype("sphere")
    motion = Motion(torch.tensor([0.0, 0.0, 5.0]), torch.tensor([0.5, 0.0, 0.0]), torch.eye(3), torch.zeros(3))
    state = ObjectState(vertices, topology, torch.rand(3, 8, 8), motion)
    single = type("Single", (), {"state": state, "prototype": "sphere", "losses": {"image": 0.1}})()

    class Joint:  # what fit_track_window reads of a window's joint fit
        def state(self, index: int) -> ObjectState:
            return state

    refined: list[int] = []

    def refine(result: Joint, frames: list[object], *args: object, **kwargs: object) -> Joint:
        refined.extend(frames)  # type: ignore[arg-type]
        return result

    monkeypatch.setattr(windows, "fit_window", lambda *args, **kwargs: Joint())
    monkeypatch.setattr(windows, "refine_frames", refine)
    monkeypatch.setattr(windows, "_quality", lambda *args: 0.5)
    crops = {i: i for i in range(3)}
    saved = windows.fit_track_window(0, [0, 1, 2], crops, lambda i: single, None, CAMERA, load_config("fast"), [1, 2])  # type: ignore[arg-type]
    assert refined == [1, 2] and set(saved.explained) == {1, 2} and saved.accepted


def test_a_frame_whose_streak_touched_another_keeps_the_window_s_pose(monkeypatch: pytest.MonkeyPatch) -> None:
    # Its crop holds both objects' pixels: its pose, refined alone, was drawn to the other's.
    vertices, topology = load_prototype("sphere")
    motion = Motion(torch.tensor([0.0, 0.0, 5.0]), torch.tensor([0.5, 0.0, 0.0]), torch.eye(3), torch.zeros(3))
    state = ObjectState(vertices, topology, torch.rand(3, 8, 8), motion)
    single = type("Single", (), {"state": state, "prototype": "sphere", "losses": {"image": 0.1}})()

    @dataclasses.dataclass(frozen=True)
    class Joint:
        refined: dict[int, str] = dataclasses.field(default_factory=dict)

        def state(self, index: int) -> ObjectState:
            return state

    def refine(result: Joint, frames: list[int], *args: object, held: set[int]) -> Joint:
        pose = args[2]
        return Joint({i: "pose" if pose and i not in held else "texture" for i in frames})

    monkeypatch.setattr(windows, "fit_window", lambda *args, **kwargs: Joint())
    monkeypatch.setattr(windows, "refine_frames", refine)
    monkeypatch.setattr(windows, "_quality", lambda *args: 0.5)
    crops = {i: i for i in range(3)}
    config = load_config("fast")
    saved = windows.fit_track_window(0, [0, 1, 2], crops, lambda i: single, None, CAMERA, config, touched={1})  # type: ignore[arg-type]
    # Its own texture on the window's pose; judged, as every frame the window stands for.
    assert saved.result.refined == {0: "pose", 1: "texture", 2: "pose"}
    assert set(saved.explained) == {0, 1, 2}


def test_each_window_is_told_which_of_its_frames_touched_another_track(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    config = load_config("fast")
    statuses = [
        FrameStatus(i, "fitted", (0, 0, 4, 4), track=t, touched=i in (3, 4) and t < 2)
        for i in range(5)
        for t in (0, 1, 2)
    ]
    frames = [FrameWithBackground(i, torch.zeros(3, 8, 8), torch.zeros(3, 8, 8)) for i in range(5)]
    monkeypatch.setattr(windows, "window_frame", lambda *args: None)
    monkeypatch.setattr(windows, "save_window", lambda *args: None)
    monkeypatch.setattr(windows, "object_paths", lambda *args: {})
    told: dict[int, set[int]] = {}

    def fit(track: int, members: list[int], *args: object, touched: set[int]) -> object:
        told[track] = touched
        return type("Saved", (), {"accepted": True})()

    monkeypatch.setattr(windows, "fit_track_window", fit)
    windows.fit_windows(iter(frames), tmp_path, _results(statuses, config), CAMERA, config, torch.device("cpu"))
    assert told == {0: {3, 4}, 1: {3, 4}, 2: set()}


def test_a_window_crops_around_the_share_a_dropped_track_gave_back(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    statuses = [FrameStatus(i, "fitted", (323, 38 + 10 * i, 28, 54), track=1, touched=i == 1) for i in range(3)] + [
        FrameStatus(1, "dropped", (332, 100, 20, 28), track=2, touched=True)
    ]
    statuses += [FrameStatus(i, "fitted", (400, 40 + 10 * i, 20, 40), track=3) for i in range(3)]
    frames = [FrameWithBackground(i, torch.zeros(3, 240, 480), torch.zeros(3, 240, 480)) for i in range(3)]
    cropped: dict[tuple[int, int], tuple[int, int, int, int]] = {}
    given: dict[int, dict[int, tuple[int, int, int, int]]] = {}

    def crop(frame: FrameWithBackground, box: tuple[int, int, int, int], result: object, *args: object) -> None:
        cropped[frame.index, result.track] = box  # type: ignore[attr-defined]

    def paths(results: object, camera: object, boxes: dict[int, tuple[int, int, int, int]]) -> dict:
        given[len(given)] = boxes
        return {}

    monkeypatch.setattr(windows, "window_frame", crop)
    monkeypatch.setattr(windows, "save_window", lambda *args: None)
    monkeypatch.setattr(windows, "object_paths", paths)
    monkeypatch.setattr(windows, "fit_track_window", lambda *a, **k: type("Saved", (), {"accepted": True})())
    config = load_config("fast")
    windows.fit_windows(iter(frames), tmp_path, _results(statuses, config), CAMERA, config, torch.device("cpu"))
    # Frame 1: the pale end's crop and its box as a neighbour hold the share given back.
    assert cropped[1, 1] == (323, 48, 29, 80) and given[1][1] == (323, 48, 29, 80)
    assert cropped[0, 1] == (323, 38, 28, 54) and cropped[1, 3] == (400, 50, 20, 40)


def test_a_window_sees_the_other_objects_of_its_frames_as_the_background(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # Two objects in the same frames: each track's window crops saw the other object's streak too
    # where it fell in the crop, and tried to explain it. Now the other's path shows the
    # background, but where it crosses this object's own path (a hole there costs more).
    from sfb_video.results import FrameResult, save_result
    from sfb_video.stages.composite import object_radius, path_mask

    vertices, topology = load_prototype("sphere")
    states = {
        track: ObjectState(
            vertices,
            topology,
            torch.rand(3, 8, 8),
            Motion(torch.tensor(x0), torch.tensor(dx), torch.eye(3), torch.zeros(3)),
        )
        for track, (x0, dx) in {0: ([-0.5, 0.0, 5.0], [1.0, 0.0, 0.0]), 1: ([0.0, -0.5, 5.0], [0.0, 1.0, 0.0])}.items()
    }
    box = (0, 0, 320, 240)
    statuses = []
    for index in range(3):
        for track, state in states.items():
            save_result(
                tmp_path,
                FrameResult(index, box, box, CAMERA, state, "cold", "sphere", {"image": 0.1}, [], 1.0, track=track),
            )
            statuses.append(FrameStatus(index, "fitted", box, track=track))
    generator = torch.Generator().manual_seed(0)
    pixels = torch.randint(1, 256, (3, 240, 320), dtype=torch.uint8, generator=generator)
    frames = [FrameWithBackground(i, pixels.clone(), torch.zeros_like(pixels)) for i in range(3)]
    handed: dict[tuple[int, int], torch.Tensor] = {}

    def crop(frame: FrameWithBackground, box: object, result: FrameResult, *args: object) -> None:
        handed[frame.index, result.track] = frame.pixels

    monkeypatch.setattr(windows, "window_frame", crop)
    monkeypatch.setattr(windows, "fit_track_window", lambda *args, **kwargs: type("Saved", (), {"accepted": True})())
    monkeypatch.setattr(windows, "save_window", lambda *args: None)
    config = load_config("fast")
    windows.fit_windows(
        iter(frames), tmp_path, _results(statuses, config, FolderSource(tmp_path)), CAMERA, config, torch.device("cpu")
    )
    paths = {t: torch.from_numpy(path_mask(s.motion, object_radius(s, CAMERA), CAMERA)) for t, s in states.items()}
    assert set(handed) == {(i, t) for i in range(3) for t in (0, 1)}
    for (_, track), seen in handed.items():
        other = paths[1 - track] & ~paths[track]
        crossing = paths[1 - track] & paths[track]
        assert bool(other.any()) and bool(crossing.any())
        assert bool((seen[:, other] == 0).all())  # the other object's path: the background
        # This one's, the crossing included (a hole there costs more), and the rest, as filmed.
        assert torch.equal(seen[:, ~other], pixels[:, ~other])
    assert all(torch.equal(f.pixels, pixels) for f in frames)  # the frames themselves untouched


def test_a_neighbour_beside_a_wide_path_is_background_for_its_window() -> None:
    # falling_three frame 11: the pale end's fitted path, as wide as its object's furthest
    # vertex (84 px), held the two streaks beside it; its window took them in and drew the three
    # as one smear. The neighbour's pixels nearer its own centre are now the background.
    vertices, topology = load_prototype("sphere")
    states = {
        track: ObjectState(
            vertices * scale,
            topology,
            torch.rand(3, 8, 8),
            Motion(torch.tensor([x, -0.3, 5.0]), torch.tensor([0.0, 0.6, 0.0]), torch.eye(3), torch.zeros(3)),
        )
        for track, (x, scale) in {0: (0.0, 1.0), 1: (0.5, 0.2)}.items()
    }
    whole = (0, 0, CAMERA.width, CAMERA.height)
    results = {t: type("Result", (), {"state": s, "detection_box": whole})() for t, s in states.items()}
    paths = windows.object_paths(results, CAMERA)  # type: ignore[arg-type]
    neighbour = paths[1].mask
    assert bool((neighbour & paths[0].mask).float().mean() > 0.5 * neighbour.float().mean())  # inside the wide path
    hidden = windows.others_region(0, paths, PARALLEL, apart={0, 1})
    assert bool(hidden[paths[1].distance < 2].all())  # the neighbour's centre
    assert not bool(hidden[paths[0].distance < 10].any())  # this object's own streak
    assert not bool(windows.others_region(1, paths, PARALLEL, apart={0, 1})[paths[1].distance < 5].any())
    # Streaks that touched (objects crossing, whose fitted paths may look level): the overlap
    # stays this object's.
    assert not bool((windows.others_region(0, paths, PARALLEL, apart={1}) & paths[0].mask).any())


def _path(box: tuple[int, int, int, int], covered: tuple[int, int, int, int]) -> windows.ObjectPath:
    """An object's path on a 40 x 40 frame: its blob's ``box``, and the part of it its fitted
    path ``covered`` (both x, y, w, h); its centre runs down the middle of that part."""

    def mask(b: tuple[int, int, int, int]) -> torch.Tensor:
        m = torch.zeros(40, 40, dtype=torch.bool)
        m[b[1] : b[1] + b[3], b[0] : b[0] + b[2]] = True
        return m

    columns = torch.arange(40, dtype=torch.float32).expand(40, 40)
    distance = (columns - (covered[0] + covered[2] / 2)).abs()
    return windows.ObjectPath(mask(covered), distance, np.array([0.0, 1.0]), mask(box))


def test_a_neighbours_blob_past_its_fitted_path_is_background_for_its_window() -> None:
    # falling_three frame 10: the pale end's fit covered the upper half of its streak only; the
    # lower half lay in the grey object's window's crop, and its fit grew a white side there.
    own = _path((20, 0, 10, 40), (18, 0, 14, 40))  # the fitted path a little wider than the blob
    pale = _path((8, 0, 14, 40), (8, 0, 14, 20))  # its fit covers the upper half only
    hidden = windows.others_region(0, {0: own, 1: pale}, PARALLEL, apart={0, 1})
    assert bool(hidden[25:, 8:20].all())  # the neighbour's lower half, outside this blob's box
    assert not bool(hidden[:, 20:30].any())  # this object's blob, its box
    # Where the streaks touched, the neighbour is only its fitted path.
    touched = windows.others_region(0, {0: own, 1: pale}, PARALLEL, apart={0})
    assert not bool(touched[25:, :].any())
