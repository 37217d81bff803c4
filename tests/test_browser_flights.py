"""A flight in a real browser: the sample flight uploaded through the page, scrubbed, and its
trajectory and current camera seen in the viser scene. Skipped only when /usr/bin/chromium is missing."""

from __future__ import annotations

import re

import cv2
import httpx
import numpy as np
import pytest

from signpose.app.workspace import SAMPLE_FLIGHT
from tests.support import browser_harness as harness

pytestmark = [pytest.mark.browser, pytest.mark.server]

VIDEO = SAMPLE_FLIGHT / "flight.mp4"
CAMERA = SAMPLE_FLIGHT / "camera.yaml"


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    harness.skip_without_chromium()
    tmp = tmp_path_factory.mktemp("serve")
    with harness.serve(tmp / "state", tmp / "serve.log") as url:
        yield url


def write_short_flight(path, frames: int) -> None:
    """The sample flight's first `frames` frames as an MP4 at `path`: a flight tracked in a second."""
    video = cv2.VideoCapture(str(VIDEO))
    writer = None
    for _ in range(frames):
        ok, image = video.read()
        assert ok
        if writer is None:
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, image.shape[1::-1])
        writer.write(image)
    writer.release()
    video.release()


def flight_nodes(frame, flight_id: str) -> dict[str, dict]:
    """The flight's nodes in the viser scene by "<sign>/trajectory" and "<sign>/current": the trajectory's
    segments, the current camera's position and visibility (`harness.scene_nodes`)."""
    nodes = {}
    for name, node in harness.scene_nodes(frame, "/signs/").items():
        match = re.fullmatch(r"/signs/([^/]+)/flights/([^/]+)/(trajectory|current)", name)
        if match and match[2] == flight_id:
            nodes[f"{match[1]}/{match[3]}"] = node
    return nodes


def flight_row(page, name: str):
    return page.locator(".flight-row").filter(has=page.locator(".flight-name", has_text=re.compile(f"^{re.escape(name)}$")))


def viewed_from(record: dict, label: str) -> list[float]:
    """The camera position (m, the sign's frame) a frame's record gives for sign `label`: filtered if it can."""
    sign = next(s for s in record["signs"] if s["label"] == label)
    return (sign["filtered_pose"] or sign["pose"])["camera_position"]


def test_upload_scrub_and_see_the_trajectory_in_the_3d_scene(page, base, tmp_path):
    # `signpose serve` on a fresh state shows the sample flight among the samples.
    flight_row(page, "corridor.mp4").wait_for(timeout=30_000)

    upload = tmp_path / "upload-flight.mp4"
    upload.write_bytes(VIDEO.read_bytes())
    page.set_input_files("#flight-picker", str(upload))
    row = flight_row(page, upload.name)
    row.wait_for(timeout=60_000)
    page.wait_for_function("id => document.querySelector(`.flight-row[data-id='${id}']`)?.dataset.status === 'done'",
                           arg=row.get_attribute("data-id"), timeout=180_000)
    flight_id = row.get_attribute("data-id")
    with httpx.Client(base_url=base, timeout=30) as api:
        flight = api.get(f"/api/flights/{flight_id}").json()
        records = api.get(f"/api/flights/{flight_id}/frames").json()["frames"]
    assert flight["status"] == "done" and flight["frames"] == len(records) > 100, flight
    row.locator(".flight-open").click()
    page.wait_for_function("id => !document.querySelector('#flight').hidden && "
                           "document.querySelector('#flight').dataset.id === id", arg=flight_id)
    assert page.inner_text("#flight-name") == upload.name

    # Two frames that see one sign, far apart: scrub to each.
    label = page.input_value("#flight-label")
    seeing = [r["frame"] for r in records if any(s["label"] == label and (s["filtered_pose"] or s["pose"])
                                                  for s in r["signs"])]
    assert len(seeing) > 20, seeing
    page.frame_locator("#scene").get_by_text("Connected", exact=True).wait_for(timeout=30_000)
    frame = page.frame(url=re.compile(r"/viser/"))
    for index in (seeing[len(seeing) // 4], seeing[3 * len(seeing) // 4]):
        page.fill("#flight-scrub", str(index))
        page.wait_for_function("i => document.querySelector('#flight-time').textContent.startsWith(`frame ${i} `)",
                               arg=index)
        page.wait_for_function("() => document.querySelector('#flight-img').complete && "
                               "document.querySelector('#flight-img').naturalWidth === 640")
        record = records[index]
        assert page.locator("#flight-overlay polygon").count() == len(record["signs"])
        states = {s["state"] for s in record["signs"]}
        assert any(state in page.inner_text("#flight-state") for state in states)

        # The viser scene: the trajectory as a line in the sign's world, the current camera at this frame.
        expected = viewed_from(record, label)
        nodes = None
        for _ in range(100):
            nodes = flight_nodes(frame, flight_id)
            current = nodes.get(f"{label}/current")
            if current and current["visible"] and current["position"] and \
                    np.allclose(current["position"], expected, atol=1e-3):
                break
            page.wait_for_timeout(100)
        else:
            raise AssertionError(f"the 3D scene's current camera is not at frame {index}'s: {nodes}, "
                                 f"expected {expected}")
        trajectory = nodes[f"{label}/trajectory"]
        assert trajectory["type"] == "LineSegmentsMessage"
        assert trajectory["visible"]


def test_a_flight_takes_the_camera_file_chosen_beside_it(page, base, tmp_path):
    flight = tmp_path / "camera-flight.mp4"
    write_short_flight(flight, 5)
    wide = tmp_path / "wide-camera.yaml"   # a 1280x720 camera: it does not fit the 640x480 frames
    wide.write_text(CAMERA.read_text().replace("640", "1280").replace("480", "720").replace("320.0", "640.0")
                    .replace("240.0", "360.0"))
    page.set_input_files("#flight-camera", str(wide))
    assert page.inner_text("#flight-camera-name") == wide.name and page.is_visible("#flight-camera-clear")
    page.set_input_files("#flight-picker", str(flight))
    refused = page.locator(".upload.failed", has=page.locator(".upload-name", has_text=flight.name))
    refused.wait_for(timeout=30_000)
    assert "does not fit" in refused.locator(".upload-status").inner_text()

    page.set_input_files("#flight-camera", str(CAMERA))
    page.set_input_files("#flight-picker", str(flight))
    row = flight_row(page, flight.name)
    row.wait_for(timeout=30_000)
    flight_id = row.get_attribute("data-id")
    page.wait_for_function("id => document.querySelector(`.flight-row[data-id='${id}']`)?.dataset.status === 'done'",
                           arg=flight_id, timeout=60_000)
    with httpx.Client(base_url=base, timeout=30) as api:
        camera = api.get(f"/api/flights/{flight_id}").json()["camera"]
        assert camera["source"] == f"file:{CAMERA.name}" and camera["fx"] == pytest.approx(554.256, abs=1e-3)
        row.locator(".flight-open").click()
        page.wait_for_function("id => document.querySelector('#flight').dataset.id === id", arg=flight_id)
        assert "fx 554.3" in page.inner_text("#flight-summary") and CAMERA.name in page.inner_text("#flight-summary")

        # Cleared, the next flight goes without one.
        page.click("#flight-camera-clear")
        assert page.inner_text("#flight-camera-name") == "camera file" and not page.is_visible("#flight-camera-clear")
        api.delete(f"/api/flights/{flight_id}").raise_for_status()
