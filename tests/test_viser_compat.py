"""signpose's only reach past viser's public API (app/viser_compat.py): still there in the viser
installed, and nowhere else. A viser upgrade that breaks it fails here, naming the version."""

from __future__ import annotations

import inspect
import re
import types
from pathlib import Path

import pytest
import viser
from signpose.app import viser_compat
from signpose.app.scene import FOLD_PANEL_BELOW_PX, fold_panel_in_small_view, panel_covers_view
from signpose.app.viser_compat import (
    FOLD_SHEET_SCRIPT,
    SHEET_BELOW_PX,
    ViserPrivateAccessError,
    check_private_access,
    fold_sheet,
    guard_uploads,
    run_script,
    start_on_unix_socket,
)

ROOT = Path(__file__).resolve().parents[1]
# What only app/viser_compat.py may use: viser's private modules and a client's private connection.
PRIVATE = re.compile(r"\bviser\._(?!_)\w+|from viser\._|from viser import _|\._websock_connection\b")


class Client:
    """A viser client as viser_compat and the scene see it: the messages queued on its connection,
    its main panel's minimise calls, its camera's aspect (width / height)."""

    def __init__(self, aspect: float = 1.0):
        self.queued: list = []
        self.minimized = 0
        self._websock_connection = types.SimpleNamespace(queue_message=self.queued.append)
        self.gui = types.SimpleNamespace(main_panel=types.SimpleNamespace(minimize=self._minimize))
        self.camera = types.SimpleNamespace(aspect=aspect)
        self.client_id = 7

    def _minimize(self) -> None:
        self.minimized += 1


def test_the_installed_viser_has_what_viser_compat_uses():
    """Fails, naming viser's version, once a viser release renames its script message or the
    client's connection, or builds its phone sheet otherwise (its source ships with viser)."""
    check_private_access()
    # and the scene's call on viser's newest API surface ("may still evolve", its docs say)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        assert callable(getattr(server.gui.main_panel, "minimize", None)), (
            f"viser {viser.__version__} has no gui.main_panel.minimize(), which app/scene.py calls")
    finally:
        server.stop()
    # A ClientHandle needs a browser connected; its constructor must still keep the connection there.
    assert "self._websock_connection = " in inspect.getsource(viser.ClientHandle.__init__), (
        f"viser {viser.__version__}'s ClientHandle keeps no _websock_connection, which "
        "signpose.app.viser_compat.run_script queues on (written against viser 1.1.1)")


def test_a_viser_without_it_is_named(monkeypatch):
    with monkeypatch.context() as patched:
        patched.setattr(viser_compat, "SHEET_SOURCE_MARKS", ("no such mark",))
        viser_compat._sheet_problem.cache_clear()
        try:
            with pytest.raises(ViserPrivateAccessError, match=re.escape(f"viser {viser.__version__} ")):
                check_private_access()
            assert not fold_sheet(Client())   # logged, nothing sent: the view works on, its sheet open
        finally:
            viser_compat._sheet_problem.cache_clear()
    with pytest.raises(ViserPrivateAccessError, match="_websock_connection"):
        check_private_access(types.SimpleNamespace())
    assert not run_script(types.SimpleNamespace(), "1")


def test_viser_on_a_unix_socket_listens_there_only(tmp_path):
    server = start_on_unix_socket(tmp_path / "viser.sock")
    try:
        assert (tmp_path / "viser.sock").is_socket()
        assert guard_uploads(server, max_bytes=1000, refused=lambda client_id, why: None)
    finally:
        server.stop()


def test_a_viser_that_serves_or_uploads_otherwise_is_named(monkeypatch, tmp_path):
    """Then nothing listens rather than an open port, and no upload is taken rather than an
    unbounded one."""
    for name, marks, problem in (("SERVE_CALL", "no such call(", viser_compat._unix_socket_problem),
                                 ("UPLOAD_STATE_KEYS", ("no such key",), viser_compat._upload_problem)):
        with monkeypatch.context() as patched:
            patched.setattr(viser_compat, name, marks)
            problem.cache_clear()
            try:
                with pytest.raises(ViserPrivateAccessError, match=re.escape(f"viser {viser.__version__} ")):
                    check_private_access()
                if name == "SERVE_CALL":
                    with pytest.raises(ViserPrivateAccessError):
                        start_on_unix_socket(tmp_path / "viser.sock")
                    assert not (tmp_path / "viser.sock").exists()
                else:
                    assert not guard_uploads(types.SimpleNamespace(), max_bytes=1, refused=lambda client_id, why: None)
            finally:
                problem.cache_clear()


def test_run_script_queues_it_on_that_client_only():
    client = Client()
    assert run_script(client, "window.x = 1;")
    [message] = client.queued
    assert type(message).__name__ == "RunJavascriptMessage" and message.source == "window.x = 1;"


def test_only_viser_compat_reaches_past_visers_public_api():
    """In the code that runs (tests fake a client's connection for viser_compat)."""
    found = [f"{path.relative_to(ROOT)}:{text.count(chr(10), 0, match.start()) + 1}"
             for folder in ("app", "pipeline", "bench", "tools") for path in sorted((ROOT / folder).glob("**/*.py"))
             if path != ROOT / "app" / "viser_compat.py"
             for text in [path.read_text(encoding="utf-8")] for match in PRIVATE.finditer(text)]
    assert not found, f"viser's private parts used outside app/viser_compat.py at {found}"


@pytest.mark.parametrize("width, height, folded", [
    (400, 800, "sheet"),        # the page's 3D column on most screens: viser's phone layout
    (700, 1300, "window"),      # the column on a 2560 px screen
    (1200, 360, "window"),      # the strip under the images
    (1280, 620, None),          # the pop-out tab on a laptop's screen
    (1900, 950, None),          # and on a larger one
    (1000, 400, "window"),      # in a low window
])
def test_the_panel_is_folded_in_small_views(width, height, folded):
    client = Client(aspect=width / height)
    if panel_covers_view(client, float(width)):
        fold_panel_in_small_view(client, float(width))
    assert client.minimized == (folded == "window")
    assert [m.source for m in client.queued] == ([FOLD_SHEET_SCRIPT] if folded == "sheet" else [])
    assert (width < SHEET_BELOW_PX) == (folded == "sheet")
    assert (folded is None) == (width >= FOLD_PANEL_BELOW_PX[0] and height >= FOLD_PANEL_BELOW_PX[1])
