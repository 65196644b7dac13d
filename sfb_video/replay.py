"""Opening a run's recording in the rerun viewer: a native window, or the web viewer served from
this machine for machines without a display (a server, a container, SSH).

The viewer is the one installed with this package's rerun-sdk: the binary in its ``rerun_cli``
package (so a virtual environment need not be activated), else a ``rerun`` on PATH. ``--web``
runs ``rerun --serve-web`` for the viewer's page, in a process group of its own that is stopped
with this command, whatever stops it (Ctrl-C, SIGTERM), and serves the recording file itself over
plain HTTP from this process, for the page to fetch: handed the file, rerun's own server kept a
core busy for as long as it served, with no page open. Both listen on this machine only
(127.0.0.1) unless ``--bind`` opens them to the network, and the address is printed once both
answer.
"""

from __future__ import annotations

import contextlib
import functools
import http.server
import importlib.util
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO
from urllib.parse import quote

from sfb_video.errors import SfbError
from sfb_video.run_folder import RECORDING

WEB_PORT = 9090
"""Where the web viewer's page is served (rerun's default)."""
DATA_PORT = 9876
"""Where the recording file is served to the page."""
SERVED_NAME = "recording.rrd"
"""The recording's name in its URL, whatever the run calls it."""
LOCAL = "127.0.0.1"
"""The default ``--bind``: this machine only. A run shows the clip and whatever it filmed."""
EVERY_ADDRESS = ("0.0.0.0", "::")
START_TIMEOUT_S = 60.0
"""How long the viewer's servers may take to answer before the command gives up."""


def recording_path(run: Path) -> Path:
    """The recording of a run folder (or ``run`` itself when it is an ``.rrd`` file).

    Raises:
        SfbError: there is no recording there.
    """
    path = run / RECORDING if run.is_dir() else run
    if not path.is_file():
        raise SfbError(f"no recording at {path}; run sfb-video process first")
    return path


def viewer_command() -> list[str]:
    """The command that starts the rerun viewer installed with this Python's rerun-sdk.

    The binary itself, not the ``rerun`` script beside Python: the script runs the binary as a
    child, which stopping the script would leave running.

    Raises:
        SfbError: rerun-sdk's viewer is not installed.
    """
    spec = importlib.util.find_spec("rerun_cli")
    if spec is not None and spec.origin is not None:
        binary = Path(spec.origin).parent / ("rerun.exe" if os.name == "nt" else "rerun")
        if binary.is_file():
            return [str(binary)]
    found = shutil.which("rerun")
    if found is not None:
        return [found]
    raise SfbError("the rerun viewer is not installed; pip install rerun-sdk into this environment")


def has_display() -> bool:
    """Whether a native window can open: always on macOS and Windows, with X11 or Wayland on Linux."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _check_port(port: int, bind: str, what: str) -> None:
    if not 0 < port < 65536:
        raise SfbError(f"{what} must be a port number from 1 to 65535, got {port}")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((bind if bind not in ("0.0.0.0", "::") else "", port))
        except OSError:
            raise SfbError(f"port {port} ({what}) is in use; choose another with {what}") from None


def _answers(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=1):
            return True
    except OSError:
        return False


def _wait_until_served(process: subprocess.Popen[bytes], log: IO[bytes], host: str, port: int) -> None:
    """Return once ``port`` answers on ``host``; ``log`` is where the viewer writes its stderr.

    Raises:
        SfbError: the viewer stopped first, or did not answer within :data:`START_TIMEOUT_S`.
    """
    deadline = time.monotonic() + START_TIMEOUT_S
    while not _answers(host, port):
        if process.poll() is not None:
            raise SfbError(f"the rerun web viewer stopped before it served: {_last_error(log)}")
        if time.monotonic() > deadline:
            raise SfbError(f"the rerun web viewer did not answer on port {port} within {START_TIMEOUT_S:.0f} s")
        time.sleep(0.1)


def _last_error(log: IO[bytes]) -> str:
    log.seek(0)
    err = log.read().decode(errors="replace")
    lines = [line for line in err.splitlines() if "rror" in line] or err.splitlines()[-1:]
    return lines[-1].strip() if lines else "no message"


def served_message(path: Path, bind: str, web_port: int, data_port: int) -> str:
    """What ``--web`` prints once the viewer answers: the address to open and who can open it."""
    if bind in EVERY_ADDRESS:
        name = socket.gethostname()
        return (
            f"serving {path} in rerun's web viewer on every address of this machine (--bind {bind}):\n"
            f"  here, open {web_url('localhost', web_port, data_port)}\n"
            f"  from another machine, {web_url(name, web_port, data_port)} (or its IP address for {name})\n"
            "(Ctrl-C stops)"
        )
    if bind in (LOCAL, "localhost", "::1"):
        return (
            f"serving {path} in rerun's web viewer on this machine only ({bind}): "
            f"open {web_url('localhost', web_port, data_port)}\n"
            f"(--bind 0.0.0.0 opens it to the network, or forward ports {web_port} and {data_port}; Ctrl-C stops)"
        )
    url = web_url(bind, web_port, data_port)
    return f"serving {path} in rerun's web viewer on {bind} only: open {url}\n(Ctrl-C stops)"


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def web_url(host: str, web_port: int, data_port: int) -> str:
    """The address that opens the web viewer on the recording served at ``data_port``."""
    return f"http://{host}:{web_port}/?url=" + quote(data_url(host, data_port), safe="")


def data_url(host: str, data_port: int) -> str:
    """The recording file's address, as the viewer's page fetches it."""
    return f"http://{host}:{data_port}/{SERVED_NAME}"


class _RecordingHandler(http.server.BaseHTTPRequestHandler):
    """Answers GET /recording.rrd with the one file, and nothing else."""

    def __init__(self, *args: object, path: Path, **kwargs: object) -> None:
        self.path_served = path
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]

    def do_GET(self) -> None:
        if self.path.split("?")[0] != f"/{SERVED_NAME}":
            self.send_error(404)
            return
        try:
            data = self.path_served.open("rb")
        except OSError:
            self.send_error(404)
            return
        with data:
            self.send_response(200)
            self.send_header("Content-Type", "application/octet-stream")
            self.send_header("Content-Length", str(os.fstat(data.fileno()).st_size))
            # The page comes from the viewer's port: another origin, which the browser checks.
            self.send_header("Access-Control-Allow-Origin", "*")
            self.end_headers()
            with contextlib.suppress(BrokenPipeError, ConnectionResetError):  # the page closed while it loaded
                shutil.copyfileobj(data, self.wfile)

    def log_message(self, format: str, *args: object) -> None:
        pass  # a line per request would bury the address printed


@contextlib.contextmanager
def _serving_file(path: Path, bind: str, port: int) -> Iterator[None]:
    """Serve ``path`` at ``/recording.rrd`` on ``bind``:``port`` from a thread, until the block ends."""

    class Server(http.server.ThreadingHTTPServer):
        address_family = socket.AF_INET6 if ":" in bind else socket.AF_INET
        daemon_threads = True

    try:
        server = Server((bind, port), functools.partial(_RecordingHandler, path=path))
    except OSError as error:
        raise SfbError(f"cannot serve the recording on {bind} port {port}: {error.strerror}") from None
    thread = threading.Thread(target=server.serve_forever, name="sfb-video recording server", daemon=True)
    thread.start()
    try:
        yield
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def replay(run: Path, *, web: bool, web_port: int = WEB_PORT, data_port: int = DATA_PORT, bind: str = LOCAL) -> int:
    """Open the recording of ``run``; with ``web``, serve it on ``bind`` until interrupted.
    Returns the exit status.

    Raises:
        SfbError: no recording; no display and no ``web``; a port in use; the viewer failed.
    """
    path = recording_path(run)
    command = viewer_command()
    if not web:
        if not has_display():
            raise SfbError(
                "no display here (neither DISPLAY nor WAYLAND_DISPLAY is set); "
                "use sfb-video replay --web to serve the viewer over HTTP"
            )
        return subprocess.call([*command, str(path)])
    _check_port(web_port, bind, "--web-port")
    _check_port(data_port, bind, "--data-port")
    # Given a URL it can open itself, rerun serves only the page (no gRPC server of its own).
    here = LOCAL if bind in EVERY_ADDRESS else bind
    server = [*command, "--serve-web", "--bind", bind, "--web-viewer-port", str(web_port), data_url(here, data_port)]
    # The viewer's own log lines (telemetry, analytics notices) would bury the address we print;
    # a file, not a pipe, keeps them for the error message: a pipe nobody reads while the viewer
    # serves would stop it once full.
    with tempfile.TemporaryFile() as log, _serving_file(path, bind, data_port):
        process = subprocess.Popen(server, stdout=subprocess.DEVNULL, stderr=log, start_new_session=True)
        # The recording's server listens already (bound above): only the viewer's port is awaited.
        status = _serve_until_stopped(process, log, here, web_port, served_message(path, bind, web_port, data_port))
        if status != 0:
            raise SfbError(f"the rerun web viewer stopped: {_last_error(log)}")
    return 0


def _serve_until_stopped(process: subprocess.Popen[bytes], log: IO[bytes], host: str, port: int, message: str) -> int:
    """Wait for the viewer to answer on ``host``:``port``, print ``message``, and wait for it to
    stop (or for Ctrl-C or SIGTERM, which stop it). Returns its exit status, 0 when this command
    stopped it."""
    stop_on_sigterm = signal.signal(signal.SIGTERM, _interrupt)
    try:
        # An address printed before its port listens opens on "connection refused".
        _wait_until_served(process, log, host, port)
        print(message, flush=True)
        return process.wait()
    except KeyboardInterrupt:
        return 0
    finally:
        signal.signal(signal.SIGTERM, stop_on_sigterm)
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGTERM)
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
