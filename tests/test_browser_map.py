"""A sign map in a real browser: photos of the sample survey uploaded through the page, a map built
in its Map section with an anchor chosen, every sign in its table with its 1-sigma, and every sign
drawn in place in the viser scene's map world. Skipped only when /usr/bin/chromium is missing."""

from __future__ import annotations

import re

import httpx
import numpy as np
import pytest

from signpose.pipeline.sign_map import load_sign_map
from tests.support import browser_harness as harness
from tests.test_map_api import LINKED, ROOM

pytestmark = [pytest.mark.browser, pytest.mark.server]

TRUTH = load_sign_map(ROOM / "truth_map.yaml")

@pytest.fixture(scope="module")
def base(tmp_path_factory):
    harness.skip_without_chromium()
    tmp = tmp_path_factory.mktemp("serve")
    with harness.serve(tmp / "state", tmp / "serve.log",
                       options=("--library", str(ROOM / "library"), "--camera", str(ROOM / "camera.yaml"))) as url:
        yield url


@pytest.fixture
def page(base):
    with harness.page_of(base) as page:
        yield page


def test_build_a_map_from_the_survey_and_see_it_in_the_table_and_the_3d_scene(page, base):
    harness.upload(page, [ROOM / f"photo_{n:03d}.jpg" for n in LINKED])
    assert "No sign map" in page.inner_text("#map-info")
    page.select_option("#map-anchor", "security_compound")
    page.click("#map-build")
    rows = page.locator("#map-signs tbody tr")
    page.wait_for_function("n => document.querySelectorAll('#map-signs tbody tr').length === n",
                           arg=len(TRUTH.signs), timeout=120_000)
    table = {rows.nth(i).get_attribute("data-id"): rows.nth(i).locator("td").all_inner_texts()
             for i in range(rows.count())}
    held = {s["id"]: s for s in httpx.get(f"{base}/api/map", timeout=30).json()["signs"]}
    assert set(table) == set(held) == set(TRUTH.signs)
    assert table["security_compound"][2] == "anchor"
    for sign_id, (_, position, sigma) in table.items():
        shown = np.array([float(v) for v in position.split()])
        np.testing.assert_allclose(shown, held[sign_id]["position_m"], atol=0.005 + 1e-9)   # in cm
        assert np.linalg.norm(shown - TRUTH.signs[sign_id].position_m) < 0.15, (sign_id, position)
        if sign_id != "security_compound":
            # its two lines, position and rotation: joined without a break where the cell is not laid out as it is read
            assert re.fullmatch(r"\d+\.\d mm\s*\d+\.\d\d°", sigma), sigma
    assert f"{len(LINKED)} photo(s)" in page.inner_text("#map-info")

    # The viser scene shows the map world, each sign where the table puts it, with its ellipsoid.
    page.frame_locator("#scene").get_by_text("Connected", exact=True).wait_for(timeout=30_000)
    frame = page.frame(url=re.compile(r"/viser/"))
    nodes = {}
    for _ in range(100):
        nodes = harness.scene_nodes(frame, "/map/")
        signs = {name.split("/")[3]: node for name, node in nodes.items() if re.fullmatch(r"/map/signs/[^/]+", name)}
        if set(signs) == set(TRUTH.signs) and all(n["visible"] and n["position"] for n in signs.values()):
            break
        page.wait_for_timeout(100)
    else:
        raise AssertionError(f"the 3D scene's map world does not show every sign: {sorted(nodes)}")
    for sign_id, node in signs.items():
        np.testing.assert_allclose(node["position"], held[sign_id]["position_m"], atol=1e-6)
    assert {f"/map/uncertainty/{s}" for s in TRUTH.signs} <= set(nodes)
    assert sum(name.startswith("/map/cameras/") for name in nodes) >= len(LINKED) // 2
