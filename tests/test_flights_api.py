"""Flights through the HTTP API (`/api/flights`), against a real uvicorn server: the sample flight
uploaded, tracked in the background as `signpose track --json` tracks it, its frames, exports,
cursor and removal; a rosbag2 folder sent as a zip; and every bad input refused saying why."""

from __future__ import annotations

import io
import json
import time
import zipfile
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from signpose.app.workspace import SAMPLE_FLIGHT, WorkspaceConfig
from signpose.pipeline.camera import load_camera
from signpose.pipeline.frames import open_source
from signpose.pipeline.library import SAMPLE_LIBRARY, load_library
from signpose.pipeline.settings import PRESETS
from signpose.pipeline.track import Tracker, tracked_frames
from tests.support.bags import ROS2, header, write_bag2, write_mcap
from tests.support.serving import MISFIT_CAMERA, TIMEOUT_S, assert_error, running_workspace, sample_library_copy

pytestmark = pytest.mark.server

VIDEO = SAMPLE_FLIGHT / "flight.mp4"
CAMERA = SAMPLE_FLIGHT / "camera.yaml"
MAX_FLIGHT_BYTES = 3_000_000   # the sample flight's 1.4 MB fits
RECORD_KEYS = {"source", "frame", "time_s", "signs", "timing_ms", "warnings"}
SIGN_KEYS = {"label", "track_id", "state", "corners", "homography", "pose", "filtered_pose"}


def config(state_dir: Path, **options) -> WorkspaceConfig:
    return WorkspaceConfig(state_dir=state_dir, library_dir=sample_library_copy(state_dir.parent), load_samples=False,
                           workers=1, max_flight_upload_bytes=MAX_FLIGHT_BYTES, **options)


@pytest.fixture(scope="module")
def base_url(tmp_path_factory):
    with running_workspace(config(tmp_path_factory.mktemp("flights") / "state", max_flight_frames=200)) as url:
        yield url


@pytest.fixture
def client(base_url):
    with httpx.Client(base_url=base_url, timeout=TIMEOUT_S) as c:
        yield c


def add_flight(client, name: str, data: bytes, **files) -> httpx.Response:
    return client.post("/api/flights", files={"file": (name, data, "application/octet-stream"), **files})


def wait_flight(client, flight_id: str, *, after_version: int = 0, timeout: float = 120) -> dict:
    """The flight once a run newer than `after_version` has ended."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        flight = client.get(f"/api/flights/{flight_id}").json()
        if flight["status"] in ("done", "error") and flight["result_version"] > after_version:
            return flight
        time.sleep(0.1)
    raise TimeoutError(f"flight {flight_id} still being tracked after {timeout} s")


@pytest.fixture(scope="module")
def sample(base_url) -> dict:
    """The sample flight with its camera file, uploaded and tracked once for the module."""
    with httpx.Client(base_url=base_url, timeout=TIMEOUT_S) as client:
        r = add_flight(client, "corridor.mp4", VIDEO.read_bytes(), camera=("camera.yaml", CAMERA.read_bytes()))
        assert r.status_code == 201, r.text
        assert r.json()["status"] in ("queued", "processing") and r.json()["total"] == 150
        return wait_flight(client, r.json()["id"])


def test_a_flight_is_tracked_in_the_background_as_signpose_track_tracks_it(client, sample):
    assert sample["status"] == "done" and sample["error"] is None
    assert sample["frames"] == sample["done"] == sample["total"] == 150
    assert (sample["width"], sample["height"], sample["fps"]) == (640, 480, 30.0)
    assert sample["camera"]["fx"] == pytest.approx(554.256, abs=1e-3)
    assert [f["id"] for f in client.get("/api/flights").json()["flights"]] == [sample["id"]]

    frames = client.get(f"/api/flights/{sample['id']}/frames").json()["frames"]
    assert [r["frame"] for r in frames] == list(range(150))
    assert all(set(r) == RECORD_KEYS and r["source"] == "corridor.mp4" for r in frames)
    assert set(frames[0]["timing_ms"]) == {"decode", "detect", "track", "total"}
    signs = [s for r in frames for s in r["signs"]]
    assert signs and all(set(s) == SIGN_KEYS and s["state"] in ("detected", "tracked") for s in signs)
    assert client.get(f"/api/flights/{sample['id']}/frames/7").json() == frames[7]

    # The same tracking as `signpose track --camera camera.yaml flight.mp4 --json`, timings aside.
    library = load_library(SAMPLE_LIBRARY)   # the server's is a copy of it
    with open_source(VIDEO) as source:
        tracker = Tracker(library, PRESETS["default"], load_camera(CAMERA), fps=source.fps)
        expected = [record["signs"] for _, _, record in tracked_frames(source, tracker, "corridor.mp4")]
    assert [r["signs"] for r in frames] == expected


def test_frame_images_cursor_and_bad_frame_numbers(client, sample):
    flight_id = sample["id"]
    r = client.get(f"/api/flights/{flight_id}/frames/10/image")
    assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
    assert cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR).shape == (480, 640, 3)
    assert client.put(f"/api/flights/{flight_id}/cursor", json={"frame": 42}).status_code == 204
    assert client.get(f"/api/flights/{flight_id}").json()["cursor"] == 42
    assert_error(client.get(f"/api/flights/{flight_id}/frames/150/image"), 404, "frames 0 to 149")
    assert_error(client.put(f"/api/flights/{flight_id}/cursor", json={"frame": 150}), 404, "frames 0 to 149")
    assert_error(client.get("/api/flights/0123456789ab"), 404, "GET /api/flights lists them")


def test_exports_are_what_signpose_track_writes(client, sample):
    flight_id = sample["id"]
    frames = client.get(f"/api/flights/{flight_id}/frames").json()["frames"]
    jsonl = client.get(f"/api/flights/{flight_id}/export", params={"format": "jsonl"})
    assert jsonl.status_code == 200 and 'filename="corridor.jsonl"' in jsonl.headers["content-disposition"]
    assert [json.loads(line) for line in jsonl.text.splitlines()] == frames
    csv = client.get(f"/api/flights/{flight_id}/export", params={"format": "csv"})
    rows = csv.text.splitlines()
    assert rows[0].startswith("frame,time_s,label,track_id,state,camera_x")
    assert len(rows) == 1 + sum(len(r["signs"]) for r in frames)
    mcap = client.get(f"/api/flights/{flight_id}/export", params={"format": "mcap"})
    assert mcap.content.startswith(b"\x89MCAP0\r\n") and b"/signpose/image/compressed" in mcap.content
    assert_error(client.get(f"/api/flights/{flight_id}/export", params={"format": "bag"}), 422, "format")


def test_a_settings_change_runs_the_flight_again(client, sample):
    flight_id = sample["id"]
    version = client.get(f"/api/flights/{flight_id}").json()["result_version"]
    threshold = client.get("/api/settings").json()["settings"]["threshold"]
    try:
        assert client.put("/api/settings", json={"threshold": threshold - 0.05}).status_code == 200
        again = wait_flight(client, flight_id, after_version=version)
        assert again["status"] == "done" and again["frames"] == 150
    finally:
        client.put("/api/settings", json={"threshold": threshold})
        wait_flight(client, flight_id, after_version=version + 1)


def test_a_sign_map_is_built_from_the_signs_the_flight_sees_together(client, sample):
    """As `signpose map build` maps the sample flight (tests/test_map_build.py), from its frames as tracked here."""
    r = client.post("/api/map/build", json={"anchor": "security_compound"})
    assert r.status_code == 200, r.text
    built = r.json()
    assert built["source"] == "built from 0 photo(s) and 1 flight(s)"
    signs = {s["id"]: s for s in built["signs"]}
    assert signs["security_compound"]["fixed"] == "anchor" and signs["chief_of_security"]["images"] > 1
    # On the corridor wall: chief_of_security 2.6 m along x and 0.1 m up from security_compound.
    offset = np.subtract(signs["chief_of_security"]["position_m"], [2.6, 0.1, 0.0])
    assert np.all(np.abs(offset) < [0.05, 0.05, 0.2]), offset
    assert client.delete("/api/map").status_code == 204


def bag_messages(n: int) -> list[tuple[str, object]]:
    """The first `n` frames of the sample flight as JPEG CompressedImage messages on /cam/image_raw/compressed."""
    messages = []
    with open_source(VIDEO) as source:
        for frame in source:
            if frame.index == n:
                break
            data = np.frombuffer(cv2.imencode(".jpg", frame.image)[1].tobytes(), np.uint8)
            stamp = 1_700_000_000_000_000_000 + frame.index * 33_333_333
            messages.append(("/cam/image_raw/compressed", ROS2.types["sensor_msgs/msg/CompressedImage"](
                header=header(ROS2, stamp, False), format="jpeg", data=data)))
    return messages


def test_a_rosbag2_folder_sent_as_a_zip_is_a_flight(client, tmp_path):
    folder = write_bag2(tmp_path / "bag", bag_messages(6))
    packed = io.BytesIO()
    with zipfile.ZipFile(packed, "w") as archive:
        for path in folder.rglob("*"):
            archive.write(path, Path("bag") / path.relative_to(folder))
    r = add_flight(client, "bag.zip", packed.getvalue())
    assert r.status_code == 201, r.text
    flight = wait_flight(client, r.json()["id"])
    try:
        assert (flight["kind"], flight["status"], flight["frames"]) == ("bag", "done", 6)
        frames = client.get(f"/api/flights/{flight['id']}/frames").json()["frames"]
        assert frames[5]["time_s"] == pytest.approx(5 * 0.033333333)
    finally:
        assert client.delete(f"/api/flights/{flight['id']}").status_code == 204
    assert client.get(f"/api/flights/{flight['id']}").status_code == 404


def test_bad_flights_are_refused_saying_why(client, tmp_path):
    info = ROS2.types["sensor_msgs/msg/CameraInfo"]
    roi = ROS2.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    bag = write_mcap(tmp_path / "info.mcap", [("/cam/camera_info", info(
        header=header(ROS2, 1, False), height=480, width=640, distortion_model="plumb_bob", d=np.zeros(5),
        k=np.eye(3).ravel(), r=np.eye(3).ravel(), p=np.zeros(12), binning_x=0, binning_y=0, roi=roi))])
    assert_error(add_flight(client, "info.mcap", bag.read_bytes()), 422,
                 "info.mcap: the bag has no image topics", "/cam/camera_info (sensor_msgs/msg/CameraInfo)")
    assert_error(add_flight(client, "cut.mp4", VIDEO.read_bytes()[:20_000]), 422, "cut.mp4: ")
    assert_error(add_flight(client, "noise.mp4", bytes(range(256)) * 100), 422, "noise.mp4: not a video file")
    assert_error(add_flight(client, "notes.txt", b"hello"), 422, "not a video or a ROS bag")
    assert_error(add_flight(client, "nobag.zip", b"PK\x05\x06" + bytes(18)), 422, "the zip holds no ROS bag")
    assert_error(add_flight(client, "flight.mp4", VIDEO.read_bytes(),
                            camera=("misfit.json", json.dumps(MISFIT_CAMERA).encode())), 422,
                 "flight.mp4: the camera", "does not fit its 640x480 px frames")
    assert_error(add_flight(client, "big.mp4", bytes(MAX_FLIGHT_BYTES + 1)), 413, "--max-flight-mb 4")
    held = {f["name"] for f in client.get("/api/flights").json()["flights"]}
    assert not held & {"info.mcap", "cut.mp4", "noise.mp4", "notes.txt", "nobag.zip", "flight.mp4", "big.mp4"}


def test_a_flight_longer_than_a_flight_may_hold_is_refused(tmp_path):
    with running_workspace(config(tmp_path / "state", max_flight_frames=100)) as url, \
            httpx.Client(base_url=url, timeout=TIMEOUT_S) as client:
        assert_error(add_flight(client, "flight.mp4", VIDEO.read_bytes()), 413,
                     "flight.mp4: 150 frames (5 s at 30 fps), more than the 100 a flight may hold",
                     "--max-flight-frames")
