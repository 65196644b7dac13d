"""``sfb-video replay``: the viewer installed beside this Python is found without PATH, a machine
without a display gets one line pointing to ``--web``, and ``--web`` serves the viewer's page and
the recording file for it, on this machine only unless asked."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest
import torch

import sfb_video.replay
from sfb_video.cli import main
from sfb_video.geometry.camera import PinholeCamera
from sfb_video.recording import Recorder
from sfb_video.replay import viewer_command


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("run")
    camera = PinholeCamera.from_fov(32, 24, 45.0)
    with Recorder(folder / "recording.rrd", camera, "a clip", subframes=1) as recorder:
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


def _listening(port: int) -> set[str]:
    """The local addresses a TCP socket listens on at ``port`` (Linux's /proc/net), in hex as
    the kernel writes them: 0100007F is 127.0.0.1, 00000000 every address."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            address, hex_port = local.split(":")
            if state == "0A" and int(hex_port, 16) == port:  # 0A: LISTEN
                found.add(address)
    return found


def _serve(run: Path, *options: str) -> tuple[subprocess.Popen[str], int, int, str]:
    """Start ``replay --web`` and wait for the line it prints once served (its first)."""
    web, data = _free_port(), _free_port()
    command = [sys.executable, "-m", "sfb_video.cli", "replay", str(run), "--web"]
    command += ["--web-port", str(web), "--data-port", str(data), *options]
    server = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert server.stdout is not None
    line = server.stdout.readline()
    assert line, server.communicate(timeout=30)[1]
    return server, web, data, line


def _stop(server: subprocess.Popen[str], data: int) -> str:
    server.terminate()  # SIGTERM, as a service manager or a shell's kill stops it
    assert server.stdout is not None
    out = server.stdout.read()  # through the file: _serve's readline left the rest in its buffer
    server.communicate(timeout=30)
    # The viewer's server stopped with the command: its port is free again.
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        probe.bind(("127.0.0.1", data))
    return out


def test_web_serves_the_viewer_on_this_machine_only_once_it_answers(run: Path) -> None:
    server, web, data, line = _serve(run)
    try:
        # The address is printed once both ports answer: open at once, the page is there.
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=2) as response:
            page = (response.status, response.headers.get("content-type"), response.read())
        assert page[0] == 200 and "text/html" in page[1] and b"<html" in page[2].lower()
        # And the recording the URL points the page to, readable from the page's origin.
        with urllib.request.urlopen(f"http://127.0.0.1:{data}/recording.rrd", timeout=10) as response:
            assert response.headers.get("access-control-allow-origin") == "*"
            assert response.read() == (run / "recording.rrd").read_bytes()
        with pytest.raises(urllib.error.HTTPError, match="404"):
            urllib.request.urlopen(f"http://127.0.0.1:{data}/../recording.rrd", timeout=10)
        if Path("/proc/net/tcp").is_file():
            assert _listening(web) == _listening(data) == {"0100007F"}  # 127.0.0.1, not the network
    finally:
        out = _stop(server, data)
    assert f"http://localhost:{web}/?url=http%3A%2F%2Flocalhost%3A{data}%2Frecording.rrd" in line
    assert "this machine only" in line and "another machine" not in line + out


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads the viewer's CPU time from Linux's /proc")
def test_the_viewer_idles_while_no_page_is_open(run: Path) -> None:
    # Handed the file, rerun's own server spun a core for as long as it served (measured: 100%).
    server, _, data, _ = _serve(run)
    try:
        (viewer,) = [p for p in Path("/proc").glob("[0-9]*") if _is_viewer_of(p, server.pid)]
        before = _cpu_seconds(viewer)
        time.sleep(3.0)
        assert _cpu_seconds(viewer) - before < 0.5  # busy, it would be 3 s
    finally:
        _stop(server, data)


def _stat(process: Path) -> list[str]:
    """The fields of /proc/PID/stat after the command's name (state, ppid, ...)."""
    return (process / "stat").read_text().rsplit(")", 1)[1].split()


def _is_viewer_of(process: Path, parent: int) -> bool:
    try:
        return int(_stat(process)[1]) == parent and "serve-web" in (process / "cmdline").read_text()
    except (OSError, IndexError, ValueError):
        return False


def _cpu_seconds(process: Path) -> float:
    fields = _stat(process)
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime


@pytest.mark.skipif(not Path("/proc/net/tcp").is_file(), reason="reads the listening sockets from Linux's /proc/net")
def test_bind_opens_the_viewer_to_the_network_and_says_so(run: Path) -> None:
    server, web, data, line = _serve(run, "--bind", "0.0.0.0")
    try:
        assert _listening(web) and _listening(data) and "0100007F" not in _listening(web) | _listening(data)
        with urllib.request.urlopen(f"http://127.0.0.1:{web}/", timeout=2) as response:
            assert response.status == 200
    finally:
        out = _stop(server, data)
    assert "on every address of this machine (--bind 0.0.0.0)" in line
    assert f"from another machine, http://{socket.gethostname()}:{web}/" in out


def test_a_port_in_use_is_one_line(run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert main(["replay", str(run), "--web", "--web-port", str(port), "--bind", "127.0.0.1"]) == 2
    assert f"port {port} (--web-port) is in use" in capsys.readouterr().err


def test_a_viewer_that_fails_after_much_logging_is_one_line_with_its_error(
    run: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # More than a pipe holds (64 KiB): read from a pipe only after the viewer stopped, it would
    # block on its own log and the command would wait out its start timeout instead.
    chatty = "import sys; sys.stderr.write('telemetry notice\\n' * 20000 + 'Error: no GPU adapter\\n'); sys.exit(1)"
    monkeypatch.setattr(sfb_video.replay, "viewer_command", lambda: [sys.executable, "-c", chatty])
    monkeypatch.setattr(sfb_video.replay, "START_TIMEOUT_S", 20.0)
    web, data = _free_port(), _free_port()
    assert main(["replay", str(run), "--web", "--web-port", str(web), "--data-port", str(data)]) == 2
    err = capsys.readouterr().err
    assert "stopped before it served: Error: no GPU adapter" in err
    assert len(err.strip().splitlines()) == 1
