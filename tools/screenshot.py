"""Render docs/screenshot.png for the README: the tool with the sample scenes loaded, one detail
view open and a threshold sweep drawn, in Debian's Chromium (the browser tests' harness).

    python tools/screenshot.py [--out docs/screenshot.png] [--image scene_010.jpg]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout root, for tests.support
from tests.support import browser_harness as harness  # noqa: E402


def default_image() -> str:
    """A hard sample with a sign: the detail view then shows the pipeline earning its answer."""
    truth = json.loads((harness.SCENES / "truth.json").read_text())["images"]
    return next(name for name, t in sorted(truth.items()) if t["label"] and t["category"] == "hard")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(harness.ROOT / "docs" / "screenshot.png"))
    parser.add_argument("--image", help="sample scene to open in the detail view (default: a hard one)")
    args = parser.parse_args()
    if not harness.CHROMIUM.exists():
        print(f"{harness.CHROMIUM} not found: install Debian's chromium", file=sys.stderr)
        return 1
    from playwright.sync_api import sync_playwright

    image = args.image or default_image()
    with tempfile.TemporaryDirectory(prefix="signpose-screenshot-") as tmp, \
            harness.serve(Path(tmp) / "state", Path(tmp) / "serve.log") as base, sync_playwright() as p:
        browser = harness.launch(p)
        page = harness.open_page(browser, base)
        page.wait_for_selector(".card")
        card = page.locator(".card", has=page.locator(".card-name", has_text=image)).first
        card.click()
        page.wait_for_function("() => [...document.querySelectorAll('#detail .stage img')].every(i => i.complete)")
        page.click("#run-sweep")
        page.wait_for_selector("#sweep:not([hidden])", timeout=300_000)
        scene = page.frame_locator("#scene")
        scene.get_by_text("Connected", exact=True).wait_for(timeout=60_000)
        # Headless Chromium renders WebGL in software; viser says so in a toast no reader needs.
        scene.locator(".mantine-Notification-closeButton").first.click(timeout=5_000)
        page.wait_for_timeout(1500)
        page.screenshot(path=args.out)
        errors = page.errors
        browser.close()
    if errors:
        print(f"page errors: {errors}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
