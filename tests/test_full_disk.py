"""A full disk while the outputs are written: every writer fails at once with the one-line "No
space left on device", no temporary file is left, the saved frames are kept, and the next run
resumes.

Each case runs in a child process with a time limit, so that a writer that hangs (rerun's own file
writer did, on a full disk: its flush timed out and its disconnect waited forever) fails its test
instead of stopping the suite. The disk is a small tmpfs, which only root on Linux may mount; the
tests are skipped elsewhere.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from sfb_video.config import load_config
from sfb_video.demo import demo_clip, demo_config
from sfb_video.video import VideoWriter

ROOT = Path(__file__).resolve().parents[1]
PAGE = 4096  # tmpfs allocates whole pages
# A hang shows as the time limit reached; a healthy case takes seconds (the pipeline run below
# about 10 s on 2 cores), so the limits leave room for a loaded machine.
CHILD_LIMIT_S = 120
RUN_LIMIT_S = 300
# The free space the exports find: far less than they need (close to 1 MB for the clip below),
# enough for the small files the fitting stage writes after its frames (detections.json, the
# marker, each through a temporary copy).
EXPORT_ROOM = 96 * 1024

TINY = ["demo.frames=4", "demo.width=120", "demo.height=90", "demo.size_px=[14.0, 16.0]"]
QUICK = ["--config", "fast", "--device", "cpu", "--masks", "diff", "--set", "fit.iterations=20"]
QUICK += ["--set", "fit.warm_iterations=10", "--set", "video.exposure_fraction=0.8", "--set", "joint.enabled=false"]
EXPORTS = ("tsr.mp4", "recording.rrd", "trajectory.csv", "meshes", "summary.json")

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="mounts a tmpfs (Linux, as root)")


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Callable[[int], Path]]:
    """Mount a tmpfs of the given size in bytes (rounded up to whole KB) and return its folder;
    unmounted after the test. Skips the test where a tmpfs cannot be mounted (not root)."""
    mounted: list[Path] = []

    def mount(size: int) -> Path:
        disk = tmp_path / f"disk{len(mounted)}"
        disk.mkdir()
        option = f"size={-(-size // 1024)}k"
        done = subprocess.run(
            ["mount", "-t", "tmpfs", "-o", option, "tmpfs", str(disk)], capture_output=True, text=True
        )
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip() or done.returncode}")
        mounted.append(disk)
        return disk

    yield mount
    for disk in mounted:
        subprocess.run(["umount", "-l", str(disk)], check=False, capture_output=True)


def _grow(disk: Path, size: int) -> None:
    subprocess.run(["mount", "-o", f"remount,size={size // 1024}k", str(disk)], check=True, capture_output=True)


def _run(
    command: list[str], limit_s: float, tmp: Path, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """Run ``command`` from the repository's root with its own temporary folder ``tmp`` (and
    ``env`` added to the environment); a run past ``limit_s`` is killed and fails the test as a
    hang."""
    tmp.mkdir(exist_ok=True)
    env = os.environ | {"TMPDIR": str(tmp)} | (env or {})
    try:
        return subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=limit_s)
    except subprocess.TimeoutExpired as e:
        err = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else e.stderr
        pytest.fail(f"hung: {command[1:4]} still running after {limit_s} s (stderr: {err!r})")


def _child(code: str, tmp: Path, **names: object) -> tuple[dict, str]:
    """Run :data:`HELPERS` and ``code`` (which binds ``report``, a dict) in a fresh Python with
    ``names`` bound; return ``report`` and what the child wrote on stderr, rerun's warnings and
    errors included."""
    prelude = "".join(f"{k} = {v!r}\n" for k, v in names.items())
    script = prelude + HELPERS + textwrap.dedent(code) + "\nimport json, sys\njson.dump(report, sys.stdout)\n"
    done = _run([sys.executable, "-c", script], CHILD_LIMIT_S, tmp, env={"RUST_LOG": "warn"})
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout), done.stderr


def _temporaries(folder: Path) -> list[str]:
    return sorted(str(p) for p in folder.rglob("*") if ".tmp" in p.name)


def _ours(tmp: Path) -> list[str]:
    """What sfb-video left in a temporary folder (torch leaves its own caches there)."""
    return sorted(name for name in os.listdir(tmp) if name.startswith("sfb-video"))


def _one_line(text: str, *words: str) -> None:
    assert "\n" not in text.strip() and "Traceback" not in text, text
    for word in words:
        assert word in text, text


# A child's helpers: random frames (noise does not compress, so a small disk fills in a few
# frames) and a file that takes every byte left.
HELPERS = """
import os, time
from pathlib import Path
import numpy as np
import torch
from sfb_video.errors import OutputError

generator = torch.Generator().manual_seed(0)

def noise(width=160, height=120):
    return torch.rand(3, height, width, generator=generator)

def fill(folder):
    with open(Path(folder) / "filler", "wb") as f:
        try:
            while True:
                f.write(bytes(1 << 16))
                f.flush()
        except OSError:
            pass
        try:
            f.close()
        except OSError:
            pass

def listing(folder):
    return sorted(os.listdir(folder))
"""


# --------------------------------------------------------------------------------------------------
# Each writer on its own


def test_the_recorder_stops_at_once_on_a_full_disk_and_leaves_nothing(
    tmpfs: Callable[[int], Path], tmp_path: Path
) -> None:
    small, roomy = tmpfs(256 * 1024), tmpfs(8 << 20)
    code = """
    from rerun.chunk import RrdReader
    from sfb_video.geometry.camera import PinholeCamera
    from sfb_video.recording import Recorder

    report = {"logging": []}

    # While frames are logged: the disk fills after a few frames. rerun's own file writer hung
    # there only at times (a race in it), so the disk fills at several points.
    for width in (64, 96, 128, 160, 192, 224):
        camera = PinholeCamera.from_fov(width, width * 3 // 4, 45.0)
        mask = torch.zeros(camera.height, camera.width, dtype=torch.bool)
        mask[: camera.height // 2, : camera.width // 2] = True
        case, start = {"width": width, "error": None}, time.monotonic()
        try:
            with Recorder(Path(small) / "recording.rrd", camera, "clip", subframes=1) as rec:
                for i in range(500):
                    rec.log_frame(i, noise(camera.width, camera.height), noise(camera.width, camera.height))
                    rec.log_detection(i, {0: (0, 0, camera.width // 2, camera.height // 2)}, mask)
        except OutputError as e:
            case.update(error=str(e), frame=i)
        case.update(seconds=time.monotonic() - start, left=listing(small))
        report["logging"].append(case)

    # On close: the last frames and the footer do not fit.
    camera = PinholeCamera.from_fov(160, 120, 45.0)
    rec = Recorder(Path(roomy) / "recording.rrd", camera, "clip", subframes=1)
    for i in range(5):
        rec.log_frame(i, noise(), noise())
    fill(roomy)
    start = time.monotonic()
    try:
        rec.close()
    except OutputError as e:
        report["closing"] = {"error": str(e), "seconds": time.monotonic() - start}
    report["closing_left"] = listing(roomy)

    # Then rerun is not wedged: a recorder on a disk with room works, in the same process.
    os.remove(Path(roomy) / "filler")
    with Recorder(Path(roomy) / "recording.rrd", camera, "clip", subframes=1) as rec:
        for i in range(3):
            rec.log_frame(i, noise(), noise())
    report["after"] = len(RrdReader(Path(roomy) / "recording.rrd").stream().to_chunks())
    report["after_left"] = listing(roomy)
    report["tmp_left"] = [name for name in listing(os.environ["TMPDIR"]) if name.startswith("sfb-video")]
    """
    report, stderr = _child(code, tmp_path / "tmp", small=str(small), roomy=str(roomy))
    # rerun's file writer never met the error: the state in which it could hang (at times: a
    # race in it) cannot occur. It says so in its log when it does.
    assert "file_sink" not in stderr and "Failed to write" not in stderr, stderr
    assert "closing" in report, f"no error on closing on a full disk: {report}"
    for case in [*report["logging"], report["closing"]]:
        assert case["error"] is not None, f"no error on a full disk: {case}"
        _one_line(case["error"], "cannot write", "recording.rrd", "No space left on device")
        assert case["seconds"] < 10, report
    assert all(0 < case["frame"] < 100 for case in report["logging"]), report
    assert all(case["left"] == [] for case in report["logging"]) and report["closing_left"] == ["filler"], report
    assert report["after"] > 0 and report["after_left"] == ["recording.rrd"], report
    assert report["tmp_left"] == [], report  # the pipe rerun writes into is gone too


def test_the_video_writer_stops_at_once_on_a_full_disk_and_leaves_nothing(
    tmpfs: Callable[[int], Path], tmp_path: Path
) -> None:
    small, roomy = tmpfs(256 * 1024), tmpfs(8 << 20)
    code = """
    from sfb_video.video import VideoReader, VideoWriter

    report = {}
    start = time.monotonic()
    try:
        with VideoWriter(Path(small) / "tsr.mp4", 25, 160, 120) as video:
            for i in range(2000):
                video.write(noise())
    except OutputError as e:
        report["writing"] = {"error": str(e), "frame": i, "seconds": time.monotonic() - start}
    report["writing_left"] = listing(small)

    # x264 holds its lookahead until the end: closing writes most of a short clip.
    video = VideoWriter(Path(roomy) / "tsr.mp4", 25, 160, 120)
    for i in range(10):
        video.write(noise())
    fill(roomy)
    start = time.monotonic()
    try:
        video.close()
    except OutputError as e:
        report["closing"] = {"error": str(e), "seconds": time.monotonic() - start}
    report["closing_left"] = listing(roomy)

    os.remove(Path(roomy) / "filler")
    with VideoWriter(Path(roomy) / "tsr.mp4", 25, 160, 120) as video:
        for i in range(3):
            video.write(noise())
    with VideoReader(Path(roomy) / "tsr.mp4") as reader:
        report["after"] = sum(1 for _ in reader)
    """
    report, _ = _child(code, tmp_path / "tmp", small=str(small), roomy=str(roomy))
    for case in ("writing", "closing"):
        assert case in report, f"no error while {case} on a full disk: {report}"
        _one_line(report[case]["error"], "cannot write", "tsr.mp4", "No space left on device")
        assert report[case]["seconds"] < 10, report
    assert report["writing_left"] == [] and report["closing_left"] == ["filler"], report
    assert report["after"] == 3


# --------------------------------------------------------------------------------------------------
# The pipeline, end to end


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4-frame 120x90 clip of a ball flying past a photo."""
    frames = demo_clip(demo_config(load_config("fast", TINY))).frames
    path = tmp_path_factory.mktemp("clip") / "ball.mp4"
    with VideoWriter(path, 30.0, frames[0].shape[1], frames[0].shape[0]) as video:
        for frame in frames:
            video.write(frame)
    return path


def _pages(folder: Path, names: list[str]) -> int:
    """The bytes a tmpfs gives the files under ``names`` in ``folder``."""
    files = [
        p for name in names for p in ([folder / name] if (folder / name).is_file() else (folder / name).rglob("*"))
    ]
    return sum(-(-p.stat().st_size // PAGE) * PAGE for p in files if p.is_file())


def test_a_full_disk_during_the_exports_is_one_line_keeps_the_frames_and_resumes(
    clip: Path, tmpfs: Callable[[int], Path], tmp_path: Path
) -> None:
    # As a user on a small disk meets it: the frames fit, the exports do not. A first run with
    # room says how much the fitting stage writes.
    reference = tmp_path / "reference"
    done = _run(
        [sys.executable, "-m", "sfb_video.cli", "process", str(clip), "--out", str(reference), *QUICK, "--quiet"],
        RUN_LIMIT_S,
        tmp_path / "tmp",
    )
    assert done.returncode == 0, done.stderr
    fitting = [p.name for p in reference.iterdir() if p.name not in EXPORTS]
    assert "frames" in fitting and _pages(reference, list(EXPORTS)) > 4 * EXPORT_ROOM
    disk = tmpfs(_pages(reference, fitting) + EXPORT_ROOM)

    out = disk / "run"
    command = [sys.executable, "-m", "sfb_video.cli", "process", str(clip), "--out", str(out), *QUICK]
    done = _run([*command, "--quiet"], RUN_LIMIT_S, tmp_path / "tmp")
    assert done.returncode == 4, done.stderr
    _one_line(done.stderr, "sfb-video: error: cannot write", "No space left on device", "run the same command again")
    frames = {p.name: p.read_bytes() for p in (out / "frames").iterdir()}
    assert sorted(frames) == sorted(p.name for p in (reference / "frames").iterdir())
    assert not any((out / name).exists() for name in ("tsr.mp4", "recording.rrd", "summary.json"))
    assert _temporaries(disk) == [] and _ours(tmp_path / "tmp") == []

    _grow(disk, 64 << 20)
    done = _run(command, RUN_LIMIT_S, tmp_path / "tmp")
    assert done.returncode == 0, done.stderr
    assert "resuming the unfinished run" in done.stdout and "(4 frames already fitted)" in done.stdout
    assert json.loads((out / "summary.json").read_text())["frames_fitted"] == 4
    assert {p.name: p.read_bytes() for p in (out / "frames").iterdir()} == frames  # not fitted again
    assert {p.name for p in out.iterdir()} == {p.name for p in reference.iterdir()}
    assert _temporaries(disk) == [] and _ours(tmp_path / "tmp") == []
