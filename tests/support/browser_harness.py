"""Run `signpose serve` and Debian's Chromium (through Playwright) for the browser tests and
tools/screenshot.py. Never downloads a browser: without /usr/bin/chromium the callers skip."""

from __future__ import annotations

import contextlib
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from tests.support.serving import wait_idle

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                 "--disable-background-networking"]
SCENES = ROOT / "sample_images" / "scenes"
VIEWPORT = {"width": 1600, "height": 1000}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(state_dir: Path, log_path: Path, timeout: float = 300, port: int | None = None, options: tuple[str, ...] = ()):
    """`signpose serve` on `port` (default: a free loopback port) with more command-line `options`; yields its
    base URL once /api/health answers (which is after the sample scenes a fresh state starts with have been
    processed)."""
    port = port or free_port()
    base = f"http://127.0.0.1:{port}"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "signpose.app.cli", "serve", "--port", str(port),
             "--state-dir", str(state_dir), *options],
            cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        try:
            deadline = time.monotonic() + timeout
            while True:
                if proc.poll() is not None:
                    raise RuntimeError(f"signpose serve exited with {proc.returncode}:\n{log_path.read_text()[-3000:]}")
                try:
                    if httpx.get(f"{base}/api/health", timeout=2).json()["status"] == "ok":
                        break
                except httpx.HTTPError:
                    pass
                if time.monotonic() > deadline:
                    raise RuntimeError(f"signpose serve not healthy after {timeout:.0f} s:\n"
                                       f"{log_path.read_text()[-3000:]}")
                time.sleep(0.2)
            yield base
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


# The viser client's scene tree (viser's page, the tool's iframe): each node under a name prefix, with its
# message type, its point count (line segments), where it is (its Three.js object, else the pose the
# server last sent) and whether it is shown.
SCENE_NODES = """prefix => {
    const m = window.__viserMutable, tree = window.__viserSceneTree.getState();
    const nodes = {};
    for (const [name, node] of Object.entries(tree)) {
        if (!name.startsWith(prefix)) continue;
        const object = m.nodeRefFromName[name];
        nodes[name] = {
            type: node.message.type,
            points: node.message.props.points?.length ?? null,
            position: object ? object.position.toArray() : (m.nodePoseData[name]?.position ?? null),
            visible: node.effectiveVisibility ?? null,
        };
    }
    return nodes;
}"""


def scene_nodes(frame, prefix: str) -> dict[str, dict]:
    """By name, the nodes of the viser client in `frame` (a Playwright frame of /viser/) whose names start
    with `prefix`, as SCENE_NODES gives them."""
    return frame.evaluate(SCENE_NODES, prefix)


def skip_without_chromium() -> None:
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} not found: install Debian's chromium to run the browser tests")


@contextlib.contextmanager
def page_of(base: str):
    """A fresh page of the tool at `base` in its own Chromium (`open_page`), closed after (`close_page`:
    failing on the page's errors)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = launch(p)
        page = open_page(browser, base)
        yield page
        close_page(page)
        browser.close()


def launch(playwright):
    return playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)


def open_page(browser, base: str, device_scale_factor: float = 1):
    """The tool's page, loaded, with page errors and Content-Security-Policy refusals (in the page
    or the viser iframe) collected in `page.errors`; on a screen of `device_scale_factor` device
    pixels to the CSS px."""
    page = browser.new_page(viewport=VIEWPORT, device_scale_factor=device_scale_factor)
    page.errors = []
    page.on("pageerror", lambda exc: page.errors.append(str(exc)))
    page.on("console", lambda msg: msg.type == "error" and "Content Security Policy" in msg.text
            and page.errors.append(msg.text))
    page.goto(f"{base}/")
    page.wait_for_selector("#settings-form .field")
    return page


def close_page(page) -> None:
    """Close a page from `open_page`; fails if it collected errors."""
    errors = page.errors
    page.close()
    assert not errors, f"uncaught errors in the page: {errors}"


FAILED = pytest.StashKey[bool]()


class SharedPage:
    """One page of the tool for a module's tests, set back between them to what a test may assume
    of a page it did not open: no request routed, the first viewport, no dialog open, the page
    scrolled to the top, no message (toast) on show, no errors collected. The detail shown and the server's state carry over,
    as they do for a person who keeps the tab open."""

    def __init__(self, browser, base: str) -> None:
        self.browser, self.base = browser, base
        self.page = None

    def take(self):
        if self.page is None or self.page.is_closed():
            self.page = open_page(self.browser, self.base)
            return self.page
        page = self.page
        page.unroute_all(behavior="ignoreErrors")
        page.set_viewport_size(VIEWPORT)
        if page.url.split("#")[0].rstrip("/") != self.base:
            page.goto(f"{self.base}/")
            page.wait_for_selector("#settings-form .field")
        page.evaluate("""() => { for (const d of document.querySelectorAll('dialog[open]')) d.close();
                                 for (const t of document.querySelectorAll('.toast')) t.remove();
                                 document.activeElement?.blur(); window.scrollTo(0, 0); }""")
        return page

    def give_back(self, *, failed: bool) -> None:
        """After a test: fails it if the page collected errors; a page a test failed on is not reused."""
        page, errors = self.page, list(self.page.errors) if self.page is not None else []
        if page is not None and (failed or errors or page.is_closed()):
            self.close()
        elif page is not None:
            page.errors.clear()
        assert not errors, f"uncaught errors in the page: {errors}"

    def close(self) -> None:
        if self.page is not None and not self.page.is_closed():
            self.page.close()
        self.page = None


def upload(page, files: list[Path], expected: str = "") -> None:
    """Add images through the file picker, labelled `expected` ("" = unlabelled), and wait for their cards."""
    page.select_option("#expected", expected)
    page.set_input_files("#file-picker", [str(f) for f in files])
    wait_cards(page, [f.name for f in files])


def wait_cards(page, names: list[str]) -> None:
    """Until the gallery has a card with a result for each of `names`.

    By name, not by count: the cards of images already on the server may still be arriving."""
    page.wait_for_function(
        """names => names.every(n => [...document.querySelectorAll('.card:not([data-status=pending]) .card-name')]
                                        .some((e) => e.textContent === n))""",
        arg=names, timeout=120_000)


def card(page, name: str):
    """The gallery card of the image called `name`."""
    return page.locator(".card").filter(has=page.locator(".card-name", has_text=re.compile(f"^{re.escape(name)}$")))


def set_setting(page, name: str, value) -> None:
    """Change one setting through its form control, as a user would."""
    control = page.locator(f"#set-{name}")
    if isinstance(value, bool):
        control.set_checked(value)
    else:
        control.fill(str(value))
        control.dispatch_event("change")


def set_settings(page, api, changes: dict) -> None:
    """Change each of `changes` through its form control, in order, then wait for the server and
    the page to hold all of them (`wait_setting`)."""
    for name, value in changes.items():
        set_setting(page, name, value)
    wait_setting(page, api, changes)


def wait_until(page, condition, what: str, timeout: float = 30) -> None:
    """Let the page run until `condition()` holds (Playwright calls route and dialog handlers only
    while the test waits on it); fail saying `what` did not happen after `timeout` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what} did not happen within {timeout:g} s")
        page.wait_for_timeout(20)


def wait_server_idle(api, timeout: float = 120) -> int:
    """Until every image has a result for the current settings; returns that settings version.

    `api`: an httpx.Client on the server's base URL.
    """
    return wait_idle(api, timeout)["version"]


def wait_setting(page, api, expected: dict, timeout: float = 120) -> None:
    """Until the server holds `expected` settings, has re-run every image under them, and the
    page's gallery shows those results."""
    deadline = time.monotonic() + timeout
    while True:
        current = api.get("/api/settings").json()["settings"]
        if all(current[k] == v for k, v in expected.items()):
            break
        if time.monotonic() > deadline:
            raise TimeoutError(f"server settings never became {expected}; last: "
                               f"{ {k: current[k] for k in expected} }")
        time.sleep(0.05)
    version = wait_server_idle(api, timeout)
    page.wait_for_function(
        "v => [...document.querySelectorAll('.card')].every(c => Number(c.dataset.version) >= v"
        " && c.dataset.status !== 'pending')", arg=version, timeout=timeout * 1000)


def stage_images_loaded(page, selector: str) -> list[dict]:
    """name + naturalWidth of every <img> under `selector`, once each has finished loading or failing."""
    page.wait_for_function(
        "s => [...document.querySelectorAll(s)].every(i => i.complete)", arg=selector, timeout=30_000)
    return page.eval_on_selector_all(selector, "imgs => imgs.map(i => ({src: i.src, w: i.naturalWidth}))")
