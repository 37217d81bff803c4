"""viser's browser client at `/viser/` on the FastAPI port, its websocket relayed to viser's private port.

viser 1.1 serves its client and websocket from its own server (the `websockets` library) and has
no ASGI mount, so FastAPI serves the client's build files and relays the websocket. The client
connects to its page's own URL with http -> ws and the trailing slash dropped (the page
`/viser/` connects to `ws://<host>/viser`), offering the subprotocol `viser-v<version>` that
viser checks; both `/viser` and `/viser/` are relayed. Its page gets one script of ours,
`CANVAS_SCRIPT`.
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import viser
import websockets
from fastapi import FastAPI, WebSocket
from fastapi.responses import HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from starlette.websockets import WebSocketDisconnect
from websockets.asyncio.client import connect
from websockets.typing import Subprotocol

log = logging.getLogger(__name__)

VISER_CLIENT_BUILD = Path(viser.__file__).resolve().parent / "client" / "build"
# viser itself accepts messages up to 50 MB (scene images, point clouds); so must the relay.
MAX_MESSAGE_BYTES = 50 * 1024 * 1024
CONNECT_TIMEOUT_S = 5.0
# Close codes: 1011 "internal error" when viser cannot be reached or vanished; 1000 otherwise.
# 1005, 1006 and 1015 only report what happened and must never be sent.
UNREACHABLE, NORMAL = 1011, 1000
UNSENDABLE = (1005, 1006, 1015)
# The page's static/viser-canvas.js: it tells the server how many device px viser's canvas has to
# the CSS px, which viser's client does not, in the page's 3D view and in its pop-out tab alike.
CANVAS_SCRIPT = '<script src="/viser-canvas.js" defer></script>'


async def relay(websocket: WebSocket, upstream_url: str) -> None:
    """Connect to viser at `upstream_url` with the client's subprotocols, then copy messages both ways.

    Whichever side closes first closes the other, with its close code and reason.
    """
    offered = [Subprotocol(p) for p in websocket.scope.get("subprotocols", [])]
    try:
        upstream = await connect(upstream_url, subprotocols=offered or None, max_size=MAX_MESSAGE_BYTES,
                                 compression=None, open_timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, websockets.exceptions.InvalidHandshake) as exc:
        log.warning("viser websocket at %s unreachable: %s", upstream_url, exc)
        await websocket.close(code=UNREACHABLE, reason="the viser server is not reachable")
        return
    await websocket.accept(subprotocol=upstream.subprotocol)

    async def browser_to_viser() -> None:
        try:
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    return
                await upstream.send(message["bytes"] if message.get("bytes") is not None else message["text"])
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
    """Serve viser's client at `/viser/` and relay its websocket to `app.state.viser_url`.

    Call after the API routes: the websocket routes must precede the static mount, which would
    otherwise claim `/viser/` for websockets too.
    """

    async def viser_websocket(websocket: WebSocket) -> None:
        await relay(websocket, websocket.app.state.viser_url)

    for path in ("/viser", "/viser/"):
        app.add_api_websocket_route(path, viser_websocket, name="viser websocket")
    # Relative URLs in the page resolve against /viser/, not /.
    app.add_api_route("/viser", lambda: RedirectResponse("/viser/"), include_in_schema=False)
    page = (VISER_CLIENT_BUILD / "index.html").read_text(encoding="utf-8").replace(
        "</head>", f"{CANVAS_SCRIPT}</head>", 1)
    app.add_api_route("/viser/", lambda: HTMLResponse(page), include_in_schema=False)
    app.mount("/viser", StaticFiles(directory=VISER_CLIENT_BUILD, html=True), name="viser")
