"""Helpers for tests against a real `signpose serve`: uvicorn in a thread, or the command in a subprocess."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import httpx
import uvicorn
import viser

from signpose.app.server import bind, create_app
from signpose.app.workspace import Workspace, WorkspaceConfig
from signpose.pipeline.library import SAMPLE_LIBRARY

REPO = Path(__file__).resolve().parents[2]
TIMEOUT_S = 30
VISER_PROTOCOL = f"viser-v{viser.__version__}"  # the websocket subprotocol viser's client asks for


@contextmanager
def running(app):
    """Serve `app` with uvicorn on a free loopback port in a thread; yields the base URL."""
    sock = bind("127.0.0.1", 0)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", timeout_graceful_shutdown=1))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + TIMEOUT_S
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}"
    finally:
        server.should_exit = True
        thread.join(TIMEOUT_S)


@contextmanager
def running_workspace(config: WorkspaceConfig):
    """`running` the app of a Workspace opened from `config`, closed after; yields the base URL."""
    workspace = Workspace.open(config)
    try:
        with running(create_app(workspace)) as url:
            yield url
    finally:
        workspace.close()


def sample_library_copy(folder: Path) -> Path:
    """A copy of the sample library in `folder`: a state started from it does not load and process
    the sample scenes, as one started from the samples themselves does."""
    library = folder / "library"
    if not library.exists():
        shutil.copytree(SAMPLE_LIBRARY, library)
    return library


def start_serve(state_dir: Path, *options: str, env: dict | None = None) -> tuple[subprocess.Popen, str]:
    """`signpose serve --port 0` on `state_dir` with the sample library copied beside it; the process
    and the address it printed (with ?token=... when it needs one)."""
    command = [sys.executable, "-m", "signpose.app.cli", "serve", "--port", "0", "--state-dir", str(state_dir),
               "--library", str(sample_library_copy(state_dir.parent)), *options]
    proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=None if env is None else {**os.environ, **env})
    line = proc.stdout.readline()
    if " open http://" not in line:
        proc.kill()
        raise AssertionError(f"signpose serve printed no address: {line}{proc.communicate()[1]}")
    return proc, line.split(" open ", 1)[1].split()[0]


def stop_serve(proc: subprocess.Popen, timeout: float = TIMEOUT_S) -> tuple[str, str]:
    """Stop a `start_serve` process as Ctrl-C would; its remaining (stdout, stderr)."""
    proc.send_signal(signal.SIGINT)
    return proc.communicate(timeout=timeout)


def upload(client, *images: tuple[str, bytes, str | None]) -> httpx.Response:
    files = [("files", (name, data, "image/jpeg")) for name, data, _ in images]
    data = {"expected": [e or "" for _, _, e in images]} if any(e is not None for *_, e in images) else None
    return client.post("/api/images", files=files, data=data)


def wait_idle(client, timeout: float = TIMEOUT_S) -> dict:
    """The `GET /api/images` body once no re-run is running and no image is pending."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        body = client.get("/api/images").json()
        if not body["running"] and all(i["status"] != "pending" for i in body["images"]):
            return body
        time.sleep(0.05)
    raise TimeoutError(f"images still being processed after {timeout} s")


def iter_events(stream: httpx.Response, timeout: float = TIMEOUT_S):
    """(kind, JSON payload) of each server-sent event on `stream` (GET /api/events, streamed), as they
    come; TimeoutError when none comes for `timeout` s once asked for. The server's keep-alive pings
    (every 15 s) keep the stream from timing out: an event that never came would be waited for forever."""
    kind, asked = None, time.monotonic()
    for line in stream.iter_lines():
        if line.startswith("event:"):
            kind = line.split(":", 1)[1].strip()
        elif line.startswith("data:"):
            yield kind, json.loads(line.split(":", 1)[1])
            asked = time.monotonic()
        elif time.monotonic() - asked > timeout:
            raise TimeoutError(f"no server-sent event for {timeout:.0f} s")


def wait_done(client) -> list[dict]:
    """The image summaries once no re-run is running or pending."""
    return wait_idle(client)["images"]


# A camera for 4000 x 100 px photos: it fits none of the 640 x 480 test images (another aspect).
MISFIT_CAMERA = {"fx": 3000, "fy": 3000, "cx": 2000, "cy": 50, "width": 4000, "height": 100}


def assert_error(r: httpx.Response, code: int, *words: str) -> None:
    assert r.status_code == code, r.text
    detail = r.json()["detail"]
    assert isinstance(detail, str), detail  # every error, validation included, is one string
    for word in words:
        assert word in detail, f"{word!r} not in {detail!r}"


def http_exchange(base_url: str, head: bytes, chunks=()) -> tuple[int, dict]:
    """Send a raw request head and body chunks; (status, JSON body) of the response, read until the server closes."""
    host, port = base_url.removeprefix("http://").split(":")
    response = b""
    with socket.create_connection((host, int(port)), timeout=TIMEOUT_S) as sock:
        try:
            sock.sendall(head)
            for chunk in chunks:
                sock.sendall(chunk)
        except (BrokenPipeError, ConnectionResetError):  # refused mid-body: the answer is already on its way
            pass
        try:
            while data := sock.recv(65536):
                response += data
        except ConnectionResetError:  # closed with our unsent bytes unread; what arrived is still here
            pass
    status_line, _, body = response.partition(b"\r\n\r\n")
    return int(status_line.split(b" ", 2)[1]), json.loads(body)
