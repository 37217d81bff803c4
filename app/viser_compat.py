"""The one place signpose reaches past viser's public API.

- viser serves only on TCP, and whatever reaches its port gets the whole scene and its controls: it
  checks no credential, Origin or Host. `start_on_unix_socket` has it listen on a Unix socket
  instead (its `serve` call swapped for `unix_serve` while it binds), so it has no port at all.
- viser takes any file upload whole, in as many parts and of any size a client declares, and
  frees a half-finished one only when its client had registered (sent a first camera report);
  `guard_uploads` refuses what is over the limit and frees every client's parts when it leaves.
- viser has no public call to run a script in one client's page, which the scene needs to tell a
  viewer its own client id (`app/scene.py`'s `name_viewer`); its plotly support does it with a
  private message on the client's private connection, and so does `run_script` here.
- Under its 576 px breakpoint viser shows its control panel as a sheet at the bottom of the view,
  open whenever it is built, which no call folds (`main_panel.minimize()` folds the floating
  window only); `fold_sheet` clicks its handle in the page, found as viser 1.1 builds it.

A viser release that changes any of these breaks only this module: `check_private_access()` (run
by tests/test_viser_compat.py) then fails naming the viser version. At run time `run_script` and
`fold_sheet` log the failure and do nothing, so the 3D view keeps working, less fitted to its
screen: without its id a viewer's page never says its canvas' size in CSS px, so its labels are
laid out as if its screen had one device px to the CSS px and its panel is never folded.
`start_on_unix_socket` raises instead, so `signpose serve` does not start rather than open a port
anyone on the machine can use, and without `guard_uploads` the scene offers no upload.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import inspect
import logging
import threading
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

import viser
import websockets.asyncio.server

log = logging.getLogger(__name__)


# viser's page is laid out for phones below this width, CSS px (Mantine's xs breakpoint, App.tsx).
SHEET_BELOW_PX = 576.0
# viser's sheet as 1.1 builds it (client/src/ControlPanel/BottomPanel.tsx): a Mantine Paper fixed to
# the bottom of the page, its handle (the connection status and buttons) the box whose click
# toggles it. The source ships with viser, so check_private_access() can tell when it changed.
SHEET_SOURCE = Path(viser.__file__).resolve().parent / "client" / "src" / "ControlPanel" / "BottomPanel.tsx"
SHEET_SOURCE_MARKS = ('position: "fixed"', "bottom: 0", 'cursor: "pointer"', "toggleExpanded()",
                      "useDisclosure(true)")
# Run in viser's page: fold its sheet once it is built (viser builds its layout when it likes), at
# most once a sheet, so one the person opened stays open; looked for every 200 ms for 30 s.
FOLD_SHEET_SCRIPT = """
const folded = (window.signposeFoldedSheets ??= new WeakSet());
const until = Date.now() + 30000;
const look = () => {
  const sheet = [...document.querySelectorAll(".mantine-Paper-root")].find((e) => {
    const style = getComputedStyle(e);
    return style.position === "fixed" && style.bottom === "0px";
  });
  if (sheet && folded.has(sheet)) return;
  const handle = sheet && sheet.querySelector('[style*="cursor: pointer"]');
  if (handle) {
    folded.add(sheet);
    handle.title = "3D view controls: click to open or fold";
    handle.click();
  } else if (Date.now() < until) {
    setTimeout(look, 200);
  }
};
look();
"""


class ViserPrivateAccessError(RuntimeError):
    """The installed viser no longer has the private parts this module uses."""


def _unsupported(what: str) -> str:
    return f"viser {viser.__version__} {what} (signpose.app.viser_compat is written against viser 1.1.1)"


def _script_problem(client: viser.ClientHandle | None) -> str | None:
    """What keeps `run_script` from working with this viser (and `client`), or None."""
    try:
        from viser._messages import RunJavascriptMessage
    except ImportError:
        return _unsupported("has no viser._messages.RunJavascriptMessage, which run_script sends")
    if "source" not in getattr(RunJavascriptMessage, "__dataclass_fields__", {}):
        return _unsupported("has a RunJavascriptMessage without the `source` field run_script sets")
    if client is not None and not callable(getattr(getattr(client, "_websock_connection", None),
                                                   "queue_message", None)):
        return _unsupported("has no ClientHandle._websock_connection.queue_message, which run_script uses")
    return None


@functools.cache
def _sheet_problem() -> str | None:
    """What keeps `fold_sheet` from finding viser's sheet, or None."""
    try:
        sheet = SHEET_SOURCE.read_text(encoding="utf-8")
    except OSError:
        return _unsupported(f"ships no {SHEET_SOURCE.name}, whose sheet fold_sheet folds")
    missing = [mark for mark in SHEET_SOURCE_MARKS if mark not in sheet]
    if missing:
        return _unsupported(f"builds its sheet otherwise than fold_sheet finds it: {SHEET_SOURCE.name} "
                            f"lacks {missing}")
    return None


def check_private_access(client: viser.ClientHandle | None = None) -> None:
    """Raise `ViserPrivateAccessError`, naming the installed viser's version, when what this module
    uses is gone: the script message, with `client` its connection's `queue_message`, the sheet as
    `fold_sheet` finds it, the `serve` call `start_on_unix_socket` swaps and what `guard_uploads`
    wraps."""
    problems = [p for p in (_script_problem(client), _sheet_problem(), _unix_socket_problem(), _upload_problem())
                if p is not None]
    if problems:
        raise ViserPrivateAccessError("; ".join(problems))


def run_script(client: viser.ClientHandle, source: str) -> bool:
    """Run the JavaScript `source` in `client`'s page (only there); False, logged, when this viser
    cannot."""
    problem = _script_problem(client)
    if problem is not None:
        log.warning("%s", problem)
        return False
    from viser._messages import RunJavascriptMessage
    client._websock_connection.queue_message(RunJavascriptMessage(source=source))
    return True


def fold_sheet(client: viser.ClientHandle) -> bool:
    """Fold viser's control panel in `client`'s page if it shows it as a sheet (`SHEET_BELOW_PX`),
    once built; False, logged, when this viser cannot."""
    problem = _sheet_problem()
    if problem is not None:
        log.warning("%s", problem)
        return False
    return run_script(client, FOLD_SHEET_SCRIPT)


# The longest path a Unix socket can have on Linux (sun_path is 108 bytes with its NUL).
MAX_SOCKET_PATH_BYTES = 107
# The call viser 1.1's server thread makes to listen (infra/_infra.py, WebsockServer._background_worker),
# looked up through its module's `websockets` when it runs, and what it does once listening.
SERVE_CALL = "websockets.asyncio.server.serve("
SERVE_READY = "ready_sem.release()"
# viser binds in its own thread while ViserServer() waits; one server is started at a time, so the
# swapped `serve` is in place for that one only.
_serve_swap = threading.Lock()


class _Swapped(types.ModuleType):
    """A module as another module sees it, with some of its attributes replaced."""

    def __init__(self, module: types.ModuleType, **replaced: Any) -> None:
        super().__init__(module.__name__)
        self._module = module
        self.__dict__.update(replaced)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._module, name)


@functools.cache
def _unix_socket_problem() -> str | None:
    """What keeps `start_on_unix_socket` from working with this viser, or None."""
    try:
        from viser.infra import _infra
    except ImportError:
        return _unsupported("has no viser.infra._infra, whose serve call start_on_unix_socket swaps")
    if getattr(_infra, "websockets", None) is not websockets:
        return _unsupported("has a viser.infra._infra without the `websockets` start_on_unix_socket swaps")
    worker = getattr(_infra.WebsockServer, "_background_worker", None)
    source = inspect.getsource(worker) if worker is not None else ""
    if SERVE_CALL not in source or SERVE_READY not in source:
        return _unsupported(f"starts its server otherwise than by {SERVE_CALL}...) in "
                            "WebsockServer._background_worker, which start_on_unix_socket swaps")
    return None


def start_on_unix_socket(path: Path) -> viser.ViserServer:
    """A `viser.ViserServer` listening on the Unix socket `path` (which must not exist) and on no
    port. Keep `path` in a directory only this user may enter: the socket checks nothing itself.
    `ViserPrivateAccessError` when this viser cannot be made to (then nothing listens)."""
    problem = _unix_socket_problem()
    if problem is not None:
        raise ViserPrivateAccessError(problem)
    if len(str(path).encode()) > MAX_SOCKET_PATH_BYTES:
        # viser would retry binding forever, and ViserServer() wait for it as long.
        raise ValueError(f"a Unix socket path is at most {MAX_SOCKET_PATH_BYTES} bytes: {path}")
    from viser.infra import _infra

    def serve(handler: Any, _host: str, _port: int, **options: Any) -> Any:
        return websockets.asyncio.server.unix_serve(handler, str(path), **options)

    with _serve_swap:
        _infra.websockets = _Swapped(websockets, asyncio=_Swapped(
            websockets.asyncio, server=_Swapped(websockets.asyncio.server, serve=serve)))
        try:
            server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
        finally:
            _infra.websockets = websockets
    if not path.is_socket():  # a viser that bound otherwise, on a port: close it at once
        server.stop()
        raise ViserPrivateAccessError(_unsupported(f"did not listen on {path} as start_on_unix_socket asked"))
    return server


# What viser 1.1 keeps of an upload in flight (_gui_api.py's _FileUploadState), which guard_uploads reads.
UPLOAD_STATE_KEYS = ("client_id", "filename", "total_bytes", "transferred_bytes")
UPLOAD_HANDLERS = ("_handle_file_transfer_start", "_handle_file_transfer_part", "_drop_uploads_from_client")


@functools.cache
def _upload_problem() -> str | None:
    """What keeps `guard_uploads` from working with this viser, or None."""
    try:
        from viser._gui_api import GuiApi, _FileUploadState
        from viser._messages import FileTransferPart, FileTransferStartUpload
    except ImportError as exc:
        return _unsupported(f"lacks what guard_uploads wraps ({exc})")
    fields = {name: set(getattr(cls, "__dataclass_fields__", {}))
              for name, cls in (("start", FileTransferStartUpload), ("part", FileTransferPart))}
    if not ({"transfer_uuid", "filename", "size_bytes"} <= fields["start"]
            and {"transfer_uuid", "content"} <= fields["part"]):
        return _unsupported(f"has file transfer messages without the fields guard_uploads reads: {fields}")
    missing = [name for name in UPLOAD_HANDLERS if not callable(getattr(GuiApi, name, None))]
    missing += [key for key in UPLOAD_STATE_KEYS if key not in getattr(_FileUploadState, "__annotations__", {})]
    gui_init = inspect.getsource(GuiApi.__init__)
    missing += [f"GuiApi.{name}" for name in ("_current_file_upload_states", "_websock_interface")
                if f"self.{name}" not in gui_init]
    if "self._websock_server = " not in inspect.getsource(viser.ViserServer.__init__):
        missing.append("ViserServer._websock_server")
    if missing:
        return _unsupported(f"handles file uploads otherwise than guard_uploads wraps: no {missing}")
    return None


@functools.cache
def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    return ctypes.CDLL(name) if name else None


def _return_freed_memory() -> None:
    """Hand memory Python has freed back to the system (glibc's malloc_trim), so RSS shows it gone:
    glibc keeps freed blocks as big as upload parts (MBs, above its mmap threshold once one was
    freed) in its heaps otherwise."""
    libc = _libc()
    if libc is not None and hasattr(libc, "malloc_trim"):
        libc.malloc_trim(0)


def guard_uploads(server: viser.ViserServer, *, max_bytes: int,
                  refused: Callable[[int, str], None]) -> bool:
    """Bound the file uploads `server.gui`'s upload buttons take and free what a client leaves.

    A file declared over `max_bytes`, or one that with the client's other unfinished uploads would
    hold more, is refused; so is a part that takes an upload past its declared size (its parts are
    freed). `refused(client_id, why)` is called on viser's event loop; keep it short. When a client
    disconnects its unfinished uploads are freed, registered or not. False, logged, when this viser
    cannot be guarded: then take no uploads through it.
    """
    problem = _upload_problem()
    if problem is not None:
        log.warning("%s", problem)
        return False
    from viser._messages import FileTransferPart, FileTransferStartUpload

    gui: Any = server.gui
    uploads: dict[str, Any] = gui._current_file_upload_states
    start, part = gui._handle_file_transfer_start, gui._handle_file_transfer_part
    uploaders: set[int] = set()   # clients that started an upload since they connected

    def guarded_start(client_id: int, message: FileTransferStartUpload) -> None:
        held = sum(state["total_bytes"] for state in uploads.values() if state["client_id"] == client_id)
        if message.size_bytes > max_bytes:
            refused(client_id, f"{message.filename} has {message.size_bytes / 1e6:.1f} MB; this server "
                               f"takes files up to {max_bytes / 1e6:.1f} MB (signpose serve --max-upload-mb)")
        elif held + message.size_bytes > max_bytes:
            refused(client_id, f"{message.filename} and the {held / 1e6:.1f} MB still being uploaded are more "
                               f"than the {max_bytes / 1e6:.1f} MB this server takes at once; reload the page "
                               "to drop unfinished uploads")
        else:
            uploaders.add(client_id)
            start(client_id, message)

    def guarded_part(client_id: int, message: FileTransferPart) -> None:
        state = uploads.get(message.transfer_uuid)
        if state is not None and state["transferred_bytes"] + len(message.content) > state["total_bytes"]:
            del uploads[message.transfer_uuid]
            _return_freed_memory()
            refused(client_id, f"{state['filename']} sent more than the {state['total_bytes']} bytes it declared")
            return
        part(client_id, message)

    def free_uploads(connection: Any) -> None:
        # viser's own disconnect handler, which runs first, frees them only for a client that sent
        # a camera report; and neither hands their memory back.
        if connection.client_id in uploaders:
            uploaders.discard(connection.client_id)
            gui._drop_uploads_from_client(connection.client_id)
            _return_freed_memory()

    handlers = gui._websock_interface
    for message_type, original, guarded in ((FileTransferStartUpload, start, guarded_start),
                                            (FileTransferPart, part, guarded_part)):
        handlers.unregister_handler(message_type, original)
        handlers.register_handler(message_type, guarded)
    server._websock_server.on_client_disconnect(free_uploads)
    return True
