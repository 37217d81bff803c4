"""The one place signpose reaches past viser's public API.

- viser has no public call to run a script in one client's page, which the scene needs to tell a
  viewer its own client id (`app/scene.py`'s `name_viewer`); its plotly support does it with a
  private message on the client's private connection, and so does `run_script` here.
- Under its 576 px breakpoint viser shows its control panel as a sheet at the bottom of the view,
  open whenever it is built, which no call folds (`main_panel.minimize()` folds the floating
  window only); `fold_sheet` clicks its handle in the page, found as viser 1.1 builds it.

A viser release that changes either breaks only this module: `check_private_access()` (run by
tests/test_viser_compat.py) then fails naming the viser version, and `run_script` and `fold_sheet`
log the failure and do nothing, so the 3D view keeps working, less fitted to its screen: without
its id a viewer's page never says its canvas' size in CSS px, so its labels are laid out as if its
screen had one device px to the CSS px and its panel is never folded.
"""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import viser

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
    uses is gone: the script message, with `client` its connection's `queue_message`, and the sheet
    as `fold_sheet` finds it."""
    problems = [p for p in (_script_problem(client), _sheet_problem()) if p is not None]
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
