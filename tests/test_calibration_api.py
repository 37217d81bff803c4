"""Camera calibration in `signpose serve` (/api/calibration), against a real uvicorn server on a free
loopback port, with chessboard photos rendered under known intrinsics (tests/chessboards.py)."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from concurrent.futures import ThreadPoolExecutor

import cv2
import httpx
import numpy as np
import pytest

from signpose.app import calibration
from signpose.app.server import create_app
from signpose.app.workspace import WorkspaceConfig
from tests.support.chessboards import BOARD, K_TRUE, SIZE, SQUARE_M, render_boards, shaky_board
import signpose.pipeline.calibrate as pipeline_calibrate
from signpose.pipeline.calibrate import find_board, reference_size
from signpose.pipeline.camera import load_camera
from signpose.pipeline.evaluate import CORES
from signpose.pipeline.library import SAMPLE_LIBRARY, load_library
from tests.support.scene_images import sign_photo
from tests.support.serving import TIMEOUT_S, assert_error, iter_events, running, upload, wait_done

# The calibration routes, against a real uvicorn server.
pytestmark = pytest.mark.server

N_PHOTOS = 12
BOARD_SPEC = {"cols": BOARD[0], "rows": BOARD[1], "square_m": SQUARE_M}


@pytest.fixture(scope="module")
def photos() -> list[tuple[str, bytes]]:
    """(name, PNG bytes) of N_PHOTOS board photos through K_TRUE and its distortion."""
    images, _ = render_boards(N_PHOTOS)
    return [(f"board{i:02d}.png", cv2.imencode(".png", im)[1].tobytes()) for i, im in enumerate(images)]


@pytest.fixture(scope="module")
def base_url(tmp_path_factory):
    config = WorkspaceConfig(state_dir=tmp_path_factory.mktemp("calibration") / "state", load_samples=False,
                             workers=2, max_upload_bytes=4_000_000, max_pixels=1_000_000)
    with running(create_app(config)) as url:  # the app owns and closes the workspace
        yield url


@pytest.fixture
def client(base_url):
    """A client on a calibration with no photos and the rendered board, and no workspace camera."""
    with httpx.Client(base_url=base_url, timeout=TIMEOUT_S) as c:
        assert c.delete("/api/calibration").status_code == 200
        assert c.put("/api/calibration/board", json=BOARD_SPEC).status_code == 200
        yield c
        c.delete("/api/camera")


def add(client, photos: list[tuple[str, bytes]]) -> httpx.Response:
    return client.post("/api/calibration/images", files=[("files", (n, d, "image/png")) for n, d in photos])


def blank_png() -> bytes:
    return cv2.imencode(".png", np.full(SIZE[::-1], 200, np.uint8))[1].tobytes()


def shaky_photo(photos: list[tuple[str, bytes]], name: str = "shaky.png") -> tuple[str, bytes]:
    """(name, PNG bytes) of photos[3] made an outlier (`shaky_board`)."""
    image = cv2.imdecode(np.frombuffer(photos[3][1], np.uint8), cv2.IMREAD_GRAYSCALE)
    return name, cv2.imencode(".png", shaky_board(image))[1].tobytes()


def test_upload_run_apply_and_download(client, photos, tmp_path):
    sign = upload(client, ("sign.jpg", sign_photo(load_library(SAMPLE_LIBRARY), "security_compound"), None))
    sign_id = sign.json()["images"][0]["id"]
    wait_done(client)
    assert client.get(f"/api/images/{sign_id}").json()["camera"]["kind"] == "assumed"

    first = add(client, photos[:6] + [("blank.png", blank_png())])
    assert first.status_code == 201, first.text
    state = add(client, photos[6:]).json()
    assert [v["name"] for v in state["views"]] == [n for n, _ in photos[:6]] + ["blank.png"] + \
        [n for n, _ in photos[6:]]
    assert [v["found"] for v in state["views"]] == [True] * 6 + [False] + [True] * 6
    assert state["revision"] > first.json()["revision"] and state["result"] is None
    assert all((v["width"], v["height"]) == SIZE and v["error_px"] is None for v in state["views"])

    state = client.post("/api/calibration/run", json={}).json()
    result = state["result"]
    cam = result["camera"]
    assert cam["fx"] == pytest.approx(K_TRUE[0, 0], rel=0.005) and cam["fy"] == pytest.approx(K_TRUE[1, 1], rel=0.005)
    assert abs(cam["cx"] - K_TRUE[0, 2]) < 2 and abs(cam["cy"] - K_TRUE[1, 2]) < 2
    assert (cam["width"], cam["height"]) == SIZE and cam["kind"] == "calibration"
    assert result["rms_px"] < 0.3 and result["used"] == N_PHOTOS and result["warnings"] == []
    assert all(0 < s < 3 for s in result["intrinsics_std"].values())
    errors = [v["error_px"] for v in state["views"]]
    assert errors[6] is None and all(0 < e < 0.5 for e in errors[:6] + errors[7:])
    assert client.get("/api/calibration").json() == state

    view_id = state["views"][0]["id"]
    figures = {}
    for overlay in ("corners", "undistorted"):
        r = client.get(f"/api/calibration/views/{view_id}/image", params={"overlay": overlay})
        assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
        figures[overlay] = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
        assert figures[overlay].shape[:2] == SIZE[::-1]
        # drawChessboardCorners colours the corners: a gray photo gains saturated pixels.
        assert cv2.cvtColor(figures[overlay], cv2.COLOR_BGR2HSV)[..., 1].max() > 200
    # Undistorting moves the edges of the frame by pixels (k1 = -0.12): the two figures differ.
    assert np.abs(figures["corners"].astype(int) - figures["undistorted"]).mean() > 2
    thumb = client.get(f"/api/calibration/views/{view_id}/image", params={"max_side": 160})
    assert cv2.imdecode(np.frombuffer(thumb.content, np.uint8), cv2.IMREAD_COLOR).shape[:2] == (120, 160)

    yaml_file = tmp_path / "camera.yaml"
    r = client.get("/api/calibration/camera.yaml")
    assert r.status_code == 200 and "attachment" in r.headers["content-disposition"]
    yaml_file.write_bytes(r.content)
    back = load_camera(yaml_file)
    assert back.K[0, 0] == pytest.approx(cam["fx"]) and back.K[1, 2] == pytest.approx(cam["cy"])
    assert back.dist.tolist() == pytest.approx(cam["dist"]) and (back.width, back.height) == SIZE

    applied = client.post("/api/calibration/apply")
    assert applied.status_code == 200 and applied.json()["camera"] == cam
    assert client.get("/api/camera").json() == applied.json()
    wait_done(client)
    used = client.get(f"/api/images/{sign_id}").json()["camera"]
    assert used == cam and used["source"].startswith(f"calibration: {N_PHOTOS} views")
    client.delete(f"/api/images/{sign_id}")


def test_outliers_can_be_dropped_and_photos_deleted(client, photos):
    state = add(client, photos[:8] + [shaky_photo(photos, "warped.png")]).json()
    assert all(v["found"] for v in state["views"])
    state = client.post("/api/calibration/run", json={"drop_outliers": False}).json()
    warped_view = state["views"][8]
    assert warped_view["outlier"] and warped_view["error_px"] > state["result"]["outlier_threshold_px"]
    # What to do, in the words of the page, which shows it as it comes: its button, not the CLI's option.
    assert state["result"]["outlier_advice"] == "retake or drop them (drop outliers)"
    rms = state["result"]["rms_px"]
    state = client.post("/api/calibration/run", json={"drop_outliers": True}).json()
    assert state["views"][8]["excluded"] and state["result"]["used"] == 8 and state["result"]["rms_px"] < rms / 2
    assert (state["result"]["outlier_advice"] is None) == (not any(v["outlier"] for v in state["views"]))

    assert client.delete(f"/api/calibration/views/{warped_view['id']}").status_code == 204
    state = client.get("/api/calibration").json()
    assert len(state["views"]) == 8 and state["result"]["used"] == 8 and not any(v["excluded"] for v in state["views"])
    assert_error(client.delete(f"/api/calibration/views/{warped_view['id']}"), 404, "no calibration photo")


def test_deleting_a_photo_fits_the_photos_left(client, photos):
    """After DELETE /api/calibration/views/{id} the result was dropped: camera.yaml and apply
    answered 409 "no calibration yet: add photos of the board" to someone holding the rest."""
    add(client, photos[:5] + [shaky_photo(photos)])
    assert_error(client.get("/api/calibration/camera.yaml"), 409, "no calibration of the 6 photos held (none is "
                 "kept when photos are added or the board changes): run the calibration")
    ran = client.post("/api/calibration/run", json={"drop_outliers": True}).json()
    assert ran["views"][5]["excluded"] and ran["result"]["used"] == 5

    assert client.delete(f"/api/calibration/views/{ran['views'][0]['id']}").status_code == 204
    state = client.get("/api/calibration").json()
    assert state["result"]["used"] == 4 and state["views"][4]["excluded"] and state["unfitted"] is None
    assert state["result"]["camera"]["fx"] == pytest.approx(K_TRUE[0, 0], rel=0.01)
    assert state["result"]["camera"] != ran["result"]["camera"]  # fitted again, not the old one kept
    r = client.get("/api/calibration/camera.yaml")
    assert r.status_code == 200 and f"{state['result']['camera']['fx']:.6g}"[:6] in r.text
    assert client.post("/api/calibration/apply").json()["camera"] == state["result"]["camera"]

    for view in state["views"][:2]:  # 2 boards fitted are left, and the outlier
        assert client.delete(f"/api/calibration/views/{view['id']}").status_code == 204
    state = client.get("/api/calibration").json()
    assert len(state["views"]) == 3 and state["result"] is None
    assert state["unfitted"].startswith("the board was found in 2 usable image(s)")  # for the page to show
    for r in (client.post("/api/calibration/apply"), client.get("/api/calibration/camera.yaml")):
        assert_error(r, 409, "no calibration: the 3 photos left could not be fitted again: the board was found in 2 "
                             "usable image(s); calibration needs at least 3", "(the one dropped as an outlier stays out)")


def test_why_the_photos_left_give_no_fit_is_said_again_after_every_removal(client, photos):
    """Removing photos one by one after dropping an outlier: the first removal below 3 boards said
    why no fit was left, the next one blanked it, and apply and camera.yaml then answered 409 "none is
    kept when photos are added or the board changes", which nobody had done."""
    state = add(client, photos[:5] + [shaky_photo(photos), ("blank.png", blank_png())]).json()
    ran = client.post("/api/calibration/run", json={"drop_outliers": True}).json()
    assert ran["views"][5]["excluded"] and ran["result"]["used"] == 5
    for view in ran["views"][:3]:
        assert client.delete(f"/api/calibration/views/{view['id']}").status_code == 204
    assert client.get("/api/calibration").json()["unfitted"].startswith("the board was found in 2 usable image(s)")

    assert client.delete(f"/api/calibration/views/{ran['views'][3]['id']}").status_code == 204
    state = client.get("/api/calibration").json()
    assert len(state["views"]) == 3 and state["result"] is None
    assert state["unfitted"].startswith("the board was found in 1 usable image(s); calibration needs at least 3")
    assert state["unfitted"].endswith("(the one dropped as an outlier stays out)")
    for r in (client.post("/api/calibration/apply"), client.get("/api/calibration/camera.yaml")):
        assert_error(r, 409, "no calibration: the 3 photos left could not be fitted again: the board was found in 1 "
                             "usable image(s)")
        assert "none is kept" not in r.json()["detail"]

    # said again, for the photos now left: the outlier gone, nothing is said of it
    assert client.delete(f"/api/calibration/views/{ran['views'][5]['id']}").status_code == 204
    state = client.get("/api/calibration").json()
    assert state["unfitted"].startswith("the board was found in 1 usable image(s)") and "outlier" not in state["unfitted"]
    assert_error(client.get("/api/calibration/camera.yaml"), 409, "the 2 photos left could not be fitted again")
    # the last photo gone, there is nothing left to fit, and nothing to say of a fit
    for view in state["views"]:
        assert client.delete(f"/api/calibration/views/{view['id']}").status_code == 204
    state = client.get("/api/calibration").json()
    assert state["views"] == [] and state["unfitted"] is None
    assert_error(client.get("/api/calibration/camera.yaml"), 409, "no calibration yet: add photos")


def test_a_photo_dropped_as_an_outlier_is_shown_dropped_while_the_photos_left_give_no_fit(client, photos):
    """`unfitted` said "the one dropped as an outlier stays out" while that photo's view said
    excluded: false, as if it counted among the boards the fit could use."""
    add(client, photos[:4] + [shaky_photo(photos)])
    ran = client.post("/api/calibration/run", json={"drop_outliers": True}).json()
    assert ran["views"][4]["excluded"] and ran["result"]["used"] == 4
    for view in ran["views"][:2]:
        assert client.delete(f"/api/calibration/views/{view['id']}").status_code == 204
    state = client.get("/api/calibration").json()
    assert state["result"] is None and state["unfitted"].startswith("the board was found in 2 usable image(s)")
    assert state["unfitted"].endswith("(the one dropped as an outlier stays out)")
    assert [(v["name"], v["found"], v["excluded"]) for v in state["views"]] == [
        (photos[2][0], True, False), (photos[3][0], True, False), ("shaky.png", True, True)]
    assert sum(v["found"] and not v["excluded"] for v in state["views"]) == 2  # the count `unfitted` gives
    # a run fits afresh: every photo with the board, the one dropped before included
    state = client.post("/api/calibration/run", json={}).json()
    assert state["result"]["used"] == 3 and not any(v["excluded"] for v in state["views"])


def test_the_size_most_photos_share_is_worked_out_once_a_state(client, photos, monkeypatch):
    """Which photos are of another size than most and why they cannot be fitted together are both in every
    response, and each worked out anew the size most photos share, twice a response. A state never changes:
    once for the response to the change that made it and every one after."""
    counted = []

    def counting_reference_size(views: tuple, found: list[int]) -> tuple[int, int]:
        counted.append(len(found))
        return reference_size(views, found)

    for module in (calibration, pipeline_calibrate):  # where the session's properties and other_sizes look it up
        monkeypatch.setattr(module, "reference_size", counting_reference_size)
    assert add(client, photos[:3]).json()["size_mismatch"] is None
    assert all(v["other_size"] is None for v in client.get("/api/calibration").json()["views"])
    assert counted == [3]

def test_photos_of_another_size_than_most_are_flagged_before_any_run(client, photos):
    """A photo of another size was listed "found", and the page said to run the calibration, which
    every run refused (its message named each size): the odd photo is flagged, and why a run cannot
    fit them, before any run."""
    large = cv2.resize(cv2.imdecode(np.frombuffer(photos[4][1], np.uint8), cv2.IMREAD_GRAYSCALE), (800, 600))
    state = add(client, [("large.png", cv2.imencode(".png", large)[1].tobytes()), *photos[:4]]).json()
    assert all(v["found"] for v in state["views"]) and state["result"] is None
    # the size most photos share is the one others are measured against, whichever came first
    assert [v["other_size"] for v in state["views"]] == ["800x600, the others 640x480"] + [None] * 4
    assert state["size_mismatch"] == ("the photos must all be one size, as a calibration holds for one: 4 of the 5 "
                                      "with the board are 640x480 px, but large.png is 800x600 px, the same frame at "
                                      "another resolution (resized, or another resolution setting): retake it at "
                                      "640x480 or leave it out (the calibrated camera is scaled to photos of that "
                                      "shape when it is used)")
    assert_error(client.post("/api/calibration/run", json={}), 422, state["size_mismatch"])  # what a run says
    for r in (client.post("/api/calibration/apply"), client.get("/api/calibration/camera.yaml")):
        assert_error(r, 409, f"no calibration: {state['size_mismatch']}")

    assert client.delete(f"/api/calibration/views/{state['views'][0]['id']}").status_code == 204
    state = client.get("/api/calibration").json()
    assert state["size_mismatch"] is None and not any(v["other_size"] for v in state["views"])
    assert client.post("/api/calibration/run", json={}).json()["result"]["used"] == 4


def test_a_new_board_size_searches_every_photo_again(client, photos):
    add(client, photos[:3])
    state = client.put("/api/calibration/board", json=BOARD_SPEC | {"cols": 7, "rows": 5}).json()
    assert state["board"]["cols"] == 7 and not any(v["found"] for v in state["views"])
    # the page said "found in 0 (at least 3 needed)" and no more: a size given in squares is the usual cause
    assert "counts inner corners" in state["hint"] and "7x5 is a board of 8x6 squares" in state["hint"]
    assert_error(client.post("/api/calibration/run", json={}), 422, "7x5 board was not found", "inner corners")
    state = client.put("/api/calibration/board", json=BOARD_SPEC | {"square_m": 0.02}).json()
    assert all(v["found"] for v in state["views"]) and state["board"]["square_m"] == 0.02
    assert state["hint"] is None
    assert client.post("/api/calibration/run", json={}).json()["result"]["used"] == 3


def test_the_search_for_a_new_board_size_says_how_far_it_has_come(client, base_url, photos):
    """A new board size searches every photo again, some 10 s for 18 phone photos, and nothing said
    how far it had come: GET /api/calibration answers it while the PUT is under way."""
    assert add(client, photos).status_code == 201
    with ThreadPoolExecutor(1) as pool, httpx.Client(base_url=base_url, timeout=TIMEOUT_S) as other:
        change = pool.submit(other.put, "/api/calibration/board", json={**BOARD_SPEC, "cols": 7, "rows": 5})
        seen = []
        while not change.done():
            state = client.get("/api/calibration").json()
            if state["search"] is not None:
                assert state["board"]["cols"] == BOARD[0] and len(state["views"]) == N_PHOTOS  # the old, until done
                seen.append(state["search"])
            time.sleep(0.01)
        assert change.result().status_code == 200
    assert seen and {(s["cols"], s["rows"], s["total"]) for s in seen} == {(7, 5, N_PHOTOS)}
    done = [s["done"] for s in seen]
    assert done == sorted(done) and len(set(done)) > 1 and max(done) <= N_PHOTOS
    after = client.get("/api/calibration").json()
    assert after["search"] is None and after["board"]["cols"] == 7 and not any(v["found"] for v in after["views"])


def test_every_change_is_sent_to_every_client_as_a_calibration_event(client, base_url, photos):
    """The calibration is one for everyone using the server, and an open Camera dialog kept showing
    a photo another person had removed: no event said the calibration had changed. Every change is a
    `calibration` event with its revision, and a board search says how far it has come."""
    with httpx.Client(base_url=base_url, timeout=TIMEOUT_S) as listener, \
            listener.stream("GET", "/api/events") as stream:
        sent = (payload for kind, payload in iter_events(stream) if kind == "calibration")

        def sent_until(revision: int) -> list[dict]:
            """The calibration events up to the one of `revision` (events of a kind may collapse into the newest)."""
            seen = [next(sent)]
            while seen[-1]["revision"] < revision:
                seen.append(next(sent))
            assert seen[-1] == {"revision": revision, "search": None}
            return seen

        revision = add(client, photos[:4]).json()["revision"]
        sent_until(revision)
        sent_until(client.post("/api/calibration/run").json()["revision"])
        one = client.get("/api/calibration").json()["views"][0]["id"]
        assert client.delete(f"/api/calibration/views/{one}").status_code == 204
        sent_until(client.get("/api/calibration").json()["revision"])
        revision = client.put("/api/calibration/board", json=BOARD_SPEC | {"cols": 7, "rows": 5}).json()["revision"]
        searches = [event["search"] for event in sent_until(revision) if event["search"]]
        assert searches and {(s["cols"], s["rows"], s["total"]) for s in searches} == {(7, 5, 3)}
        sent_until(client.delete("/api/calibration").json()["revision"])


@pytest.mark.skipif(CORES < 2, reason="one core: no second search to run beside the first")
def test_photos_are_searched_side_by_side(client, photos, monkeypatch):
    """The board search took some 10 s for 18 phone photos on one core, one photo after another.
    The photos of an upload, and of a new board size, are searched side by side: here each
    search waits for a second one to start, which never came when they ran in turn."""
    together = threading.Barrier(2, timeout=10)

    def find_board_beside_another(gray, board, name=""):
        together.wait()
        return find_board(gray, board, name)

    monkeypatch.setattr(calibration, "find_board", find_board_beside_another)
    assert add(client, photos[:2]).status_code == 201
    state = client.put("/api/calibration/board", json=BOARD_SPEC | {"cols": 7, "rows": 5}).json()
    assert state["board"]["cols"] == 7 and [v["found"] for v in state["views"]] == [False, False]
    state = client.put("/api/calibration/board", json=BOARD_SPEC).json()
    assert [v["found"] for v in state["views"]] == [True, True]


def test_run_needs_no_body_as_a_curl_user_calls_it(client, photos):
    add(client, photos[:3])
    client.put("/api/calibration/board", json=BOARD_SPEC | {"square_m": 0.02})
    # curl -X POST URL (no body, no Content-Type); curl -d '' URL (an empty form); an empty JSON body
    for headers in ({}, {"content-type": "application/x-www-form-urlencoded"}, {"content-type": "application/json"}):
        r = client.post("/api/calibration/run", headers=headers)
        assert r.status_code == 200, r.text
        state = r.json()
        assert state["result"]["used"] == 3 and state["board"]["square_m"] == 0.02  # the board set, no outliers dropped
        assert not any(v["excluded"] for v in state["views"])
    r = client.post("/api/calibration/run", content=b"drop_outliers=1",
                    headers={"content-type": "application/x-www-form-urlencoded"})
    assert_error(r, 415, "no body, or a JSON body")


def test_bad_input_gets_a_clear_4xx_and_changes_nothing(client, photos):
    before = client.get("/api/calibration").json()
    assert_error(add(client, [photos[0], ("notes.png", b"these are not pixels"), ("cut.png", photos[1][1][:3000])]),
                 422, "2 of the 3 files cannot be used, so none was added: (1) notes.png: not an image",
                 "(2) cut.png: damaged or truncated PNG")
    assert_error(client.post("/api/calibration/images", files={"files": ("empty.png", b"", "image/png")}), 422,
                 "empty")
    for bad, words in (({"cols": 2}, ("at least 3x3", "inner corners")), ({"rows": 0}, ("inner corners",)),
                       ({"cols": 500}, ("at most 100",)), ({"square_m": 0}, ("square size", "metres")),
                       ({"square_m": -0.02}, ("square size",)), ({"cols": "nine"}, ("cols",)),
                       ({"square_m": None}, ("square_m",))):
        assert_error(client.put("/api/calibration/board", json=BOARD_SPEC | bad), 422, *words)
    assert_error(client.put("/api/calibration/board", content=b"9x6", headers={"content-type": "text/plain"}), 415,
                 "JSON")
    assert client.get("/api/calibration").json() == before

    assert_error(client.post("/api/calibration/run", json={}), 422, "no calibration photos")
    add(client, photos[:2] + [("blank.png", blank_png())])
    assert_error(client.post("/api/calibration/run", json={}), 422, "found in 2 usable image(s)", "at least 3")
    for r in (client.post("/api/calibration/apply"), client.get("/api/calibration/camera.yaml")):
        # found in most: its size is right, and photos are what is missing
        assert_error(r, 409, "board is found in 2 of the 3 photos held", "at least 3 (15-20 recommended): add photos "
                             "of the board")
        assert "inner corners" not in r.json()["detail"]
    assert client.get("/api/calibration").json()["hint"] == "add photos of the board"
    view_id = client.get("/api/calibration").json()["views"][0]["id"]
    assert_error(client.get(f"/api/calibration/views/{view_id}/image", params={"overlay": "undistorted"}), 409,
                 "found in 2 of the 3 photos held")
    assert client.get(f"/api/calibration/views/{view_id}/image", params={"overlay": "sideways"}).status_code == 422
    assert_error(client.get("/api/calibration/views/123456789abc/image"), 404, "no calibration photo")
    assert client.get("/api/camera").json()["camera"] is None
    assert client.get("/api/health").json()["status"] == "ok"


def test_photo_limit(client, photos):
    session = client.get("/api/calibration").json()
    assert session["max_views"] >= 20 and session["min_views"] == 3 and session["max_square_m"] == 1.0
    assert_error(add(client, [photos[0]] * (session["max_views"] + 1)), 409, "limit is", "delete some")
    assert client.get("/api/calibration").json()["views"] == []


def test_photos_sent_a_request_each_are_listed_in_the_order_chosen(client, photos):
    """Sent three at a time, they were numbered as they landed; the fit's views follow that order."""
    for position in (2, 0, 1):
        name, data = photos[position]
        r = client.post("/api/calibration/images", files={"files": (name, data, "image/png")},
                        data={"batch": "b", "position": position})
        assert r.status_code == 201, r.text
    r = client.post("/api/calibration/images", files=[("files", (n, d, "image/png")) for n, d in photos[3:6]],
                    data={"batch": "b", "position": 3})
    assert r.status_code == 201, r.text
    assert [v["name"] for v in r.json()["views"]] == [n for n, _ in photos[:6]]
    assert r.json()["added"] == [v["id"] for v in r.json()["views"][3:6]]   # which are this request's


def test_the_answer_names_the_photo_it_added_whatever_its_name(client, photos):
    """Views are listed in the order chosen, and two phones both write IMG_0001.jpg: the page read
    the last view, or the last of that name, as the one just added, and said "board found" of a
    photo without the board."""
    board, blank = photos[0][1], blank_png()
    first = client.post("/api/calibration/images", files={"files": ("IMG_0001.png", blank, "image/png")},
                        data={"batch": "b", "position": 1}).json()
    second = client.post("/api/calibration/images", files={"files": ("IMG_0001.png", board, "image/png")},
                         data={"batch": "b", "position": 0}).json()
    found = {v["id"]: v["found"] for v in second["views"]}
    assert [found[first["added"][0]], found[second["added"][0]]] == [False, True]
    assert [v["name"] for v in second["views"]] == ["IMG_0001.png", "IMG_0001.png"]
    assert_error(client.post("/api/calibration/images", files={"files": photos[6]}, data={"batch": "b", "position": "-1"}),
                 422, "position")


def test_api_doc_names_every_field_the_calibration_answer_has(client, photos):
    """docs/api.md's row for GET /api/calibration names every field of the answer, of its views and of its
    result (`views`, each with `error_px` and `tilt_deg`, not a summary such as "(found, error, ...)")."""
    assert add(client, photos).status_code == 201
    answer = client.post("/api/calibration/run").json()
    api_doc = (Path(__file__).resolve().parents[1] / "docs" / "api.md").read_text(encoding="utf-8")
    row = next(line for line in api_doc.splitlines() if line.startswith("| `GET /api/calibration`"))
    fields = {*answer, *answer["views"][0], *answer["result"]}
    assert [f for f in sorted(fields) if f"`{f}`" not in row] == []
