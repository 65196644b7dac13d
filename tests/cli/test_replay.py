"""``sfb-video replay``: the viewer installed beside this Python is found without PATH, a machine
without a display gets one line pointing to ``--web``, and ``--web`` serves the viewer's page and
streams the recording to it."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
import torch

import sfb_video.replay
from sfb_video.cli import main
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.recording import APPLICATION_ID, Recorder
from sfb_video.replay import viewer_command

# The gRPC-web call the web viewer makes to read the recording it is served.
READ_MESSAGES = "rerun.sdk_comms.v1alpha1.MessageProxyService/ReadMessages"


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("run")
    camera = PinholeCamera.from_fov(32, 24, 45.0)
    with Recorder(folder / "recording.rrd", camera, "a clip") as recorder:
        recorder.log_frame(0, torch.rand(3, 24, 32), torch.rand(3, 24, 32))
    return folder


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_viewer_installed_with_rerun_sdk_is_found_without_path(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", "")
    (binary,) = viewer_command()
    assert Path(binary).parent.name == "rerun_cli"  # the package rerun-sdk installed beside this Python
    assert subprocess.run([binary, "--version"], capture_output=True, timeout=60).returncode == 0


def test_no_display_is_one_line_that_points_to_web(
    run: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sfb_video.replay.sys, "platform", "linux")
    assert main(["replay", str(run)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "no display" in err and "--web" in err


def test_no_recording_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(tmp_path)]) == 2
    assert "no recording at" in capsys.readouterr().err


def test_web_serves_the_viewer_and_streams_the_recording(run: Path) -> None:
    web, grpc = _free_port(), _free_port()
    command = [sys.executable, "-m", "sfb_video.cli", "replay", str(run), "--web"]
    command += ["--web-port", str(web), "--grpc-port", str(grpc), "--bind", "127.0.0.1"]
    server = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        page = None
        deadline = time.monotonic() + 60
        while page is None and time.monotonic() < deadline:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=2) as response:
                    page = (response.status, response.headers.get("content-type"), response.read())
            except OSError:
                time.sleep(0.2)
        assert page is not None, server.stderr.read() if server.poll() is not None else "no answer"
        assert page[0] == 200 and "text/html" in page[1] and b"<html" in page[2].lower()
        request = urllib.request.Request(
            f"http://127.0.0.1:{grpc}/{READ_MESSAGES}",
            data=b"\0\0\0\0\0",  # one empty gRPC message: read everything
            headers={"content-type": "application/grpc-web+proto", "x-grpc-web": "1"},
        )
        streamed = b""
        with urllib.request.urlopen(request, timeout=10) as response:
            while APPLICATION_ID.encode() not in streamed or b"world/camera" not in streamed:
                chunk = response.read1(1 << 16)
                if not chunk:
                    break
                streamed += chunk
        assert APPLICATION_ID.encode() in streamed and b"world/camera" in streamed
    finally:
        server.terminate()  # SIGTERM, as a service manager or a shell's kill stops it
        out, _ = server.communicate(timeout=30)
    assert f"http://localhost:{web}/?url=rerun%2Bhttp%3A%2F%2Flocalhost%3A{grpc}%2Fproxy" in out
    # The viewer's server stopped with the command: its port is free again.
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        probe.bind(("127.0.0.1", grpc))


def test_a_port_in_use_is_one_line(run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["replay", str(run), "--web", "--web-port", str(port), "--bind", "127.0.0.1"]) == 2
    assert f"port {port} (--web-port) is in use" in capsys.readouterr().err
