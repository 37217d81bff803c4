"""The viser scene on a real viser server and Workspace: nodes, poses in the sign frame, sliders, feedback loops."""

from __future__ import annotations

import contextlib
import math
import dataclasses
import json
import time
import types

import cv2
import numpy as np
import pytest
import viser
import viser.transforms as tf

from signpose.app.scene import (INITIAL_VIEW_LOOK_AT_M, INITIAL_VIEW_POSITION_M, LABEL_EDGE_PX, LABEL_GAP_PX,
                       LABEL_LINE_PX, LABEL_SEPARATOR, MAX_TEXTS_LISTED, NO_WORLD, View, attach, camera_pose_in_sign, frustum_scale, frustum_shape,
                       image_plane_points, label_groups, label_size_px, labels_apart, matched_points, screen_px,
                       status_markdown)
from signpose.app.viser_compat import FOLD_SHEET_SCRIPT
from signpose.app.workspace import SAMPLE_SCENES, Outcome, Workspace, WorkspaceConfig
from signpose.pipeline.camera import assumed_camera
from signpose.pipeline.settings import PRESETS, settings_schema
from tests.support.scene_images import sign_photo

IDLE_TIMEOUT_S = 30
TRUTH = json.loads((SAMPLE_SCENES / "truth.json").read_text(encoding="utf-8"))["images"]
POSITIVES = {name for name, entry in TRUTH.items() if entry["label"] is not None}


def wait_for(condition, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        time.sleep(0.02)


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """The sample scenes in a fresh Workspace with their camera file; loaded once, as that takes seconds."""
    ws = Workspace.open(WorkspaceConfig(state_dir=tmp_path_factory.mktemp("scene") / "state",
                                   camera_file=SAMPLE_SCENES / "camera.yaml", workers=2))
    assert ws.wait_idle(IDLE_TIMEOUT_S)
    yield ws
    ws.close()


@pytest.fixture
def scene(workspace):
    """A loopback viser server showing `workspace`; the settings go back to the defaults afterwards.

    Tests that add or remove images restore the sample set themselves.
    """
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    handle = attach(server, workspace)
    # The world is chosen after the last camera is drawn: waiting for the cameras alone raced it.
    wait_for(lambda: len(handle.cameras) == len(POSITIVES) and handle.world.value in handle.signs)
    # ... and mid-redraw: setting the world's options shows their first before the redraw picks the
    # most seen. A redraw of our own waits for that one to end.
    handle.redraw()
    yield handle, workspace
    handle.close()
    server.stop()
    workspace.replace_settings(PRESETS["default"])
    assert workspace.wait_idle(IDLE_TIMEOUT_S)


def settle(handle, workspace) -> None:
    """Wait until the workspace is idle and the scene has drawn its latest results."""
    assert workspace.wait_idle(IDLE_TIMEOUT_S)
    time.sleep(0.3)  # the last results event, then one coalesced redraw
    handle.redraw()


def test_camera_in_front_of_sign_sits_on_negative_z_looking_at_it():
    position, wxyz = camera_pose_in_sign(np.eye(3), np.array([0.0, 0.0, 2.0]))
    np.testing.assert_allclose(position, [0.0, 0.0, -2.0], atol=1e-12)
    np.testing.assert_allclose(wxyz, [1.0, 0.0, 0.0, 0.0], atol=1e-12)
    forward = tf.SO3(wxyz).as_matrix()[:, 2]  # viser frustums look down their local +z
    np.testing.assert_allclose(position + 2.0 * forward, [0.0, 0.0, 0.0], atol=1e-12)


def test_pixels_land_on_the_ray_through_them():
    W, H = 800, 600
    K = assumed_camera(W, H).K
    fov, aspect = frustum_shape(W, H, K)
    scale = frustum_scale(fov, aspect, 0.5)
    points = image_plane_points(np.array([[0, 0], [W, H], [W / 2, H / 2]]), W, H, fov, aspect, scale)
    assert points[1, 0] - points[0, 0] == pytest.approx(0.5)  # the drawn photo is 0.5 m wide
    assert points[0, 0] < 0 and points[0, 1] < 0  # top-left pixel: camera -x, -y
    np.testing.assert_allclose(points[2, :2], [0.0, 0.0], atol=1e-12)
    pixels = (points / points[:, 2:]) @ K.T
    np.testing.assert_allclose(pixels[:, :2], [[0, 0], [W, H], [W / 2, H / 2]], atol=1e-9)


def test_nodes_match_the_recognitions(scene):
    handle, workspace = scene
    records = {r.id: r for r in workspace.images()}
    assert {records[i].name for i in handle.cameras} == POSITIVES
    assert set(handle.signs) == {TRUTH[name]["label"] for name in POSITIVES}
    assert handle.signs[handle.world.value].frame.visible
    assert sum(nodes.frame.visible for nodes in handle.signs.values()) == 1
    for image_id, nodes in handle.cameras.items():
        record = records[image_id]
        rec = record.recognition
        assert nodes.sign == rec.label == TRUTH[record.name]["label"]
        assert nodes.frustum.name == f"/signs/{rec.label}/cameras/{image_id}"
        R, t = rec.pose.R, rec.pose.t
        np.testing.assert_allclose(nodes.frustum.position, rec.pose.camera_position, atol=1e-6)
        np.testing.assert_allclose(nodes.frustum.position, -R.T @ t, atol=1e-6)
        q = tf.SO3.from_matrix(R.T).wxyz
        assert np.allclose(nodes.frustum.wxyz, q, atol=1e-6) or np.allclose(nodes.frustum.wxyz, -q, atol=1e-6)
        w, x, y, z = rec.pose.quaternion_wxyz  # of R; the frustum carries its inverse
        assert abs(np.dot(nodes.frustum.wxyz, [w, -x, -y, -z])) == pytest.approx(1.0, abs=1e-6)
        # The rendering's true camera: the frame conventions hold end to end.
        R_true, t_true = (np.asarray(TRUTH[record.name][k]) for k in ("R", "t"))
        true_position = -R_true.T @ t_true
        assert np.linalg.norm(nodes.frustum.position - true_position) < 0.1 * np.linalg.norm(true_position)
        segments = np.asarray(nodes.matches.points)
        assert segments.shape == (len(matched_points(rec, handle.workspace.library[rec.label])[0]), 2, 3)
        np.testing.assert_allclose(segments[:, 0, 2], 0.0, atol=1e-6)  # each line starts on the sign plane
        # ... and continues through the camera centre: sign point, photo point and centre are collinear.
        to_photo = segments[:, 1] - segments[:, 0]
        to_centre = nodes.frustum.position - segments[:, 0]
        sine = np.linalg.norm(np.cross(to_photo, to_centre), axis=1) / (
            np.linalg.norm(to_photo, axis=1) * np.linalg.norm(to_centre, axis=1))
        assert np.median(sine) < 0.01
    n = len(TRUTH)
    assert handle.status.content.startswith(f"**{n}** images · **{n}**/{n} correct · ")
    assert "wrong" not in handle.status.content


def test_new_viewers_and_reset_view_frame_the_sign_and_its_cameras(scene):
    """The starting view was fixed, for cameras a metre or two from the sign: a drone's camera
    further away was out of it."""
    handle, _ = scene
    initial = handle.server.initial_camera
    for world in handle.world.options:
        handle.world.value = world
        far = next(n for n in handle.cameras.values() if n.sign == world)
        far.frustum.position = (3.0, -2.0, -7.0)  # as a camera 8 m off would be drawn
        handle.redraw()
        points = _frame_points(handle, world)
        axis = initial.look_at - initial.position
        rays = points - initial.position
        angles = np.degrees(np.arccos(rays @ axis / (np.linalg.norm(rays, axis=1) * np.linalg.norm(axis))))
        # inside the view with room to spare for viser's panel
        assert angles.max() < 0.8 * np.degrees(initial.fov) / 2, (world, angles.max())


def test_a_viewer_narrower_than_tall_is_framed_for_its_width(scene):
    """The page's 3D column is about 390 x 870 px: framed for the height, cameras were cut off at
    the sides. A viewer's camera is framed again for its own canvas when it first reports it."""
    handle, _ = scene
    initial = handle.server.initial_camera
    viewer = Viewer(1, 0.45, initial)
    assert _widest(handle, initial) > viewer.across_deg   # what the page's column showed
    handle.frame_for(viewer)
    assert _widest(handle, viewer.camera) < 0.8 * viewer.across_deg


def test_a_narrow_viewer_has_room_for_the_labels_of_the_cameras_at_its_edges(scene):
    """The page's 3D column framed the cameras, not their labels, which viser writes rightward from
    them: a camera near the edge had its name cut off there."""
    handle, _ = scene
    viewer = Viewer(1, 0.45, handle.server.initial_camera)
    handle.frame_for(viewer)
    half_px = viewer.camera.image_width / 2
    label_px = max(label_size_px(n.label.text)[0] for n in handle.cameras.values()
                   if n.sign == handle.world.value and n.label.visible)
    off_axis_px = half_px * math.tan(math.radians(_widest(handle, viewer.camera))) / math.tan(
        math.radians(viewer.across_deg))
    assert off_axis_px + label_px <= half_px, (off_axis_px, label_px, half_px)


def test_viewers_left_as_framed_follow_new_cameras_and_one_moved_by_hand_stays(scene, monkeypatch):
    """Cameras drawn after a viewer had connected were outside its view until the page was reloaded."""
    handle, _ = scene
    initial = handle.server.initial_camera
    column, moved = Viewer(1, 0.45, initial), Viewer(2, 1.6, initial)
    monkeypatch.setattr(handle.server, "get_clients", lambda: {1: column, 2: moved})
    handle.frame_for(column)
    handle.frame_for(moved)
    moved.camera.position = np.asarray(moved.camera.position) + (0.0, 0.0, -0.5)  # the person pulled back
    held = moved.camera.position.copy()
    far = next(n for n in handle.cameras.values() if n.sign == handle.world.value)
    far.frustum.position = (3.0, -2.0, -7.0)  # as a camera 8 m off would be drawn
    handle.redraw()
    assert _widest(handle, column.camera) < 0.8 * column.across_deg
    assert np.array_equal(moved.camera.position, held)


@pytest.mark.slow
def test_viewers_are_framed_on_the_first_cameras_drawn_in_an_empty_scene(scene, monkeypatch):
    """A page opened on an empty workspace (`serve --library DIR` loads no samples: the start of a
    round) was never framed: the first photo's camera, metres off, stayed outside its view until
    Reset View. A viewer moved by hand, then emptied of cameras, has nothing left to keep either."""
    handle, workspace = scene
    initial = handle.server.initial_camera
    moved = Viewer(2, 1.6, initial)
    monkeypatch.setattr(handle.server, "get_clients", lambda: {2: moved})
    handle.frame_for(moved)
    moved.camera.position = np.asarray(moved.camera.position) + (0.0, 0.0, -0.5)  # the person pulled back
    workspace.update_settings({"plaque_fallback": False, "min_inliers": handle.panel.controls["min_inliers"].input.max})
    settle(handle, workspace)
    assert not handle.cameras
    # a page opened now, on a fresh server's starting view, looked around while there is nothing to see
    fresh = Viewer(1, 0.45, types.SimpleNamespace(fov=initial.fov, position=INITIAL_VIEW_POSITION_M,
                                                  look_at=INITIAL_VIEW_LOOK_AT_M))
    monkeypatch.setattr(handle.server, "get_clients", lambda: {1: fresh, 2: moved})
    handle._on_connect(fresh)
    fresh.report()
    fresh.camera.position = np.asarray(fresh.camera.position) + (0.3, 0.0, 0.0)
    workspace.replace_settings(PRESETS["default"])
    settle(handle, workspace)
    far = next(n for n in handle.cameras.values() if n.sign == handle.world.value)
    far.frustum.position = (3.0, -2.0, -7.0)  # as a camera 8 m off would be drawn
    handle.redraw()
    for viewer in (fresh, moved):
        assert _widest(handle, viewer.camera) < 0.8 * viewer.across_deg, viewer.client_id


@pytest.mark.slow
def test_a_view_moving_lays_out_the_labels_again_and_redraws_nothing_else(scene, monkeypatch):
    """Every camera report of every viewer (a dozen a second while one is dragged) ran the whole
    redraw: listing the images, comparing every record and writing the status line again, where
    only the labels' layout depends on the view."""
    handle, workspace = scene
    viewer = Viewer(1, 0.45, handle.server.initial_camera)
    monkeypatch.setattr(handle.server, "get_clients", lambda: {1: viewer})
    handle._on_connect(viewer)
    viewer.report()   # framed for its canvas
    settle(handle, workspace)
    world = [n for n in handle.cameras.values() if n.sign == handle.world.value]
    framed = [n.label.visible for n in world]
    assert len(world) > 1 and sum(framed) > 1
    redraw, redraws = handle.redraw, []
    monkeypatch.setattr(handle, "redraw", lambda: (redraws.append(time.monotonic()), redraw()))
    near = viewer.camera.position
    viewer.camera.position = viewer.camera.look_at + 40 * (near - viewer.camera.look_at)   # its names print as one
    viewer.report()
    wait_for(lambda: sum(n.label.visible for n in world) == 1)
    viewer.camera.position = near
    viewer.report()
    wait_for(lambda: [n.label.visible for n in world] == framed)
    time.sleep(0.3)
    assert not redraws


class Viewer:
    """A viser client as `SceneHandle` sees it: an id and a camera of a canvas' aspect (width / height)."""

    def __init__(self, client_id: int, aspect: float, start: viser.InitialCameraConfig, height_px: int = 870):
        self.client_id = client_id
        self._on_camera = []
        self.camera = type("Camera", (), dict(fov=start.fov, aspect=aspect, image_width=round(aspect * height_px),
                                              image_height=height_px, position=np.asarray(start.position),
                                              look_at=np.asarray(start.look_at),
                                              up_direction=np.array([0.0, -1.0, 0.0]),
                                              on_update=lambda _camera, callback: self._on_camera.append(callback)))()
        # half the canvas' width, in degrees
        self.across_deg = np.degrees(math.atan(math.tan(start.fov / 2) * min(aspect, 1.0)))
        # how its control panel was folded: "window" for viser's minimise, "sheet" for a script run
        self.folds: list[str] = []
        self.gui = types.SimpleNamespace(main_panel=types.SimpleNamespace(minimize=lambda: self.folds.append("window")))
        self._websock_connection = types.SimpleNamespace(queue_message=lambda message: self.folds.append(
            "sheet" if message.source == FOLD_SHEET_SCRIPT else "script"))

    def atomic(self):
        return contextlib.nullcontext()

    def report(self) -> None:
        """What viser does when the viewer reports its camera again (a first report connects it)."""
        for callback in self._on_camera:
            callback(self.camera)


def _widest(handle, camera) -> float:
    """Degrees off `camera`'s view axis of the farthest of the points to frame in the shown world."""
    axis = np.asarray(camera.look_at) - camera.position
    rays = _frame_points(handle, handle.world.value) - camera.position
    return np.degrees(np.arccos(rays @ axis / (np.linalg.norm(rays, axis=1) * np.linalg.norm(axis)))).max()


def _frame_points(handle, world: str) -> np.ndarray:
    """(N, 3) m: the corners of `world`'s sign and the positions of its cameras."""
    corners = np.asarray(handle.signs[world].outline.points).reshape(-1, 3)
    cameras = [np.asarray(n.frustum.position) for n in handle.cameras.values() if n.sign == world]
    return np.vstack([corners, *cameras])


def test_status_line_uses_the_words_of_the_pages_top_bar():
    line = status_markdown(["correct", "wrong", "recognized", "none", "none", "error", "pending"], [Outcome()] * 7,
                           {"running": True, "done": 2, "total": 7})
    assert line == ("**7** images · **1**/2 correct · **1** wrong · **1** recognised (unlabelled) · "
                    "**2** no sign (unlabelled) · **1** pending · **1** error · re-running 2/7")


def test_status_line_says_when_its_times_are_cache_lookups(scene):
    handle, workspace = scene
    threshold = handle.panel.controls["ransac_threshold_px"].input
    threshold.value = threshold.value + 1.0  # features and matches are taken from each image's cache
    settle(handle, workspace)
    assert "ms/image (median, stages reused from cache)" in handle.status.content
    outcomes = [r.outcome for r in workspace.images()]
    assert all(o.recognition.reused_stages for o in outcomes)
    run_afresh = [Outcome(dataclasses.replace(o.recognition, reused_stages=[])) for o in outcomes]
    assert "ms/image (median) · " not in handle.status.content
    assert "ms/image (median)" in status_markdown(["correct"] * len(outcomes), run_afresh, {})


@pytest.mark.slow
def test_sliders_rerun_and_frustums_follow(scene):
    handle, workspace = scene
    version = workspace.settings_version
    handle.panel.controls["plaque_fallback"].input.value = False
    min_inliers = handle.panel.controls["min_inliers"].input
    min_inliers.value = min_inliers.max
    assert workspace.settings.min_inliers == min_inliers.max and not workspace.settings.plaque_fallback
    assert workspace.settings_version == version + 2
    settle(handle, workspace)
    assert not handle.cameras and not handle.signs
    n, positives = len(TRUTH), len(POSITIVES)
    assert handle.world.options == (NO_WORLD,)
    # the words of the page's top bar: every expected sign is now missed
    assert f"**{n - positives}**/{n} correct · **{positives}** wrong" in handle.status.content
    min_inliers.value = 12
    settle(handle, workspace)
    assert handle.cameras


def test_settings_from_elsewhere_move_controls_without_echo(scene):
    handle, workspace = scene
    version = workspace.settings_version
    workspace.update_settings({"ratio": 0.7, "detector": "orb", "full_frame_fallback": False})
    assert handle.panel.controls["ratio"].input.value == pytest.approx(0.7)
    assert handle.panel.controls["detector"].input.value == "orb"
    assert handle.panel.controls["full_frame_fallback"].input.value is False
    assert workspace.settings_version == version + 1  # the sliders did not send the change back


def test_every_setting_has_a_control(scene):
    handle, _ = scene
    assert set(handle.panel.controls) == {entry["name"] for entry in settings_schema()}
    assert handle.panel.controls["seed"].input.max == 2**31 - 1


def test_nullable_setting_is_a_checkbox_and_a_slider(scene):
    handle, workspace = scene
    control = handle.panel.controls["high_threshold"]
    assert control.enabled.value is False and control.input.disabled
    version = workspace.settings_version
    control.input.value = 0.9  # staged only: the checkbox is off
    assert workspace.settings_version == version
    control.enabled.value = True
    assert workspace.settings.high_threshold == pytest.approx(0.9) and not control.input.disabled
    control.enabled.value = False
    assert workspace.settings.high_threshold is None


def test_rejected_change_reverts_the_control(scene):
    handle, workspace = scene
    workspace.update_settings({"high_threshold": 0.8})
    threshold = handle.panel.controls["threshold"].input
    before = workspace.settings.threshold
    threshold.value = 0.9  # must stay below high_threshold
    assert workspace.settings.threshold == before and threshold.value == pytest.approx(before)


def test_removed_image_loses_its_nodes(scene):
    handle, workspace = scene
    image_id = next(iter(handle.cameras))
    record = workspace.get(image_id)
    workspace.remove_image(image_id)
    try:
        wait_for(lambda: image_id not in handle.cameras)
    finally:
        workspace.add_image(record.name, (SAMPLE_SCENES / record.name).read_bytes(), record.expected)


def test_cameras_standing_together_share_one_label(scene):
    """A photo uploaded twice (or a burst) put two cameras in one spot, and their labels printed
    one name over the other: cameras closer than the drawn photo width share one label, a name a line."""
    handle, workspace = scene
    original = next(r for r in workspace.images() if r.id in handle.cameras)
    copy = workspace.add_image("copy.jpg", (SAMPLE_SCENES / original.name).read_bytes(), original.expected)
    try:
        settle(handle, workspace)
        pair = [handle.cameras[original.id], handle.cameras[copy.id]]
        assert [nodes.label.visible for nodes in pair] == [True, False]
        assert pair[0].label.text == f"{original.name}\ncopy.jpg"
        others = [nodes for image_id, nodes in handle.cameras.items() if image_id not in (original.id, copy.id)]
        assert all(nodes.label.visible and "\n" not in nodes.label.text for nodes in others)
    finally:
        workspace.remove_image(copy.id)
    settle(handle, workspace)
    label = handle.cameras[original.id].label
    assert label.visible and label.text == original.name


def _camera(position, look_at, width_px: int, height_px: int, fov_deg: float = 90):
    """A viewer's camera as viser reports it, y down the sign as the scene sets it up."""
    return types.SimpleNamespace(position=np.asarray(position, float), look_at=np.asarray(look_at, float),
                                 up_direction=np.array([0.0, -1.0, 0.0]), fov=math.radians(fov_deg),
                                 image_width=width_px, aspect=width_px / height_px)


def test_screen_px_is_where_a_viewer_sees_a_point():
    camera = _camera((0, 0, 0), (0, 0, 1), 400, 200)
    px = screen_px(np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1], [0, 0, -1]]), camera)
    np.testing.assert_allclose(px[:3], [[200, 100], [300, 100], [200, 200]])   # f = 100 px: 200 high, 90°
    assert np.isnan(px[3]).all()   # behind the viewer


def _overlapping(labels, view: View) -> list:
    """The pairs of `labels` (SharedLabel) whose boxes on `view`'s screen overlap, or come nearer than LABEL_GAP_PX."""
    boxes = [label.box(view) for label in labels]
    return [(a, b) for i, a in enumerate(boxes) for b in boxes[:i]
            if a[0] < b[2] + LABEL_GAP_PX and b[0] < a[2] + LABEL_GAP_PX
            and a[1] < b[3] + LABEL_GAP_PX and b[1] < a[3] + LABEL_GAP_PX]


def test_labels_are_laid_out_in_css_px_on_a_screen_of_two_device_px_to_one():
    """viser reports its canvas in device px and draws the labels at a size in CSS px: on a screen of
    two device px to the CSS px they were laid out at half their size on it, and overlapped there.
    A view of such a canvas is in CSS px, as that of the same canvas on a screen of one."""
    names = [f"IMG_20240512_1034{i:02d}.jpg" for i in range(20)]
    positions = np.array([(x, y, z) for z in (-1.2, -1.8) for x in np.linspace(-0.9, 0.9, 5) for y in (-0.25, 0.2)])
    groups = label_groups(list(positions), 0.25)
    pose = ((-1.5, -1.0, -5.0), (0, 0, -1.0))
    column = View.of(_camera(*pose, 446, 900, 50), positions)
    sharp = View.of(_camera(*pose, 892, 1800, 50), positions, px_per_css_px=2.0)
    np.testing.assert_allclose(sharp.px, column.px)
    assert (sharp.width, sharp.height) == (column.width, column.height)
    assert labels_apart(groups, names, [sharp]) == labels_apart(groups, names, [column])
    # read as CSS px, the sharp canvas seemed to have room for four times the labels
    assert len(labels_apart(groups, names, [View.of(_camera(*pose, 892, 1800, 50), positions)])) > len(
        labels_apart(groups, names, [column]))


def test_a_canvas_width_heard_of_frames_and_lays_out_its_viewer_in_css_px(scene, monkeypatch):
    """A viewer on a screen of two device px to the CSS px is framed with room for its labels at their
    size there, once its page has said its canvas' width in CSS px: the room a canvas half its size
    on a screen of one has. Another viewer's canvas of the same size in device px, on a screen of
    one, keeps its own: kept by canvas size, the scale said last held for both."""
    handle, _ = scene
    start = handle.server.initial_camera
    plain, sharp, wide = Viewer(1, 0.5, start), Viewer(2, 0.5, start, height_px=2 * 870), \
        Viewer(3, 0.5, start, height_px=2 * 870)
    monkeypatch.setattr(handle.server, "get_clients", lambda: {2: sharp, 3: wide})
    for viewer in (plain, sharp, wide):
        handle.frame_for(viewer)
    assert _widest(handle, sharp.camera) > _widest(handle, plain.camera) + 0.5   # labels half their size
    framed_wide = wide.camera.position
    handle.set_canvas_width(3, wide.camera.image_width)
    handle.set_canvas_width(2, sharp.camera.image_width / 2)
    wait_for(lambda: np.allclose(sharp.camera.position, plain.camera.position))
    assert np.array_equal(wide.camera.position, framed_wide)


def test_a_viewers_canvas_width_is_its_own_until_it_leaves(scene, monkeypatch):
    """Its device px to the CSS px follow the device px its camera reports (fewer while viser lowers
    its resolution, in the same CSS px); a viewer that left, or one never connected, keeps none."""
    handle, _ = scene
    viewer = Viewer(2, 0.5, handle.server.initial_camera, height_px=2 * 870)
    clients = {2: viewer}
    monkeypatch.setattr(handle.server, "get_clients", lambda: clients)
    handle.set_canvas_width(2, viewer.camera.image_width / 2)
    handle.set_canvas_width(5, 400.0)   # not connected
    assert handle._px_per_css_px_of(viewer) == 2.0
    viewer.camera.image_width = round(0.75 * viewer.camera.image_width)
    assert handle._px_per_css_px_of(viewer) == pytest.approx(1.5, abs=0.01)
    handle._on_disconnect(viewer)
    clients.clear()
    assert handle._css_width == {}


def test_a_viewers_panel_is_folded_once_its_view_is_known_and_again_across_the_phone_layout(scene, monkeypatch):
    """viser's control panel covers much of a small view: folded once the viewer's canvas size in CSS
    px and its camera are both known, whichever comes first, and not again, so a panel the person
    opened stays open; but again as the view crosses viser's phone breakpoint, where viser builds
    its panel anew, open (as a sheet or a window)."""
    handle, _ = scene
    strip = Viewer(2, 1200 / 360, handle.server.initial_camera, height_px=360)
    column = Viewer(3, 400 / 800, handle.server.initial_camera, height_px=800)
    monkeypatch.setattr(handle.server, "get_clients", lambda: {2: strip, 3: column})
    # viser calls the connect callback on its thread pool after the first camera report, which may
    # be handed out before that callback registered for reports; a view that does not move sends no
    # other. Its page may say its size in between.
    handle.set_canvas_width(2, 1200.0)
    assert strip.folds == []   # its camera not yet known
    handle._on_connect(strip)
    assert strip.folds == ["window"]
    handle._on_connect(column)
    column.report()
    assert column.folds == []   # its canvas' CSS px not yet said
    handle.set_canvas_width(3, 400.0)
    strip.report()
    handle.set_canvas_width(3, 420.0)
    assert (strip.folds, column.folds) == (["window"], ["sheet"])
    handle.set_canvas_width(3, 700.0)   # the window widened past viser's phone layout
    handle.set_canvas_width(3, 500.0)
    assert column.folds == ["sheet", "window", "sheet"]


def test_a_view_that_settles_small_after_it_loads_is_folded_then(scene, monkeypatch):
    """A page lays its 3D strip out as it loads: the viewer's first camera may report a canvas it then
    leaves (as tall as a large view's). Its panel is folded once the view settles small, once."""
    handle, _ = scene
    strip = Viewer(2, 1200 / 900, handle.server.initial_camera, height_px=900)
    monkeypatch.setattr(handle.server, "get_clients", lambda: {2: strip})
    handle._on_connect(strip)
    handle.set_canvas_width(2, 1200.0)
    strip.report()
    assert strip.folds == []   # a view this large keeps its panel
    strip.camera.aspect = 1200 / 360
    strip.report()
    strip.report()
    assert strip.folds == ["window"]


def _said(label, names: list[str]) -> bool:
    """Whether `label` (a SharedLabel) lists the `names` of its cameras, one a line, or, for more than
    MAX_TEXTS_LISTED, counts them with the first and last."""
    named = [names[i] for i in label.cameras]
    if len(named) > MAX_TEXTS_LISTED:
        return label.text in (f"{len(named)} cameras: {named[0]} ... {named[-1]}",
                              f"{len(named)} cameras:\n{named[0]} ...\n{named[-1]}")
    return label.text.split("\n") == named


def _covered(label, view: View) -> list[int]:
    """The cameras of `label`'s own group that its box covers on `view`'s screen."""
    left, top, right, bottom = label.box(view)
    return [i for i in label.cameras if left < view.px[i, 0] < right and top < view.px[i, 1] < bottom]


def test_labels_that_would_overlap_on_a_viewers_screen_share_one():
    """Twenty cameras a few metres off, seen in the page's narrow 3D column: their names were
    printed over each other. Labels that would overlap share one beside their cameras, so that none
    does, and every camera is named or counted once; seen closer, where each has room, every camera
    keeps its own."""
    names = [f"IMG_20240512_1034{i:02d}.jpg" for i in range(20)]
    positions = np.array([(x, y, z) for z in (-1.2, -1.8) for x in np.linspace(-0.9, 0.9, 5) for y in (-0.25, 0.2)])
    groups = label_groups(list(positions), 0.25)
    assert len(groups) == 20   # none standing together
    column = View.of(_camera((-1.5, -1.0, -5.0), (0, 0, -1.0), 446, 900, 50), positions)   # the page's 3D column
    # near enough for names as wide as DejaVu Sans draws them (at 4 m they would overlap there)
    close = View.of(_camera((0, 0, -3.5), (0, 0, -1.5), 1600, 1000, 50), positions)
    shared = labels_apart(groups, names, [column])
    assert sorted(i for label in shared for i in label.cameras) == list(range(20)) and not _overlapping(shared, column)
    assert any(len(label.cameras) > 1 for label in shared)
    for label in shared:
        assert _said(label, names) and label.fits(column) and not _covered(label, column), label
    assert [(label.at, label.cameras, label.text) for label in labels_apart(groups, names, [close])] == \
        [(i, [i], names[i]) for i in range(20)]
    # Apart on one viewer's screen is not enough: no label may overlap another on any.
    both = labels_apart(groups, names, [close, column])
    assert not _overlapping(both, close) and not _overlapping(both, column)


def test_a_shared_label_lists_several_names_a_line_to_fit_above_the_bottom_of_the_view():
    """In the 3D strip under the images (1280 px wide and less), some 300 px high, twenty names one a
    line ran past its bottom: a label lists several a line where one a line does not fit (here, six in
    a strip 60 px high)."""
    names = [f"IMG_20240512_1034{i:02d}.jpg" for i in range(MAX_TEXTS_LISTED)]
    positions = np.array([(x, 0, -2.0) for x in np.linspace(-0.1, 0.1, len(names))])
    strip = View.of(_camera((0, 0, -4), (0, 0.3, 0), 1260, 60, 50), positions)
    [label] = labels_apart(label_groups(list(positions), 0.001), names, [strip])
    lines = label.text.split("\n")
    assert label.fits(strip) and 1 < len(lines) < len(names)
    assert [name for line in lines for name in line.split(LABEL_SEPARATOR)] == names


def test_a_label_that_would_run_off_the_view_is_written_the_other_way():
    """A camera near the right edge of the page's narrow 3D column had its name cut off there."""
    # one camera 100 px left of the right edge, forty standing together 160 px above the bottom, at the left
    points = np.array([[0.13, -0.3, 0]] + [[-0.2, 0.3, 0]] * 40)
    view = View.of(_camera((0, 0, -1.0), (0, 0, 0), 446, 900, 50), points)
    names = [f"IMG_20240512_1034{i:02d}.jpg" for i in range(41)]
    right, low = labels_apart([[0], list(range(1, 41))], names, [view])
    assert right.anchor == "top-right" and right.fits(view)
    assert low.fits(view) and _said(low, names)


@pytest.mark.parametrize("text, measured_px", [
    # Chromium's widths of viser's label type where the sans-serif is DejaVu Sans (Debian's), less the padding
    ("35 cameras: scene_002.jpg ... IMG_20240512_103419.jpg", 348.5), ("scene_002.jpg", 86.5), ("WMm", 33.9),
])
def test_a_label_is_laid_out_at_least_as_wide_as_it_is_drawn(text, measured_px):
    """Widths taken from Arial's put a label of 19 digits 27 px narrower than drawn: it ran past the view."""
    assert label_size_px(text)[0] >= measured_px + 0.2 * LABEL_LINE_PX


def test_a_label_is_written_clear_of_the_view_edge():
    """A label laid out to end exactly at the left edge was drawn 1 px past it by the browser, which
    rounds the canvas' size its own way: a label that would come nearer an edge than LABEL_EDGE_PX is
    written the other way."""
    name = "IMG_20240512_103400.jpg"
    width, _ = label_size_px(name)
    view = View(px=np.array([[400 - width - 1, 100.0]]), width=400, height=300)   # its text ends 1 px short of the right edge
    [label] = labels_apart([[0]], [name], [view])
    assert label.anchor == "top-right" and label.fits(view)
    assert label.box(view)[0] >= LABEL_EDGE_PX


def test_many_cameras_sharing_a_label_are_counted_beside_them():
    """43 cameras in one sign world became one label listing every name, as tall as the view, written
    over the cameras: which frustum was which could not be told. More than MAX_TEXTS_LISTED are counted,
    with the first and last names, and a shared label is written beside its cameras, covering none."""
    rng = np.random.default_rng(7)
    positions = rng.uniform([-0.3, -0.2, -2.4], [0.3, 0.2, -1.6], (43, 3))   # a cluster 1.6-2.4 m off the sign
    names = [f"scene_{i:03d}.jpg" for i in range(43)]
    page = View.of(_camera((-1.8, -1.0, -6.0), (0, 0, -1.0), 1280, 900, 50), positions)   # viser's own page
    labels = labels_apart(label_groups(list(positions), 0.25), names, [page])
    assert sorted(i for label in labels for i in label.cameras) == list(range(43)) and not _overlapping(labels, page)
    many = [label for label in labels if len(label.cameras) > MAX_TEXTS_LISTED]
    assert many and all(label.text.count("\n") <= 2 for label in many)
    for label in labels:
        assert _said(label, names) and label.fits(page) and not _covered(label, page), label


def test_upload_button_adds_an_image(scene):
    handle, workspace = scene
    # What viser does when a browser upload completes (the value setter cannot take an UploadedFile).
    button = handle.upload
    button._impl.value = viser.UploadedFile("upload.jpg", sign_photo(workspace.library, "chief_of_security"))
    for callback in button._impl.update_cb:
        callback(viser.GuiEvent(client=None, client_id=None, target=button))
    record = workspace.images()[-1]
    try:
        assert record.name == "upload.jpg"
        settle(handle, workspace)
        assert record.id in handle.cameras and f"**{len(TRUTH) + 1}** images" in handle.status.content
    finally:
        workspace.remove_image(record.id)


def test_view_from_puts_the_client_at_the_camera_and_names_it(scene):
    """Clicking a frustum calls view_from with the clicking client; a stand-in records what it is told.
    Nothing said which camera was clicked, among cameras sharing a label or counted in one: the
    client is told its name."""
    handle, _ = scene

    class Camera:
        position = look_at = up_direction = None

    class Client:
        camera = Camera()
        notes = []

        def atomic(self):
            return contextlib.nullcontext()

        def add_notification(self, title, body, **options):
            self.notes.append((title, options))

    other = next(s for s in handle.signs if s != handle.world.value)
    image_id, nodes = next((k, n) for k, n in handle.cameras.items() if n.sign == other)
    client = Client()
    handle.view_from(image_id, client)
    assert handle.world.value == other
    axes = tf.SO3(np.asarray(nodes.frustum.wxyz)).as_matrix()
    np.testing.assert_allclose(client.camera.position, nodes.frustum.position)
    assert client.camera.look_at[2] == pytest.approx(0.0, abs=1e-9)  # the optical axis meets the sign plane
    direction = client.camera.look_at - client.camera.position
    np.testing.assert_allclose(direction / np.linalg.norm(direction), axes[:, 2], atol=1e-9)
    np.testing.assert_allclose(client.camera.up_direction, -axes[:, 1])
    name = next(r.name for r in handle.workspace.images() if r.id == image_id)
    [(title, options)] = client.notes
    assert title.split(" · ")[0] == name and options["auto_close_seconds"] > 0


def test_close_stops_following(scene):
    handle, workspace = scene
    handle.close()
    workspace.update_settings({"plaque_fallback": False, "min_inliers": 1000})
    assert workspace.wait_idle(IDLE_TIMEOUT_S)
    time.sleep(0.3)
    assert len(handle.cameras) == len(POSITIVES)
    assert handle.panel.controls["min_inliers"].input.value != 1000


def test_the_map_world_draws_every_mapped_sign_in_place_its_uncertainty_and_the_photos_cameras(workspace):
    """A map of the sample signs, one of them turned: the map world is shown as the map comes, each sign
    at its map pose with its 3-sigma ellipsoid, and each photo's camera located in the map frame (one
    sign in view: where its pose puts it in the sign's world, carried through the map)."""
    from signpose.app.map_scene import ELLIPSOID_SIGMAS
    from signpose.app.scene import MAP_WORLD
    from signpose.app.sign_maps import SignMaps
    from signpose.pipeline.pose import rotation_from_euler_zyx_deg
    from signpose.pipeline.sign_map import MappedSign, SignMap

    covariance = np.diag([1e-4, 4e-4, 9e-4, 1e-5, 1e-5, 1e-5])
    poses = {sign_id: (rotation_from_euler_zyx_deg(30.0 * i, 0.0, 0.0), np.array([2.0 * i, 0.1, -1.0 * i]))
             for i, sign_id in enumerate(workspace.library.ids)}
    sign_map = SignMap({s: MappedSign(s, R, p, covariance) for s, (R, p) in poses.items()})
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    maps = SignMaps(publish=workspace.publish)
    handle = attach(server, workspace, sign_maps=maps)
    try:
        wait_for(lambda: len(handle.cameras) == len(POSITIVES), timeout=IDLE_TIMEOUT_S)
        assert MAP_WORLD not in handle.world.options   # no map held: no map world
        maps.hold_file(sign_map, "test.yaml")
        # Until the redraw that chose the map world has also shown it (it sets the world, then the nodes).
        wait_for(lambda: handle.world.value == MAP_WORLD and len(handle.map_layer.cameras) == len(POSITIVES)
                 and handle.map_layer.root.visible, timeout=IDLE_TIMEOUT_S)
        layer = handle.map_layer
        assert not any(n.frame.visible for n in handle.signs.values())
        for sign_id, (R, position) in poses.items():
            nodes = layer.signs[sign_id]
            np.testing.assert_allclose(nodes.sign.frame.position, position)
            np.testing.assert_allclose(tf.SO3(nodes.sign.frame.wxyz).as_matrix(), R, atol=1e-12)
            np.testing.assert_allclose(sorted(nodes.ellipsoid.scale), ELLIPSOID_SIGMAS * np.array([0.01, 0.02, 0.03]))
        for image_id, (rec, camera, frustum) in layer.cameras.items():
            R, position = poses[rec.label]
            in_sign = handle.cameras[image_id].frustum.position
            # Within a centimetre: the fit in the map is over the sign's corners, the pose over its inliers.
            np.testing.assert_allclose(frustum.position, R @ in_sign + position, atol=0.01)
            assert camera.signs_used == (rec.label,)
        maps.clear()
        wait_for(lambda: MAP_WORLD not in handle.world.options and not layer.signs, timeout=IDLE_TIMEOUT_S)
    finally:
        handle.close()
        server.stop()


def test_a_flight_is_drawn_in_the_map_world_through_its_frames_located_in_the_map(tmp_path):
    """Frames that see a mapped sign (as a flight's records keep them) give the camera's trajectory in the map
    frame: each frame's camera where its pose puts it in the sign's frame, carried through the map; its current
    camera follows the frame the page shows."""
    from signpose.app.flights import Flight
    from signpose.app.map_scene import MapLayer
    from signpose.app.sign_maps import SignMaps
    from signpose.pipeline.library import load_library
    from signpose.pipeline.pose import Pose, camera_position, rotation_from_euler_zyx_deg
    from signpose.pipeline.sign_map import MappedSign, SignMap

    library = load_library()
    sign = library["security_compound"]
    camera = assumed_camera(640, 480)
    corners = sign.to_metric(sign.corners_px)
    records, expected = [], []
    for frame in range(4):
        R, t = rotation_from_euler_zyx_deg(0.0, 5.0 * frame, 0.0), np.array([0.1 * frame, 0.0, 2.0])
        px = cv2.projectPoints(corners, cv2.Rodrigues(R)[0], t, camera.K, camera.dist)[0].reshape(-1, 2)
        pose = Pose(R, t, "outline", 0.1, False, None, np.diag([1e-6] * 3 + [1e-6] * 3)).to_json()
        seen = [{"label": "security_compound", "corners": px.tolist(), "pose": pose, "filtered_pose": None}]
        records.append({"frame": frame, "signs": seen if frame != 2 else []})   # frame 2 sees nothing
        expected.append(camera_position(R, t))
    R_map, p_map = rotation_from_euler_zyx_deg(90.0, 0.0, 0.0), np.array([1.0, 2.0, 3.0])
    maps = SignMaps(publish=lambda *_: None)
    maps.hold_file(SignMap({"security_compound": MappedSign("security_compound", R_map, p_map)}), "test.yaml")
    flight = Flight("f1", "f1.mp4", "video", tmp_path, tmp_path / "f1.mp4", 640, 480, records=records,
                    tracked_camera=camera, fps=30.0, result_version=1)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        layer = MapLayer(server, maps, types.SimpleNamespace(held=lambda: [flight]), lambda records: [])
        layer.draw(library, [], 0.25)
        segments = np.asarray(layer.flight_nodes["f1"].trajectory.points)
        in_map = [R_map @ p + p_map for p in expected]
        # frames 0-1 and, across the gap of frame 2, none to 3
        np.testing.assert_allclose(segments, [[in_map[0], in_map[1]]], atol=1e-4)
        np.testing.assert_allclose(layer.flight_nodes["f1"].frusta[0].position, in_map[0], atol=1e-4)
        current = layer.flight_nodes["f1"].current
        assert current.visible   # at the cursor, frame 0
        for cursor, shown in ((3, True), (2, False)):   # the page scrubs to frame 3, then to 2, which sees no sign
            flight.cursor = cursor
            layer.show_cursor("f1")
            assert current.visible == shown
        np.testing.assert_allclose(current.position, in_map[3], atol=1e-4)
    finally:
        server.stop()


def test_a_photo_s_camera_in_the_map_world_is_fitted_to_every_mapped_sign_it_sees(tmp_path):
    """A survey photo that sees two mapped signs is located from both, as `recognize --map` locates it
    (every sign in view, one joint fit), not from its answer's sign alone; a photo of one sign from that one."""
    from signpose.app.sign_maps import SignMaps
    from signpose.pipeline.camera import load_camera
    from signpose.pipeline.every_sign import recognize_every_sign
    from signpose.pipeline.localise import locate_in_map
    from signpose.pipeline.settings import preset
    from signpose.pipeline.sign_map import load_sign_map

    room = SAMPLE_SCENES.parent / "surveys" / "room"
    truth = {p["image"]: p for p in json.loads((room / "truth.json").read_text())["photos"]}
    names = ["photo_000.jpg", "photo_002.jpg", "photo_005.jpg"]   # one sign, then two neighbours each
    ws = Workspace.open(WorkspaceConfig(state_dir=tmp_path / "state", library_dir=room / "library",
                                        camera_file=room / "camera.yaml", load_samples=False, workers=2))
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    maps = SignMaps(publish=ws.publish)
    handle = attach(server, ws, sign_maps=maps)
    try:
        ws.add_images([(name, (room / name).read_bytes(), None) for name in names])
        assert ws.wait_idle(IDLE_TIMEOUT_S)
        sign_map = load_sign_map(room / "truth_map.yaml")
        maps.hold_file(sign_map, "truth_map.yaml")
        wait_for(lambda: len(handle.map_layer.cameras) == len(names), timeout=IDLE_TIMEOUT_S)
        library, camera = ws.library, load_camera(room / "camera.yaml")
        by_name = {r.id: r.name for r in ws.images()}
        for image_id, (_, located, frustum) in handle.map_layer.cameras.items():
            name = by_name[image_id]
            found = recognize_every_sign(cv2.imread(str(room / name)), library, preset("default"), camera)
            cli = locate_in_map(found=found, sign_map=sign_map, library=library, camera=camera)
            assert located is not None and set(truth[name]["signs"]) <= set(located.signs_used)
            assert sorted(located.signs_used) == sorted(cli.signs_used)
            np.testing.assert_allclose(frustum.position, cli.position_m, atol=1e-6)
            np.testing.assert_allclose(located.position_m, truth[name]["camera_position"], atol=0.05)
    finally:
        handle.close()
        server.stop()
        ws.close()
