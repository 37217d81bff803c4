"""The viser scene against a real viser server: nodes, poses in the sign frame, sliders, feedback loops."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import cv2
import numpy as np
import pytest
import viser
import viser.transforms as tf

from app.scene import (NO_WORLD, attach, camera_pose_in_sign, frustum_scale, frustum_shape,
                       image_plane_points)
from pipeline.camera import assumed_camera
from pipeline.library import Library, LibrarySign, load_library
from pipeline.recognize import StageCache, recognize
from pipeline.settings import Settings, settings_schema

W, H = 800, 600


def wait_for(condition, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.02)


def wall(seed: int) -> np.ndarray:
    """A gray, textured, sign-free wall photo."""
    return cv2.GaussianBlur(np.random.default_rng(seed).integers(40, 140, (H, W), dtype=np.uint8), (0, 0), 3)


def render(sign: LibrarySign, R: np.ndarray, t: np.ndarray, seed: int) -> np.ndarray:
    """A BGR photo of `sign` on a textured wall, seen by the assumed camera at pose (R, t)."""
    K = assumed_camera(W, H).K
    H_img = K @ np.column_stack([R[:, 0], R[:, 1], t]) @ sign.pixel_to_metric
    sign_px = cv2.warpPerspective(sign.image, H_img, (W, H))
    inside = cv2.warpPerspective(np.full_like(sign.image, 255), H_img, (W, H)) > 127
    return cv2.cvtColor(np.where(inside, sign_px, wall(seed)), cv2.COLOR_GRAY2BGR)


@dataclass
class Event:
    kind: str
    payload: dict


@dataclass
class Record:
    id: str
    name: str
    expected: str | None
    image: np.ndarray
    cache: StageCache
    recognition: object = None
    settings_version: int = 0
    error: str | None = None


class FakeWorkspace:
    """docs/web-contract.md's Workspace, minus HTTP concerns: re-runs synchronously, events from the caller's thread."""

    camera = None

    def __init__(self, library: Library) -> None:
        self.library = library
        self.settings = Settings()
        self.settings_version = 0
        self.updates: list[dict] = []
        self._records: dict[str, Record] = {}
        self._subscribers: list = []
        self._lock = threading.Lock()

    def images(self) -> list[Record]:
        return list(self._records.values())

    def add_image(self, name: str, data: bytes, expected: str | None) -> Record:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        record = Record(f"img{len(self._records)}", name, expected, image, StageCache())
        self._records[record.id] = record
        self._run([record])
        self._emit("images", {})
        return record

    def remove_image(self, image_id: str) -> None:
        del self._records[image_id]
        self._emit("images", {})

    def update_settings(self, changes: dict) -> Settings:
        with self._lock:
            self.settings = self.settings.replace(**changes)
            self.settings_version += 1
            self.updates.append(changes)
        self._emit("settings", {"version": self.settings_version, "settings": self.settings.to_dict()})
        self._run(self.images())
        return self.settings

    def subscribe(self, callback):
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback)

    def _run(self, records: list[Record]) -> None:
        for record in records:
            record.recognition = recognize(record.image, self.library, self.settings, None, record.cache)
            record.settings_version = self.settings_version
        self._emit("results", {"version": self.settings_version, "running": False,
                               "done": len(records), "total": len(records)})

    def _emit(self, kind: str, payload: dict) -> None:
        for callback in list(self._subscribers):
            callback(Event(kind, payload))


def photo_bytes(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", image)[1].tobytes()


# Two photos of one sign, one of another, and a bare wall.
VIEWS = [
    ("security_compound", (0.05, -0.35, 0.02), (0.10, -0.05, 1.6)),
    ("security_compound", (-0.10, 0.30, -0.05), (-0.15, 0.05, 2.0)),
    ("ministry_of_torture", (0.00, 0.15, 0.00), (0.00, 0.00, 1.8)),
]


@pytest.fixture(scope="module")
def library() -> Library:
    return load_library()


@pytest.fixture
def scene(library):
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    workspace = FakeWorkspace(library)
    for i, (sign_id, rpy, t) in enumerate(VIEWS):
        R = tf.SO3.from_rpy_radians(*rpy).as_matrix()
        workspace.add_image(f"view{i}.png", photo_bytes(render(library[sign_id], R, np.array(t), i)), sign_id)
    workspace.add_image("wall.png", photo_bytes(cv2.cvtColor(wall(9), cv2.COLOR_GRAY2BGR)), None)
    handle = attach(server, workspace)
    wait_for(lambda: len(handle.cameras) == len(VIEWS))
    yield handle, workspace
    handle.close()
    server.stop()


def test_camera_in_front_of_sign_sits_on_negative_z_looking_at_it():
    position, wxyz = camera_pose_in_sign(np.eye(3), np.array([0.0, 0.0, 2.0]))
    np.testing.assert_allclose(position, [0.0, 0.0, -2.0], atol=1e-12)
    np.testing.assert_allclose(wxyz, [1.0, 0.0, 0.0, 0.0], atol=1e-12)
    forward = tf.SO3(wxyz).as_matrix()[:, 2]  # viser frustums look down their local +z
    np.testing.assert_allclose(position + 2.0 * forward, [0.0, 0.0, 0.0], atol=1e-12)


def test_pixels_land_on_the_ray_through_them():
    K = assumed_camera(W, H).K
    fov, aspect = frustum_shape(W, H, K)
    scale = frustum_scale(fov, aspect, 0.5)
    corners = image_plane_points(np.array([[0, 0], [W, H], [W / 2, H / 2]]), W, H, fov, aspect, scale)
    assert corners[1, 0] - corners[0, 0] == pytest.approx(0.5)  # the drawn photo is 0.5 m wide
    assert corners[0, 0] < 0 and corners[0, 1] < 0  # top-left pixel: camera -x, -y
    np.testing.assert_allclose(corners[2, :2], [0.0, 0.0], atol=1e-12)
    rays = corners / corners[:, 2:]
    pixels = rays @ K.T
    np.testing.assert_allclose(pixels[:, :2], [[0, 0], [W, H], [W / 2, H / 2]], atol=1e-9)


def test_nodes_match_the_recognitions(scene):
    handle, workspace = scene
    recognised = {r.id: r for r in workspace.images() if r.recognition.recognized}
    assert set(handle.cameras) == set(recognised) and len(recognised) == len(VIEWS)
    assert set(handle.signs) == {"security_compound", "ministry_of_torture"}
    assert handle.world.value == "security_compound"  # the sign seen most
    assert handle.signs["security_compound"].frame.visible and not handle.signs["ministry_of_torture"].frame.visible
    for image_id, nodes in handle.cameras.items():
        rec = recognised[image_id].recognition
        assert nodes.sign == rec.label == recognised[image_id].expected
        R, t = rec.pose.R, rec.pose.t
        np.testing.assert_allclose(nodes.frustum.position, rec.pose.camera_position, atol=1e-6)
        np.testing.assert_allclose(nodes.frustum.position, -R.T @ t, atol=1e-6)
        q = tf.SO3.from_matrix(R.T).wxyz
        assert np.allclose(nodes.frustum.wxyz, q, atol=1e-6) or np.allclose(nodes.frustum.wxyz, -q, atol=1e-6)
        # Pose.quaternion_wxyz is of R; the frustum carries its inverse.
        w, x, y, z = rec.pose.quaternion_wxyz
        assert abs(np.dot(nodes.frustum.wxyz, [w, -x, -y, -z])) == pytest.approx(1.0, abs=1e-6)
        assert nodes.frustum.name == f"/signs/{rec.label}/cameras/{image_id}"
        segments = np.asarray(nodes.matches.points)
        assert segments.shape == (rec.best.estimate.n_inliers, 2, 3)
        np.testing.assert_allclose(segments[:, 0, 2], 0.0, atol=1e-6)  # starts on the sign plane
        # Each line continues through the camera centre: sign point, photo point and centre are collinear.
        to_photo = segments[:, 1] - segments[:, 0]
        to_centre = nodes.frustum.position - segments[:, 0]
        sine = np.linalg.norm(np.cross(to_photo, to_centre), axis=1) / (
            np.linalg.norm(to_photo, axis=1) * np.linalg.norm(to_centre, axis=1))
        assert np.median(sine) < 5e-3
    assert "**4** images" in handle.status.content and "**3** recognised" in handle.status.content
    assert "**1** no sign" in handle.status.content and "**3**/3 correct" in handle.status.content


def test_slider_reruns_and_frustums_follow(scene):
    handle, workspace = scene
    slider = handle.panel.controls["min_inliers"].input
    slider.value = slider.max
    assert workspace.settings.min_inliers == slider.max
    wait_for(lambda: not handle.cameras and not handle.signs)
    assert handle.world.options == (NO_WORLD,) and "**0** recognised" in handle.status.content
    slider.value = Settings().min_inliers
    wait_for(lambda: len(handle.cameras) == len(VIEWS))
    assert len(workspace.updates) == 2


def test_settings_from_elsewhere_move_controls_without_echo(scene):
    handle, workspace = scene
    workspace.update_settings({"ratio": 0.7, "detector": "orb", "full_frame_fallback": False})
    wait_for(lambda: handle.panel.controls["ratio"].input.value == pytest.approx(0.7))
    assert handle.panel.controls["detector"].input.value == "orb"
    assert handle.panel.controls["full_frame_fallback"].input.value is False
    assert len(workspace.updates) == 1


def test_every_setting_has_a_control_in_its_group_folder(scene):
    handle, _ = scene
    assert set(handle.panel.controls) == {entry["name"] for entry in settings_schema()}
    assert handle.panel.controls["high_threshold"].enabled is not None
    assert handle.panel.controls["seed"].input.max == 2**31 - 1


def test_nullable_setting_is_a_checkbox_and_a_slider(scene):
    handle, workspace = scene
    control = handle.panel.controls["high_threshold"]
    assert control.enabled.value is False and control.input.disabled
    control.input.value = 0.9  # staged only: the checkbox is off
    assert workspace.updates == []
    control.enabled.value = True
    assert workspace.settings.high_threshold == pytest.approx(0.9) and not control.input.disabled
    control.enabled.value = False
    assert workspace.settings.high_threshold is None


def test_rejected_change_reverts_the_control(scene):
    handle, workspace = scene
    workspace.update_settings({"high_threshold": 0.8})
    handle.panel.controls["threshold"].input.value = 0.9  # must stay below high_threshold
    assert workspace.settings.threshold == pytest.approx(0.6)
    assert handle.panel.controls["threshold"].input.value == pytest.approx(0.6)


def test_removed_image_loses_its_nodes(scene):
    handle, workspace = scene
    image_id = next(iter(handle.cameras))
    workspace.remove_image(image_id)
    wait_for(lambda: image_id not in handle.cameras)


def test_upload_button_adds_an_image(scene, library):
    handle, workspace = scene
    photo = render(library["chief_of_security"], np.eye(3), np.array([0.0, 0.0, 1.5]), 5)
    # What viser does when a browser upload completes (its setter cannot take an UploadedFile).
    button = handle.upload
    button._impl.value = viser.UploadedFile("upload.png", photo_bytes(photo))
    for callback in button._impl.update_cb:
        callback(viser.GuiEvent(client=None, client_id=None, target=button))
    assert workspace.images()[-1].name == "upload.png"
    wait_for(lambda: "chief_of_security" in handle.signs and len(handle.cameras) == len(VIEWS) + 1)


def test_view_from_puts_the_client_at_the_camera(scene):
    handle, _ = scene

    class Camera:
        position = look_at = up_direction = None

    class Client:
        camera = Camera()

        def atomic(self):
            return threading.Lock()

    image_id, nodes = next((k, n) for k, n in handle.cameras.items() if n.sign == "ministry_of_torture")
    client = Client()
    handle.view_from(image_id, client)
    assert handle.world.value == "ministry_of_torture"
    axes = tf.SO3(np.asarray(nodes.frustum.wxyz)).as_matrix()
    np.testing.assert_allclose(client.camera.position, nodes.frustum.position)
    np.testing.assert_allclose(client.camera.look_at[2], 0.0, atol=1e-9)  # the optical axis meets the sign
    direction = client.camera.look_at - client.camera.position
    np.testing.assert_allclose(direction / np.linalg.norm(direction), axes[:, 2], atol=1e-9)
    np.testing.assert_allclose(client.camera.up_direction, -axes[:, 1])


def test_close_stops_following(scene):
    handle, workspace = scene
    handle.close()
    workspace.update_settings({"min_inliers": 1000})
    time.sleep(0.3)
    assert len(handle.cameras) == len(VIEWS)
