"""viser's browser client at `/viser/` on the FastAPI port, its websocket relayed to viser's Unix socket.

viser 1.1 serves its client and websocket from its own server (the `websockets` library) and has
no ASGI mount, so FastAPI serves the client's build files and relays the websocket. The client
connects to its page's own URL with http -> ws and the trailing slash dropped (the page
`/viser/` connects to `ws://<host>/viser`), offering the subprotocol `viser-v<version>` that
viser checks; both `/viser` and `/viser/` are relayed. Its page gets one script of ours,
`CANVAS_SCRIPT`.

viser itself checks no token, Origin or Host: whoever reaches it gets the scene (every photo's
thumbnail and pose) and its controls. So it listens on no port at all but on a Unix socket in a
directory only this user may enter (`PrivateViser`), and the relay, behind the app's AccessGuard,
is the only way in. That is sturdier than a port with a per-start secret the relay presents: a
secret must be checked before viser handles anything, HTTP requests for its page too, by code
wrapped around viser's own, and one check it misses (a new route, a handshake path) opens the
scene to every web page the user visits and every local user, while a Unix socket is out of a
browser's reach altogether and its directory's mode is enforced by the kernel.

The relay passes on only frames viser can read: a text frame or bytes that are no viser message
close the connection (1003) with one log line, where viser would write a traceback per frame.
"""

from __future__ import annotations

import asyncio
import logging
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import viser
import websockets
from fastapi import FastAPI, WebSocket
from fastapi.responses import HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from starlette.websockets import WebSocketDisconnect
from websockets.asyncio.client import unix_connect
from websockets.typing import Subprotocol

from .viser_compat import start_on_unix_socket

log = logging.getLogger(__name__)

VISER_CLIENT_BUILD = Path(viser.__file__).resolve().parent / "client" / "build"
# viser itself accepts messages up to 50 MB (scene images, point clouds); so must the relay.
MAX_MESSAGE_BYTES = 50 * 1024 * 1024
CONNECT_TIMEOUT_S = 5.0
# Close codes: 1011 "internal error" when viser cannot be reached or vanished; 1003 "unsupported
# data" for a frame that is no viser message; 1000 otherwise. 1005, 1006 and 1015 only report what
# happened and must never be sent.
UNREACHABLE, UNREADABLE, NORMAL = 1011, 1003, 1000
UNSENDABLE = (1005, 1006, 1015)
# The page's static/viser-canvas.js: it tells the server how many device px viser's canvas has to
# the CSS px, which viser's client does not, in the page's 3D view and in its pop-out tab alike.
CANVAS_SCRIPT = '<script src="/viser-canvas.js" defer></script>'


@dataclass(frozen=True)
class PrivateViser:
    """A viser server listening on `socket_path` only, in a directory of its own (mode 0700)."""

    server: viser.ViserServer
    socket_path: Path

    @classmethod
    def start(cls) -> PrivateViser:
        folder = Path(tempfile.mkdtemp(prefix="signpose-viser-"))  # mode 0700, a new name each time
        try:
            return cls(start_on_unix_socket(folder / "viser.sock"), folder / "viser.sock")
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise

    def stop(self) -> None:
        self.server.stop()
        shutil.rmtree(self.socket_path.parent, ignore_errors=True)


def unreadable(data: bytes | str) -> str | None:
    """Why viser could not read the frame `data` from a browser, or None when it can."""
    if isinstance(data, str):
        return "a text frame"
    try:
        viser.infra.Message.deserialize(data)
    except (ValueError, KeyError, TypeError, AttributeError, RecursionError) as exc:
        # not msgpack, nested past its depth limit, no or an unknown type, wrong fields
        return f"{type(exc).__name__}: {str(exc)[:80]}"
    return None


async def relay(websocket: WebSocket, socket_path: Path) -> None:
    """Connect to viser on the Unix socket `socket_path` with the client's subprotocols, then copy
    messages both ways.

    Whichever side closes first closes the other, with its close code and reason. A frame from the
    browser that viser cannot read closes both, logged in one line.
    """
    offered = [Subprotocol(p) for p in websocket.scope.get("subprotocols", [])]
    try:
        upstream = await unix_connect(str(socket_path), uri="ws://localhost/", subprotocols=offered or None,
                                      max_size=MAX_MESSAGE_BYTES, compression=None, open_timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, websockets.exceptions.InvalidHandshake) as exc:
        log.warning("viser websocket at %s unreachable: %s", socket_path, exc)
        await websocket.close(code=UNREACHABLE, reason="the viser server is not reachable")
        return
    await websocket.accept(subprotocol=upstream.subprotocol)

    async def browser_to_viser() -> None:
        try:
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    return
                data = message["bytes"] if message.get("bytes") is not None else message["text"]
                why = unreadable(data)
                if why is not None:
                    client = websocket.client
                    log.warning("closed a /viser websocket from %s: it sent no viser message (%s)",
                                f"{client.host}:{client.port}" if client else "?", why)
                    await websocket.close(code=UNREADABLE, reason="not a viser message")
                    return
                await upstream.send(data)
        except websockets.exceptions.ConnectionClosed:
            return

    async def viser_to_browser() -> None:
        try:
            async for data in upstream:
                if isinstance(data, bytes):
                    await websocket.send_bytes(data)
                else:
                    await websocket.send_text(data)
        except websockets.exceptions.ConnectionClosed:
            pass
        except (WebSocketDisconnect, RuntimeError):  # the browser left while we were sending
            return
        code = upstream.close_code or NORMAL
        await websocket.close(code=UNREACHABLE if code in UNSENDABLE else code, reason=upstream.close_reason or "")

    async with upstream:
        tasks = [asyncio.create_task(browser_to_viser()), asyncio.create_task(viser_to_browser())]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)


def mount_viser(app: FastAPI) -> None:
    """Serve viser's client at `/viser/` and relay its websocket to `app.state.viser_socket`.

    Call after the API routes: the websocket routes must precede the static mount, which would
    otherwise claim `/viser/` for websockets too.
    """

    async def viser_websocket(websocket: WebSocket) -> None:
        await relay(websocket, websocket.app.state.viser_socket)

    for path in ("/viser", "/viser/"):
        app.add_api_websocket_route(path, viser_websocket, name="viser websocket")
    # Relative URLs in the page resolve against /viser/, not /.
    app.add_api_route("/viser", lambda: RedirectResponse("/viser/"), include_in_schema=False)
    page = (VISER_CLIENT_BUILD / "index.html").read_text(encoding="utf-8").replace(
        "</head>", f"{CANVAS_SCRIPT}</head>", 1)
    app.add_api_route("/viser/", lambda: HTMLResponse(page), include_in_schema=False)
    app.mount("/viser", StaticFiles(directory=VISER_CLIENT_BUILD, html=True), name="viser")
