"""viser behind `signpose serve`, against a real `signpose serve`: reachable only through the
relayed, token-checked `/viser`, its uploads bounded and freed, garbage from a browser logged once.
"""

from __future__ import annotations

import os
import re
import stat
import time
import uuid
from pathlib import Path

import cv2
import httpx
import msgspec
import numpy as np
import pytest
import zstandard
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import ClientConnection, connect

from tests.support.serving import TIMEOUT_S, VISER_PROTOCOL, start_serve, stop_serve

TOKEN = "team-token-for-tests"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
MAX_UPLOAD_MB = 150
PART_BYTES = 10_000_000   # under uvicorn's 16 MiB websocket frame limit
LISTEN = "0A"             # a TCP socket's state in /proc/net/tcp: listening

pytestmark = pytest.mark.server


@pytest.fixture(scope="module")
def serve(tmp_path_factory):
    """(process, base URL) of `signpose serve` on every interface with a token, as a team would run it."""
    proc, url = start_serve(tmp_path_factory.mktemp("viser-private") / "state", "--host", "0.0.0.0",
                            "--token", TOKEN, "--max-upload-mb", str(MAX_UPLOAD_MB))
    port = int(re.search(r":(\d+)/", url).group(1))
    yield proc, started(f"http://127.0.0.1:{port}", AUTH)
    stop_serve(proc)


def started(base: str, headers: dict | None = None) -> str:
    """`base` once its server answers: its lifespan, which starts viser, has run."""
    assert httpx.get(base + "/api/health", headers=headers, timeout=TIMEOUT_S).status_code == 200
    return base


def socket_inodes(pid: int) -> set[int]:
    """The inodes of the sockets process `pid` holds open."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:  # closed meanwhile
            continue
        if target.startswith("socket:["):
            inodes.add(int(target[8:-1]))
    return inodes


def listening_tcp_ports(pid: int) -> set[int]:
    """Every TCP port, IPv4 or IPv6, that process `pid` listens on."""
    inodes, ports = socket_inodes(pid), set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] == LISTEN and int(fields[9]) in inodes:
                ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    return ports


def unix_socket_paths(pid: int) -> list[Path]:
    """The paths of the Unix sockets process `pid` listens on."""
    inodes = socket_inodes(pid)
    return [Path(fields[7]) for line in Path("/proc/net/unix").read_text().splitlines()[1:]
            for fields in [line.split()] if len(fields) > 7 and int(fields[6]) in inodes and fields[7][0] == "/"]


def viser_messages(frame: bytes) -> list[dict]:
    """The messages in one frame viser sent: two lengths, zstd-compressed msgpack, binary buffers."""
    size = int.from_bytes(frame[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(frame[16:16 + size])
    return msgspec.msgpack.decode(inner)["messages"]


def receive_until(ws: ClientConnection, found, timeout: float = TIMEOUT_S) -> dict:
    """The first message viser sends on `ws` for which `found(message)` holds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for message in viser_messages(ws.recv(timeout=deadline - time.monotonic())):
            if found(message):
                return message
    raise TimeoutError("viser did not send it")


def send(ws: ClientConnection, kind: str, **fields) -> None:
    """Send a message as viser's client does: msgpack, its type's name under "type"."""
    ws.send(msgspec.msgpack.encode({"type": kind, **fields}))


def open_viewer(base: str) -> tuple[ClientConnection, str]:
    """A viser client through the relay, and the uuid of the scene's "Add image" button."""
    ws = connect(base.replace("http://", "ws://") + "/viser", subprotocols=[VISER_PROTOCOL], additional_headers=AUTH,
                 max_size=None, open_timeout=10)
    button = receive_until(ws, lambda m: m["type"] == "GuiUploadButtonMessage")
    return ws, button["uuid"]


def register(ws: ClientConnection) -> None:
    """Register with viser as the page's viewer does, with its first camera report: only then is it
    told anything, or are its uploads taken."""
    send(ws, "ViewerCameraMessage", wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, -3.0), fov=1.0, near=0.01,
         far=100.0, image_height=480, image_width=640, look_at=(0.0, 0.0, 0.0), up_direction=(0.0, -1.0, 0.0))


def start_upload(ws: ClientConnection, button: str, *, size: int, parts: int) -> str:
    transfer = str(uuid.uuid4())
    send(ws, "FileTransferStartUpload", source_component_uuid=button, transfer_uuid=transfer, filename="big.jpg",
         mime_type="image/jpeg", part_count=parts, size_bytes=size)
    return transfer


def rss_mb(pid: int) -> float:
    status = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"VmRSS:\s+(\d+) kB", status).group(1)) / 1000


def test_nothing_but_the_public_port_listens_and_it_refuses_strangers(serve):
    proc, base = serve
    public = int(base.rsplit(":", 1)[1])
    ports = listening_tcp_ports(proc.pid)
    assert ports == {public}, f"signpose serve listens on {sorted(ports)}, not only on its own port {public}"
    for port in ports:
        for path in ("/", "/viser", "/viser/"):
            with pytest.raises(InvalidStatus) as refused:
                connect(f"ws://127.0.0.1:{port}{path}", origin="http://evil.example",
                        subprotocols=[VISER_PROTOCOL], open_timeout=10)
            assert refused.value.response.status_code in (401, 403), (port, path)
            page = httpx.get(f"http://127.0.0.1:{port}{path}", headers={"Host": "evil.example"}, timeout=TIMEOUT_S)
            assert page.status_code in (401, 403), (port, path, page.status_code)
            assert "<title>Viser</title>" not in page.text
    # viser itself listens on a Unix socket in a directory only this user may enter
    [viser_socket] = unix_socket_paths(proc.pid)
    folder = viser_socket.parent.stat()
    assert stat.S_IMODE(folder.st_mode) == 0o700 and folder.st_uid == os.getuid(), viser_socket
    # and the token-bearing relay still reaches it
    ws, _button = open_viewer(base)
    ws.close()


@pytest.mark.parametrize("registered", [False, True])
def test_a_half_finished_upload_is_freed_when_its_client_leaves(serve, registered):
    """A client declares a big upload, sends part of it and leaves: what it sent is freed, whether
    it registered with viser (the page's viewer, a closed tab) or not (a script)."""
    proc, base = serve
    ws, button = open_viewer(base)
    transfer = start_upload(ws, button, size=12 * PART_BYTES, parts=12)
    ws.send(msgspec.msgpack.encode({"type": "FileTransferPart", "source_component_uuid": button,
                                    "transfer_uuid": transfer, "part_index": 0, "content": b"\0" * 1000}))
    receive_until(ws, lambda m: m["type"] == "FileTransferPartAck")   # warm: the relay, viser's handlers
    ws.close()
    time.sleep(1)
    before = rss_mb(proc.pid)
    ws, button = open_viewer(base)
    if registered:
        register(ws)
    transfer = start_upload(ws, button, size=12 * PART_BYTES, parts=12)
    for index in range(10):
        send(ws, "FileTransferPart", source_component_uuid=button, transfer_uuid=transfer, part_index=index,
             content=os.urandom(PART_BYTES))
        receive_until(ws, lambda m: m["type"] == "FileTransferPartAck")
    held = rss_mb(proc.pid)
    assert held > before + 80, (before, held)   # the parts are held while the upload runs
    ws.close()
    deadline = time.monotonic() + 10
    while rss_mb(proc.pid) > before + 50 and time.monotonic() < deadline:
        time.sleep(0.2)
    assert rss_mb(proc.pid) <= before + 50, (before, held, rss_mb(proc.pid))


def test_an_upload_over_the_limit_is_refused_with_a_message(serve):
    _proc, base = serve
    ws, button = open_viewer(base)
    register(ws)

    def notice(message: dict) -> bool:
        return message["type"] == "NotificationShowMessage" and message["props"]["title"] == "Image not added"

    start_upload(ws, button, size=(MAX_UPLOAD_MB + 1) * 1_000_000, parts=20)
    body = receive_until(ws, notice)["props"]["body"]
    assert "big.jpg has 151.0 MB" in body and f"up to {MAX_UPLOAD_MB:.1f} MB" in body, body
    # one that sends more than it declared is dropped the same way
    transfer = start_upload(ws, button, size=100, parts=2)
    send(ws, "FileTransferPart", source_component_uuid=button, transfer_uuid=transfer, part_index=0,
         content=b"\0" * 101)
    body = receive_until(ws, notice)["props"]["body"]
    assert "sent more than the 100 bytes it declared" in body, body
    ws.close()


def test_a_garbage_frame_is_logged_in_one_line(tmp_path):
    proc, url = start_serve(tmp_path / "state")
    base = started(url.split("?")[0].rstrip("/"))
    [viser_socket] = unix_socket_paths(proc.pid)
    try:
        for garbage in (b"\x00not msgpack", msgspec.msgpack.encode({"type": "NoSuchMessage"}), "text"):
            with connect(base.replace("http://", "ws://") + "/viser", subprotocols=[VISER_PROTOCOL],
                         max_size=None, open_timeout=10) as ws:
                ws.send(garbage)
                with pytest.raises(ConnectionClosed) as closed:
                    while True:
                        ws.recv(timeout=TIMEOUT_S)
            assert closed.value.rcvd.code == 1003
    finally:
        _out, err = stop_serve(proc)
    lines = [line for line in err.splitlines() if "/viser websocket" in line]
    assert len(lines) == 3 and "Traceback" not in err, err
    assert not viser_socket.parent.exists()   # removed at shutdown


def test_an_upload_within_the_limit_adds_the_image(serve):
    """What the "Add image" button sends, in parts as viser's client cuts it, passes the guard."""
    _proc, base = serve
    _ok, jpeg = cv2.imencode(".jpg", np.full((120, 160, 3), 128, np.uint8))
    content = jpeg.tobytes()
    before = len(httpx.get(base + "/api/images", headers=AUTH, timeout=TIMEOUT_S).json()["images"])
    ws, button = open_viewer(base)
    register(ws)
    transfer = start_upload(ws, button, size=len(content), parts=2)
    half = len(content) // 2
    for index, chunk in enumerate((content[:half], content[half:])):
        send(ws, "FileTransferPart", source_component_uuid=button, transfer_uuid=transfer, part_index=index,
             content=chunk)
    deadline = time.monotonic() + TIMEOUT_S
    while len(httpx.get(base + "/api/images", headers=AUTH, timeout=TIMEOUT_S).json()["images"]) == before:
        assert time.monotonic() < deadline, "the uploaded image was not added"
        time.sleep(0.1)
    ws.close()
