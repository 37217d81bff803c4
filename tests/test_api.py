"""The `signpose serve` HTTP API, SSE and viser relay, against a real uvicorn server on a free loopback port."""

from __future__ import annotations

import json
import math
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from signpose.app.figures import DIM, GREEN, RED, TEXT_BLOCK_PX, UNSEEN, stage_figure
from signpose.app.server import create_app
from signpose.app.viser_proxy import CANVAS_SCRIPT
from signpose.app.workspace import Workspace, WorkspaceConfig
from signpose.pipeline.library import SAMPLE_LIBRARY, load_library
from signpose.pipeline.recognize import recognize
from signpose.pipeline.settings import preset
from signpose.pipeline.verify import CHECK_WIDTH
from signpose.pipeline.synth import synthetic_camera
from signpose.pipeline.camera import load_camera, ros_camera_yaml
from tests.support.scene_images import (DECOYS, HEIC_START, OFF_CENTRE, big_photo, decoy_image, empty_photo, has,
                                        plaque_of, png_bomb, scrambled_scene, sign_photo, tiny_photo, TURNED_WITHIN_M,
                                        turned_photos, turned_scene_position, with_focal_exif)
from tests.support.serving import (MISFIT_CAMERA, REPO, TIMEOUT_S, VISER_PROTOCOL, assert_error, http_exchange,
                                   iter_events, running, start_serve, stop_serve, upload, wait_done)

# The HTTP API, against a real uvicorn server (one per module, and more per test).
pytestmark = pytest.mark.server

LIBRARY = load_library(SAMPLE_LIBRARY)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAX_UPLOAD = 2_000_000
MAX_IMAGES = 20


def config(state_dir: Path, **options) -> WorkspaceConfig:
    return WorkspaceConfig(state_dir=state_dir, load_samples=False, workers=2, max_upload_bytes=MAX_UPLOAD,
                           max_images=MAX_IMAGES, max_pixels=1_000_000, **options)


@pytest.fixture(scope="module")
def base_url(tmp_path_factory):
    workspace = Workspace.open(config(tmp_path_factory.mktemp("api") / "state"))
    try:
        with running(create_app(workspace)) as url:
            yield url
    finally:
        workspace.close()


@pytest.fixture
def client(base_url):
    with httpx.Client(base_url=base_url, timeout=TIMEOUT_S) as c:
        yield c


def add_photos(client, *sign_ids: str) -> list[str]:
    """Upload a labelled photo per sign id ("none": a wall without a sign); their ids once processed."""
    r = upload(client, *[(f"{sid}.jpg", empty_photo(i) if sid == "none" else sign_photo(LIBRARY, sid, seed=i), sid)
                         for i, sid in enumerate(sign_ids)])
    assert r.status_code == 201, r.text
    ids = [i["id"] for i in r.json()["images"]]
    wait_done(client)
    return ids


# ---------------------------------------------------------------- server

def test_health_docs_and_every_contract_path_in_openapi(client):
    assert client.get("/api/health").json() | {"version": "x", "images": 0, "memory_held_bytes": 0} == \
        {"status": "ok", "version": "x", "images": 0, "busy": False, "memory_held_bytes": 0,
         "memory_limit_bytes": WorkspaceConfig.max_memory_bytes}
    docs = client.get("/docs").text
    assets = re.findall(r'(?:src|href)="([^"]+)"', docs)
    assert assets and all(a.startswith("/docs-assets/") for a in assets), assets   # nothing from a CDN
    assert all(client.get(a).status_code == 200 for a in assets)
    assert client.get("/").headers["content-type"].startswith("text/html")  # the page, from static/
    paths = client.get("/openapi.json").json()["paths"]
    for path in ("/api/health", "/api/settings", "/api/settings/schema", "/api/presets",
                 "/api/settings/preset/{name}", "/api/settings/export", "/api/settings/import", "/api/library",
                 "/api/library/{sign_id}/image", "/api/library/{sign_id}", "/api/images", "/api/images/{image_id}",
                 "/api/images/{image_id}/file", "/api/images/{image_id}/stages/{stage}", "/api/recognize",
                 "/api/calibrate/threshold", "/api/sweep", "/api/camera", "/api/camera/file", "/api/camera/assumed",
                 "/api/events",
                 "/api/calibration", "/api/calibration/images", "/api/calibration/board", "/api/calibration/run",
                 "/api/calibration/views/{view_id}/image", "/api/calibration/views/{view_id}",
                 "/api/calibration/apply", "/api/calibration/camera.yaml",
                 "/api/flights", "/api/flights/{flight_id}", "/api/flights/{flight_id}/frames",
                 "/api/flights/{flight_id}/frames/{index}", "/api/flights/{flight_id}/frames/{index}/image",
                 "/api/flights/{flight_id}/cursor", "/api/flights/{flight_id}/export"):
        assert path in paths, path


def test_events_stream_starts_with_the_state_and_follows_changes(client, base_url):
    with httpx.Client(base_url=base_url, timeout=TIMEOUT_S) as listener, \
            listener.stream("GET", "/api/events") as stream:
        assert stream.headers["content-type"].startswith("text/event-stream")
        events = iter_events(stream)
        kind, first = next(events)
        assert kind == "settings" and "threshold" in first["settings"]
        assert next(events)[0] == "results"
        version = client.put("/api/settings", json={"min_margin": 6}).json()["version"]
        assert any(k == "settings" and p["version"] == version for k, p in events)
    client.put("/api/settings", json={"min_margin": 5})


# Raw bodies: NaN and Infinity are what Python's json reads and writes for non-finite floats.
@pytest.mark.parametrize("method, path, body, where, what", [
    ("PUT", "/api/calibration/board", '{"cols": NaN, "rows": 6, "square_m": 0.02}', "body.cols", "finite"),
    ("PATCH", "/api/images/{id}", '{"expected": NaN}', "body.expected", "string"),
    ("PUT", "/api/settings", "[NaN]", "body", "dictionary"),
    ("POST", "/api/calibrate/threshold", '{"image_id": "{id}", "rect": [NaN, 0, 10, 10]}', "body.rect.0", "finite"),
    ("POST", "/api/calibrate/threshold", '{"image_id": "{id}", "rect": [1e308, 0, 1e309, 10]}', "body.rect.2",
     "finite"),
    ("PUT", "/api/camera/assumed", '{"hfov_deg": [NaN]}', "body.hfov_deg", "number"),
    ("POST", "/api/calibration/run", '{"drop_outliers": Infinity}', "body.drop_outliers", "boolean"),
    ("PUT", "/api/settings", "not json", "the body is not valid JSON", "line 1 column 1 (char 0)"),
    ("PUT", "/api/camera", '{"fx": 1,', "the body is not valid JSON", "line 1 column 10 (char 9)"),
    ("GET", "/api/sweep?steps=many", None, "query.steps", "integer"),
])
def test_validation_errors_are_one_line_that_never_echoes_the_input(client, method, path, body, where, what):
    image_id = upload(client, ("t.jpg", tiny_photo(), None)).json()["images"][0]["id"]
    r = client.request(method, path.replace("{id}", image_id), content=body and body.replace("{id}", image_id),
                       headers={"content-type": "application/json"})
    client.delete(f"/api/images/{image_id}")
    # not 500: FastAPI's default answer echoed the NaN and could not encode it
    assert_error(r, 422, f"{where}: ", what)


# ---------------------------------------------------------------- settings

def test_settings_read_change_and_refuse_bad_values(client):
    before = client.get("/api/settings").json()
    r = client.put("/api/settings", json={"ratio": 0.7})
    assert r.status_code == 200 and r.json()["version"] == before["version"] + 1
    assert r.json()["settings"]["ratio"] == 0.7
    raw = {"content": b'{"threshold": NaN}', "headers": {"content-type": "application/json"}}
    assert_error(client.put("/api/settings", **raw), 422, "threshold", "finite")
    assert_error(client.put("/api/settings", content=b'{"threshold": Infinity}',
                            headers={"content-type": "application/json"}), 422, "finite")
    assert_error(client.put("/api/settings", json={"threshold": 1.2}), 422, "between 0.0 and 1.0")
    assert_error(client.put("/api/settings", json={"treshold": 0.5}), 422, "unknown setting", "treshold")
    assert_error(client.put("/api/settings", json={"max_features": "many"}), 422, "max_features", "number")
    assert_error(client.put("/api/settings", json={"detector": "surf"}), 422, "sift")
    assert client.put("/api/settings", json=[1, 2]).status_code == 422
    assert client.get("/api/settings").json()["version"] == before["version"] + 1
    client.put("/api/settings", json={"ratio": before["settings"]["ratio"]})


def test_schema_presets_export_and_import(client):
    schema = {f["name"]: f for f in client.get("/api/settings/schema").json()}
    assert schema["threshold"] | {"help": ""} == schema["threshold"] | {
        "type": "float", "group": "Segmentation", "min": 0.0, "max": 1.0, "help": ""}
    assert schema["detector"]["choices"] == ["sift", "orb"]
    presets = client.get("/api/presets").json()
    assert set(presets) == {"paper", "default"} and presets["paper"]["threshold"] == 0.75
    assert client.post("/api/settings/preset/paper").json()["settings"]["threshold"] == 0.75
    assert_error(client.post("/api/settings/preset/fast"), 404, "paper", "default")

    exported = client.get("/api/settings/export")
    assert exported.headers["content-disposition"] == 'attachment; filename="signpose-settings.json"'
    client.post("/api/settings/preset/default")
    r = client.post("/api/settings/import", files={"file": ("s.json", exported.content, "application/json")})
    assert r.status_code == 200 and r.json()["settings"] == presets["paper"]
    assert_error(client.post("/api/settings/import", files={"file": ("s.json", b"{oops", "application/json")}),
                 422, "s.json", "not valid JSON")
    assert_error(client.post("/api/settings/import", files={"file": ("s.json", b"", "application/json")}),
                 422, "s.json is an empty file (nothing in it to read)")
    assert_error(client.post("/api/settings/import", files={"file": ("s.json", b'{"ratio": 7}', "application/json")}),
                 422, "ratio")
    # what GET /api/settings answers, saved to a file, was refused as two unknown settings
    client.post("/api/settings/preset/paper")
    answered = client.get("/api/settings").content
    client.post("/api/settings/preset/default")
    r = client.post("/api/settings/import", files={"file": ("saved.json", answered, "application/json")})
    assert r.status_code == 200 and r.json()["settings"] == presets["paper"], r.text
    client.post("/api/settings/preset/default")


# ---------------------------------------------------------------- library

def test_library_list_image_add_and_delete(client):
    signs = client.get("/api/library").json()
    assert [s["id"] for s in signs] == LIBRARY.ids
    assert set(signs[0]) == {"id", "name", "text", "image", "width_m", "height_m", "kind", "min_text_correlation"}
    assert (signs[0]["kind"], signs[0]["min_text_correlation"]) == ("plaque", None)
    image = client.get(f"/api/library/{signs[0]['id']}/image")
    assert image.status_code == 200 and image.content.startswith(PNG_SIGNATURE)

    photo = sign_photo(LIBRARY, "security_compound")  # 640 x 480
    form = {"id": "door_plate", "name": "Door plate", "width_m": "0.4", "height_m": "0.3"}
    r = client.post("/api/library", files={"file": ("d.jpg", photo, "image/jpeg")}, data=form)
    assert r.status_code == 201 and r.json()["id"] == "door_plate" and r.json()["image"].endswith(".png")
    # Told from the image: a photo of a plaque on a textured wall is a picture.
    assert (r.json()["kind"], r.json()["min_text_correlation"]) == ("picture", None)
    assert client.get("/api/library/door_plate/image").content.startswith(PNG_SIGNATURE)
    assert_error(client.post("/api/library", files={"file": ("d.jpg", photo, "image/jpeg")}, data=form),
                 409, "already has")
    for bad, words in (({"id": "../../etc/passwd"}, ("id", "a-z")), ({"id": "Caps"}, ("id",)),
                       ({"width_m": "nan"}, ("width_m",)), ({"width_m": "-1"}, ("width_m",)),
                       ({"width_m": "abc"}, ("body.width_m: ", "number")),
                       ({"width_m": "400"}, ("metres",)), ({"width_m": "30"}, ("centimetres", "30 cm is 0.3 m")),
                       ({"width_m": "0.0003"}, ("0.3 mm", "metres")), ({"height_m": "0.1"}, ("aspect",)),
                       ({"kind": "poster"}, ("kind 'poster'", '"plaque"', '"picture"')),
                       ({"min_text_correlation": "5"}, ("min_text_correlation", "from 0 (no check) to 1"))):
        r = client.post("/api/library", files={"file": ("d.jpg", photo, "image/jpeg")}, data=form | {"id": "x"} | bad)
        assert_error(r, 422, *words)
    assert_error(client.post("/api/library", files={"file": ("d.jpg", b"GIF89a nope", "image/gif")},
                             data=form | {"id": "y"}), 422, "damaged or truncated GIF")
    assert client.get("/api/library/..%2F..%2Fstate/image").status_code == 404
    assert_error(client.get("/api/library/passwd/image"), 404, "no sign", "known")
    assert client.delete("/api/library/door_plate").status_code == 204
    assert_error(client.delete("/api/library/door_plate"), 404, "door_plate", "known")
    # Said to be a plaque, with its own bar for the text check: kept as given.
    r = client.post("/api/library", files={"file": ("d.jpg", photo, "image/jpeg")},
                    data=form | {"kind": "plaque", "min_text_correlation": "0.3"})
    assert r.status_code == 201 and (r.json()["kind"], r.json()["min_text_correlation"]) == ("plaque", 0.3)
    assert [(s["kind"], s["min_text_correlation"]) for s in client.get("/api/library").json()
            if s["id"] == "door_plate"] == [("plaque", 0.3)]
    assert client.delete("/api/library/door_plate").status_code == 204
    assert [s["id"] for s in client.get("/api/library").json()] == LIBRARY.ids


def test_the_state_library_with_a_sign_added_is_a_library_as_read_elsewhere(tmp_path):
    """library.json refuses unknown keys: what the server writes beside the signs (where they came from, the
    signs added) must not be one, or `signpose recognize --library <state>/library` would refuse it."""
    workspace = Workspace.open(config(tmp_path / "state"))
    with running(create_app(workspace)) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as client:
        photo = sign_photo(LIBRARY, "security_compound")
        r = client.post("/api/library", files={"file": ("d.jpg", photo, "image/jpeg")},
                        data={"id": "door_plate", "width_m": "0.4", "height_m": "0.3"})
        assert r.status_code == 201, r.text
    written = json.loads((workspace.state.library_dir / "library.json").read_text(encoding="utf-8"))
    assert written["added"] == ["door_plate"]
    assert load_library(workspace.state.library_dir).ids == [*LIBRARY.ids, "door_plate"]


def test_a_sign_drawn_on_a_transparent_ground_is_a_sign_on_white(client):
    """Artwork exported with a transparent ground was refused as blank: alpha dropped, black on black."""
    sign = plaque_of(DECOYS[0])
    artwork = np.dstack([np.zeros((*sign.image.shape, 3), np.uint8), 255 - sign.image])  # only the ink is opaque
    form = {"id": "artwork", "width_m": str(sign.width_m), "height_m": str(sign.height_m)}
    r = client.post("/api/library", data=form,
                    files={"file": ("a.png", cv2.imencode(".png", artwork)[1].tobytes(), "image/png")})
    assert r.status_code == 201, r.text
    stored = cv2.imdecode(np.frombuffer(client.get("/api/library/artwork/image").content, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert stored.shape == sign.image.shape and np.abs(stored.astype(int) - sign.image).mean() < 1
    assert client.delete("/api/library/artwork").status_code == 204


def test_a_sign_whose_image_cannot_be_told_from_another_signs_is_refused_naming_it(client):
    """The same image under a second id was taken, and then neither sign was ever recognised ("margin over
    the runner-up too small"), or the wrong one was."""
    chief = LIBRARY["chief_of_security"]
    again = cv2.imencode(".jpg", chief.image, [cv2.IMWRITE_JPEG_QUALITY, 80])[1].tobytes()  # re-exported
    form = {"id": "chief_2", "width_m": str(chief.width_m)}
    r = client.post("/api/library", data=form, files={"file": ("chief.jpg", again, "image/jpeg")})
    assert_error(r, 409, "'chief_2'", "too like", "'chief_of_security' (Chief of Security)",
                 "delete 'chief_of_security' first")
    assert [s["id"] for s in client.get("/api/library").json()] == LIBRARY.ids


# ---------------------------------------------------------------- images

def test_upload_list_detail_label_and_delete(client):
    photo = sign_photo(LIBRARY, "chief_of_security")
    r = upload(client, ("chief.jpg", photo, "chief_of_security"), ("wall.jpg", empty_photo(), "none"),
               ("unlabelled.jpg", sign_photo(LIBRARY, "security_compound"), None))
    assert r.status_code == 201
    ids = [i["id"] for i in r.json()["images"]]
    summaries = {i["id"]: i for i in wait_done(client)}
    assert [summaries[i]["status"] for i in ids] == ["correct", "correct", "recognized"]
    chief = summaries[ids[0]]
    assert chief["label"] == "chief_of_security" and chief["inliers"] > 12 and (chief["width"], chief["height"]) == (
        640, 480)

    detail = client.get(f"/api/images/{ids[0]}").json()
    assert detail["result"]["label"] == "chief_of_security" and len(detail["result"]["corners"]) == 4
    assert detail["result"]["pose"]["camera_position"] is not None
    assert detail["camera"]["source"].startswith("assumed") and detail["attempts"][-1]["winner"] == "chief_of_security"
    file = client.get(f"/api/images/{ids[0]}/file")
    assert file.content == photo and file.headers["content-type"] == "image/jpeg"

    r = client.patch(f"/api/images/{ids[2]}", json={"expected": "ministry_of_torture"})
    assert r.status_code == 200 and r.json()["status"] == "wrong"
    assert_error(client.patch(f"/api/images/{ids[2]}", json={"expected": "ministry"}), 422, "not a sign", "none")
    sneaky = upload(client, ("../../../etc/cron.d/x.jpg", tiny_photo(), None)).json()["images"][0]
    assert sneaky["name"] == "x.jpg"  # a label only: stored under a server-chosen name
    for image_id in [*ids, sneaky["id"]]:
        assert client.delete(f"/api/images/{image_id}").status_code == 204
    assert_error(client.get(f"/api/images/{ids[0]}"), 404, ids[0])
    assert_error(client.delete(f"/api/images/{ids[0]}"), 404)
    assert_error(client.get("/api/images/..%2F..%2Fsettings.json/file"), 404)


def test_stage_figures(client):
    image_id = add_photos(client, "ministry_of_torture")[0]
    for stage in ("input", "gray", "mask", "blob", "crop", "matches", "inliers"):
        r = client.get(f"/api/images/{image_id}/stages/{stage}")
        assert r.status_code == 200 and r.content.startswith(PNG_SIGNATURE), stage
        assert r.headers["content-type"] == "image/png" and r.headers["x-settings-version"].isdigit()
    assert client.get(f"/api/images/{image_id}/stages/matches?sign=security_compound").status_code == 200
    assert_error(client.get(f"/api/images/{image_id}/stages/matches?sign=nope"), 404, "not in the library")
    assert_error(client.get(f"/api/images/{image_id}/stages/sift"), 422, "input")
    client.delete(f"/api/images/{image_id}")


def test_the_blob_figure_tints_the_chosen_blob_and_dims_the_rest():
    """The chosen blob half photo, half green; every other pixel the photo dimmed (boxes and their
    labels aside)."""
    photo = cv2.imread(str(REPO / "sample_images" / "scenes" / "scene_004.jpg"))
    rec = recognize(photo, load_library(), preset("default"))
    assert rec.attempt.source == "blob 1"
    figure = stage_figure("blob", photo, rec, load_library()).astype(float)
    inner = cv2.erode((rec.segmentation.labels == 1).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    away = rec.segmentation.labels == 0
    for x0, y0, x1, y1 in rec.segmentation.crops:
        away[max(0, y0 - 8):y1 + 8, max(0, x0 - 8):x1 + 8] = False  # each crop's box
        away[max(0, y0 - 40):y0 + 8] = False  # and its label, moved along to fit the image
    assert inner.sum() > 1000 and away.sum() > 100_000
    assert np.abs(figure[inner] - (0.5 * photo[inner] + 0.5 * np.array(GREEN))).max() <= 1
    assert np.abs(figure[away] - DIM * photo[away]).max() <= 1


def test_text_check_figure_or_why_there_is_none(client):
    sign_id, wall_id = add_photos(client, "ministry_of_torture", "none")
    r = client.get(f"/api/images/{sign_id}/stages/text")
    assert r.status_code == 200 and r.content.startswith(PNG_SIGNATURE) and r.headers["x-settings-version"].isdigit()
    figure = cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR)
    assert figure.shape[1] == CHECK_WIDTH * TEXT_BLOCK_PX  # the template's pixels as blocks, not resampled
    assert has(figure, GREEN) and not has(figure, RED) and not has(figure, UNSEEN)  # every strip seen and passing
    assert_error(client.get(f"/api/images/{wall_id}/stages/text"), 404, "no sign was recognised", "scores")
    # A plaque of other words features read as chief_of_security: its turned-down check, in red.
    decoy = cv2.imencode(".jpg", decoy_image(DECOYS[0], 0), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    decoy_id = upload(client, ("decoy.jpg", decoy, None)).json()["images"][0]["id"]
    wait_done(client)
    result = client.get(f"/api/images/{decoy_id}").json()["result"]
    assert not result["recognized"] and result["turned_down"][0]["text_check"]["weakest"] < 0.7
    r = client.get(f"/api/images/{decoy_id}/stages/text")
    assert r.status_code == 200 and has(cv2.imdecode(np.frombuffer(r.content, np.uint8), cv2.IMREAD_COLOR), RED)
    # A plaque of a sign's words and more: every strip passes, and the foot says, in red, where it goes on.
    more = cv2.imencode(".png", decoy_image("مجمع أمني جديد", 0))[1].tobytes()
    more_id = upload(client, ("more.png", more, None)).json()["images"][0]["id"]
    wait_done(client)
    check = client.get(f"/api/images/{more_id}").json()["result"]["turned_down"][0]["text_check"]
    assert check["weakest"] > 0.9 and check["continued"] == ["left"], check
    figure = cv2.imdecode(np.frombuffer(client.get(f"/api/images/{more_id}/stages/text").content, np.uint8),
                          cv2.IMREAD_COLOR)
    assert has(figure, GREEN) and has(figure[-figure.shape[0] // 8:], RED), "no red line at the foot"
    client.delete(f"/api/images/{more_id}")
    before = client.get("/api/settings").json()["settings"]["min_text_correlation"]
    client.put("/api/settings", json={"min_text_correlation": 0})  # as the paper preset has it
    wait_done(client)
    assert_error(client.get(f"/api/images/{sign_id}/stages/text"), 404, "text check is off",
                 "min_text_correlation 0")
    client.put("/api/settings", json={"min_text_correlation": before})
    wait_done(client)
    for image_id in (sign_id, wall_id, decoy_id):
        client.delete(f"/api/images/{image_id}")


def label_bands(figure: np.ndarray) -> list[np.ndarray]:
    """The black bands the figure's labels are written on (solid black but for the text), as crops."""
    black = np.all(figure == 0, axis=2).astype(np.uint8)
    _, _, stats, _ = cv2.connectedComponentsWithStats(black, connectivity=4)
    return [figure[y:y + h, x:x + w] for x, y, w, h, area in stats[1:] if area > 200 and area > 0.5 * w * h]


@pytest.mark.parametrize("scene, sign, by_plaque", [
    ("scenes/scene_002.jpg", "security_compound", False),  # its region's label sat under the answer's
    ("datasets/set2/scene_007.jpg", "ministry_of_torture", True),  # once labelled "no sign"
])
def test_input_figure_shows_every_label_and_the_answer(client, scene, sign, by_plaque):
    r = upload(client, (Path(scene).name, (REPO / "sample_images" / scene).read_bytes(), sign))
    image_id = r.json()["images"][0]["id"]
    wait_done(client)
    detail = client.get(f"/api/images/{image_id}").json()
    assert detail["status"] == "correct" and detail["by_plaque"] == by_plaque
    # the plaque fallback matches no features: no inliers or margin, but the correlation that decided
    assert (detail["inliers"] is None and detail["margin"] is None) == by_plaque
    assert (detail["plaque_correlation"] is not None) == by_plaque
    summary = next(i for i in client.get("/api/images").json()["images"] if i["id"] == image_id)
    assert summary == {k: v for k, v in detail.items() if k in summary}  # the gallery's summary says the same
    figure = cv2.imdecode(np.frombuffer(client.get(f"/api/images/{image_id}/stages/input").content, np.uint8),
                          cv2.IMREAD_COLOR)
    bands = label_bands(figure)
    assert len(bands) == len(detail["attempts"]) + 1  # one per searched region and the answer's: none overlap
    assert sum(has(b, GREEN) for b in bands) == 1 and not any(has(b, RED) for b in bands)  # the sign, no "no sign"
    for a, b in zip(detail["result"]["corners"], np.roll(detail["result"]["corners"], -1, axis=0)):
        x, y = np.round((np.array(a) + b) / 2).astype(int)  # the middle of each side of the outline
        assert has(figure[y - 1:y + 2, x - 1:x + 2], GREEN), (x, y)
    client.delete(f"/api/images/{image_id}")


@pytest.mark.parametrize("name, data, expected, code, words", [
    ("empty.jpg", b"", None, 422, ("empty.jpg", "empty")),
    ("notes.jpg", b"meeting at 10, bring the photos", None, 422, ("notes.jpg", "not an image")),
    ("cut.jpg", sign_photo(LIBRARY, "security_compound")[:9000], None, 422, ("cut.jpg: damaged or truncated JPEG",)),
    ("head.jpg", sign_photo(LIBRARY, "security_compound")[:300], None, 422, ("head.jpg: damaged or truncated JPEG",)),
    ("scrambled.jpg", scrambled_scene(), None, 422, ("scrambled.jpg: damaged or truncated JPEG", "data is corrupt")),
    ("IMG_0001.HEIC", HEIC_START, None, 422, ("IMG_0001.HEIC: HEIC/HEIF images are not supported", "Most Compatible")),
    ("bomb.png", png_bomb(1500, 1000), None, 413, ("bomb.png", "1500x1000", "megapixels")),
    ("huge_bomb.png", png_bomb(), None, 413, ("huge_bomb.png: 20000x20000 px is 400.0 megapixels", "--max-megapixels")),
    ("x.jpg", sign_photo(LIBRARY, "security_compound"), "no_such_sign", 422, ("no_such_sign", "security_compound")),
])
def test_bad_uploads_get_a_clear_4xx_and_nothing_is_kept(client, name, data, expected, code, words):
    before = len(client.get("/api/images").json()["images"])
    r = upload(client, ("fine.jpg", sign_photo(LIBRARY, "chief_of_security"), None), (name, data, expected))
    assert_error(r, code, *words)
    assert len(client.get("/api/images").json()["images"]) == before
    assert client.get("/api/health").json()["status"] == "ok"


def test_upload_count_and_label_mismatches(client):
    photo = tiny_photo()
    assert_error(upload(client, *[(f"{i}.jpg", photo, None) for i in range(MAX_IMAGES + 1)]), 409,
                 f"limit is {MAX_IMAGES}", "delete some")
    r = client.post("/api/images", files=[("files", ("a.jpg", photo, "image/jpeg"))] * 3,
                    data={"expected": ["none", ""]})
    assert_error(r, 422, "2 expected labels for 3 files", "one for all of them, one per file")


def test_one_expected_label_is_given_to_every_file(client):
    """One label for 10 files was a 422 (one per file was needed): a folder of one sign's photos
    took a label per photo."""
    photos = [("files", (f"{i}.jpg", sign_photo(LIBRARY, "chief_of_security", seed=i), "image/jpeg"))
              for i in range(10)]
    r = client.post("/api/images", files=photos, data={"expected": "chief_of_security"})
    assert r.status_code == 201, r.text
    assert [i["expected"] for i in r.json()["images"]] == ["chief_of_security"] * 10
    ids = {i["id"] for i in r.json()["images"]}
    assert all(i["status"] == "correct" for i in wait_done(client) if i["id"] in ids)
    for image_id in ids:
        client.delete(f"/api/images/{image_id}")
    assert_error(client.post("/api/images", files={"expected": (None, "none")}), 422, "files")


def test_a_batch_sent_a_file_a_request_is_listed_in_its_order_whatever_lands_first(tmp_path):
    """Three uploads at a time land in any order, and were listed so: b02, b01, b00. With the batch
    and each file's position in it they are listed as chosen, also after a restart; a batch's
    files stay together, where its first one landed."""
    def post(c, name, **order):
        r = c.post("/api/images", files={"files": (name, tiny_photo(), "image/jpeg")}, data=order)
        assert r.status_code == 201, r.text

    def names(c):
        return [i["name"] for i in c.get("/api/images").json()["images"]]

    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        post(c, "before.jpg")
        post(c, "b2.jpg", batch="b", position=2)
        post(c, "other.jpg")                        # another client's, meanwhile
        post(c, "c0.jpg", batch="c", position=0)
        post(c, "b0.jpg", batch="b", position=0)
        two = [("files", (n, tiny_photo(), "image/jpeg")) for n in ("c1.jpg", "c2.jpg")]
        assert c.post("/api/images", files=two, data={"batch": "c", "position": 1}).status_code == 201
        post(c, "b1.jpg", batch="b", position=1)
        listed = ["before.jpg", "b0.jpg", "b1.jpg", "b2.jpg", "other.jpg", "c0.jpg", "c1.jpg", "c2.jpg"]
        assert names(c) == listed
        for data, words in (({"batch": "b", "position": "-1"}, ("position", "greater than or equal to 0")),
                            ({"batch": "b", "position": "first"}, ("position", "integer")),
                            ({"batch": "x" * 65}, ("batch", "at most 64")),
                            ({"batch": ["b", "c"]}, ("got 2 values", "'batch'"))):
            assert_error(c.post("/api/images", files={"files": ("x.jpg", tiny_photo(), "image/jpeg")}, data=data),
                         422, *words)
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        assert names(c) == listed
        post(c, "b3.jpg", batch="b", position=3)   # a batch from before the restart: after everything
        assert names(c) == [*listed, "b3.jpg"]


@pytest.mark.parametrize("path, listing, listed", [("/api/images", "/api/images", "images"),
                                                   ("/api/calibration/images", "/api/calibration", "views")])
@pytest.mark.parametrize("order", [{"position": "2"}, {"batch": "", "position": "0"}])
def test_a_position_without_a_batch_is_refused(client, path, listing, listed, order):
    """It was ignored: the file was listed where it landed, not at the place the client meant."""
    def ids():
        return [i["id"] for i in client.get(listing).json()[listed]]

    before = ids()
    r = client.post(path, files={"files": ("x.jpg", tiny_photo(), "image/jpeg")}, data=order)
    assert_error(r, 422, "'position' is the place of this request's files within a 'batch' and needs one",
                 "send 'batch' too")
    assert ids() == before


def test_uploads_past_the_memory_limit_are_refused_saying_what_fits(tmp_path):
    """Without a memory cap a server could grow by 110 MB per 12 MP photo, and the default --max-images 500
    would need 55 GB. Each image held counts 5 bytes a pixel plus 1 MB against a limit."""
    photo = big_photo(1000, 750)  # 0.75 megapixels: counted 4.75 MB
    cfg = WorkspaceConfig(state_dir=tmp_path / "state", load_samples=False, workers=2, max_memory_bytes=12_000_000)
    with running(create_app(cfg)) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        assert upload(c, ("a.jpg", photo, None), ("b.jpg", photo, "security_compound")).status_code == 201
        held = wait_done(c)
        # What the refusal below counts, for an operator to see before uploading.
        assert c.get("/api/health").json() | {"version": ""} == {
            "status": "ok", "version": "", "images": 2, "busy": False, "memory_held_bytes": 9_500_000,
            "memory_limit_bytes": 12_000_000}
        assert_error(upload(c, ("c.jpg", photo, None)), 409, "the 2 images held take 9.5 MB of the server's memory "
                     "limit of 12 MB (--max-memory-gb); c.jpg (0.8 megapixels) would take 4.75 MB more and 2.5 MB is "
                     "left: an image of up to 0.3 megapixels fits; delete some images")
        too_big = upload(c, ("huge.jpg", big_photo(2000, 1500), None))  # alone over the limit: 413
        assert_error(too_big, 413, "huge.jpg: 3.0 megapixels would take 16 MB held", "memory limit of 12 MB")
        assert wait_done(c) == held  # nothing held is lost or changed
        assert [c.get(f"/api/images/{i['id']}/file").content for i in held] == [photo, photo]
        assert c.delete(f"/api/images/{held[0]['id']}").status_code == 204
        assert c.get("/api/health").json()["memory_held_bytes"] == 4_750_000
        assert_error(upload(c, *[(f"{i}.jpg", photo, None) for i in range(3)]), 409,
                     "these 3 images would take 14.2 MB more and 7.25 MB is left: only the first of them fits")
        assert upload(c, ("d.jpg", photo, None)).status_code == 201
        assert len(wait_done(c)) == 2 and len(list((tmp_path / "state" / "images").glob("*.jpg"))) == 2


def test_oversized_bodies_are_refused_before_or_while_they_arrive(base_url, client):
    # Declared too large: refused from the headers alone, the body is never sent.
    head = (b"POST /api/images HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: multipart/form-data; boundary=b\r\n"
            b"Content-Length: 30000000\r\nConnection: close\r\n\r\n")
    status, body = http_exchange(base_url, head)
    assert status == 413 and "30.0 MB" in body["detail"] and "2.0 MB" in body["detail"]
    # the page sends one file per request: a single large photo needs the limit raised, where it is set
    assert "or start the server with a higher limit (signpose serve --max-upload-mb 30)" in body["detail"]
    # Streamed without a length: refused as soon as the bytes received pass the limit.
    head = (b"POST /api/images HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: multipart/form-data; boundary=b\r\n"
            b"Transfer-Encoding: chunked\r\nConnection: close\r\n\r\n")
    part = b"--b\r\nContent-Disposition: form-data; name=\"files\"; filename=\"big.jpg\"\r\n\r\n"
    block = b"x" * 65536
    chunks = [b"%x\r\n%s\r\n" % (len(part), part)] + [b"%x\r\n%s\r\n" % (len(block), block)] * (
        MAX_UPLOAD // len(block) + 2)
    status, body = http_exchange(base_url, head, chunks)
    assert status == 413 and "limit of 2.0 MB" in body["detail"] and body["detail"].endswith("--max-upload-mb)")
    assert client.get("/api/health").status_code == 200


def test_stateless_recognize(client):
    before = len(client.get("/api/images").json()["images"])
    r = client.post("/api/recognize", files={"file": ("p.jpg", sign_photo(LIBRARY, "security_compound"), "image/jpeg")})
    assert r.status_code == 200
    body = r.json()
    assert body["image"] == "p.jpg" and body["label"] == "security_compound" and len(body["homography"]) == 3
    assert {"scores", "pose", "timing_ms", "warnings", "corners", "recognized"} <= set(body)
    # every sign in view, as `recognize --json` lists them; no map held, so no camera in it
    assert [s["label"] for s in body["signs"]] == ["security_compound"] and body["signs"][0]["pose"] == body["pose"]
    assert body["camera_in_map"] is None
    assert len(client.get("/api/images").json()["images"]) == before
    assert_error(client.post("/api/recognize", files={"file": ("e.jpg", b"", "image/jpeg")}), 422, "empty")


CAMERA_YAML = ros_camera_yaml(synthetic_camera((640, 480)), "synthetic").encode()


def test_a_field_or_parameter_a_route_does_not_take_is_refused_naming_it(client):
    """Dropped without a word, they read as applied: min_inliers=1000 on a recognition that used 10."""
    photo = ("a.jpg", sign_photo(LIBRARY, "security_compound"), "image/jpeg")
    assert_error(client.post("/api/recognize?min_inliers=1000", files={"file": photo}), 422,
                 "unknown query parameter 'min_inliers': this request takes none")
    assert_error(client.post("/api/recognize", files={"file": photo}, data={"detector": "orb"}), 422,
                 "unknown form field 'detector': this request takes 'file'")
    assert_error(client.put("/api/camera/assumed", json={"hfov_deg": 60, "x": 1}), 422,
                 "body.x: unknown key, which this request does not take")
    assert client.get("/api/library/security_compound/image?v=1").status_code == 200  # a page's cache-busting
    # A method the route has not, or a route there is not: said, not the page's bare 404 "Not Found".
    r = client.get("/api/recognize")
    assert_error(r, 405, "GET /api/recognize: this route takes POST")
    assert r.headers["allow"] == "POST"
    assert_error(client.delete("/api/settings"), 405, "this route takes GET, PUT")
    assert_error(client.get("/api/nothing"), 404, "no API route /api/nothing", "/docs")


@pytest.mark.parametrize("method, path, files, form", [
    ("POST", "/api/recognize", [("a.jpg", sign_photo(LIBRARY, "security_compound"), "image/jpeg"),
                                ("b.jpg", sign_photo(LIBRARY, "chief_of_security"), "image/jpeg")], None),
    ("POST", "/api/settings/import", [("a.json", b'{"ratio": 0.7}', "application/json"),
                                      ("b.json", b'{"ratio": 0.6}', "application/json")], None),
    ("POST", "/api/library", [("a.jpg", sign_photo(LIBRARY, "security_compound"), "image/jpeg"),
                              ("b.jpg", sign_photo(LIBRARY, "chief_of_security"), "image/jpeg")],
     {"id": "door_plate", "width_m": "0.4"}),
    ("PUT", "/api/camera", [("a.yaml", CAMERA_YAML, "application/x-yaml"),
                            ("b.yaml", CAMERA_YAML, "application/x-yaml")], None),
])
def test_single_file_routes_refuse_several_files_or_none(client, method, path, files, form):
    def state():
        return [client.get(p).json() for p in ("/api/settings", "/api/library", "/api/camera")]

    before = state()
    r = client.request(method, path, files=[("file", f) for f in files], data=form)
    assert_error(r, 422, "got 2 files", "'file'", "one request per file")  # not the last one, silently
    assert_error(client.request(method, path, files=[("files", files[0])], data=form), 422, "'file'")
    assert state() == before


@pytest.mark.parametrize("method, path, field, form", [
    ("POST", "/api/images", "files", None), ("POST", "/api/calibration/images", "files", None),
    ("POST", "/api/recognize", "file", None), ("POST", "/api/settings/import", "file", None),
    ("POST", "/api/library", "file", {"id": "door_plate", "width_m": "0.4"}), ("PUT", "/api/camera", "file", None),
])
def test_a_part_without_a_file_name_is_said_to_be_no_file(client, method, path, field, form):
    def state():
        # the images held, not their results, which an earlier test's re-run may still be updating
        held = [i["id"] for i in client.get("/api/images").json()["images"]]
        return [held, *(client.get(p).json() for p in ("/api/calibration", "/api/library", "/api/camera"))]

    before = state()
    photo = sign_photo(LIBRARY, "security_compound")
    # A file sent with an empty name (httpx, like many clients, then leaves the filename out), and a text field.
    for part in (("", photo, "image/jpeg"), (None, "photo.jpg")):
        r = client.request(method, path, files=[(field, part)], data=form)
        assert_error(r, 422, f"the part in the multipart field '{field}' is not a file", "file name",
                     f"curl -F '{field}=@")
        assert "UploadFile" not in r.text and "class" not in r.text
    if field == "files":  # the second of two: said which
        r = client.request(method, path, files=[(field, ("a.jpg", photo, "image/jpeg")), (field, (None, "b"))])
        assert_error(r, 422, f"part 2 of 2 in the multipart field '{field}' is not a file")
    assert state() == before
    assert client.get("/api/health").json()["status"] == "ok"


@pytest.mark.parametrize("field, values", [("id", ["door_plate", "exit"]), ("width_m", ["0.4", "4"]),
                                           ("name", ["Door", "Exit"]), ("text", ["a", "b"]),
                                           ("height_m", ["0.3", "0.2"])])
def test_add_sign_refuses_a_repeated_text_field(client, field, values):
    form = {"id": "door_plate", "width_m": "0.4"} | {field: values}
    r = client.post("/api/library", files={"file": ("d.jpg", sign_photo(LIBRARY, "security_compound"), "image/jpeg")},
                    data=form)
    assert_error(r, 422, "got 2 values", f"'{field}'", "send it once")  # not the last one, silently
    assert [s["id"] for s in client.get("/api/library").json()] == LIBRARY.ids


# ---------------------------------------------------------------- tuning

def test_threshold_calibration(client):
    sign_id, wall_id = add_photos(client, "security_compound", "none")
    auto = client.post("/api/calibrate/threshold", json={"image_id": sign_id}).json()
    assert auto["source"] == "detected sign" and auto["white_level"] > 0.9
    assert auto["background_level"] < auto["suggested_threshold"] < auto["white_level"]
    assert len(auto["histogram"]) == 256 and sum(auto["histogram"]) > 10_000
    rect = client.post("/api/calibrate/threshold", json={"image_id": sign_id, "rect": [200, 180, 440, 280]}).json()
    assert rect["source"] == "rectangle" and rect["rect"] == [200, 180, 440, 280]
    assert sum(rect["histogram"]) == 240 * 100
    assert_error(client.post("/api/calibrate/threshold", json={"image_id": sign_id, "rect": [700, 0, 900, 50]}),
                 422, "640x480")
    assert_error(client.post("/api/calibrate/threshold", json={"image_id": wall_id}), 422, "send rect [x0, y0, x1, y1]")
    assert_error(client.post("/api/calibrate/threshold", json={"image_id": "0123456789ab"}), 404)
    for image_id in (sign_id, wall_id):
        client.delete(f"/api/images/{image_id}")


def test_threshold_calibration_measures_the_blob_when_the_answer_came_from_elsewhere(client):
    """Nothing recognised, the features' best region the full frame: the server looked only at the
    region its answer came from and refused (422) though the page drew the blob and asked after
    every settings change. It measures the largest blob now."""
    (image_id,) = add_photos(client, "security_compound")
    try:
        client.put("/api/settings", json={"min_inliers": 200, "plaque_fallback": False, "zoom_fallback": False}).raise_for_status()
        wait_done(client)
        attempts = [a["source"] for a in client.get(f"/api/images/{image_id}").json()["attempts"]]
        assert attempts == ["blob 1", "full frame"], attempts
        r = client.post("/api/calibrate/threshold", json={"image_id": image_id})
        assert r.status_code == 200, r.text
        assert r.json()["source"] == "blob" and r.json()["white_level"] > 0.9
    finally:
        client.post("/api/settings/preset/default").raise_for_status()
        client.delete(f"/api/images/{image_id}")


@pytest.mark.parametrize("end, value", [("lo", "-inf"), ("hi", "inf"), ("lo", "nan"), ("hi", "NaN")])
def test_sweep_ends_must_be_finite(client, end, value):
    assert_error(client.get("/api/sweep", params={end: value}), 422, f"{end} must be a finite number, got {value.lower()}")


def test_sweep_finds_the_working_band(client):
    ids = add_photos(client, "security_compound", "chief_of_security", "none")
    r = client.get("/api/sweep", params={"param": "threshold", "lo": 0.1, "hi": 0.99, "steps": 9})
    assert r.status_code == 200, r.text
    sweep = r.json()
    assert sweep["labelled"] >= 3 and len(sweep["values"]) == len(sweep["correct"]) == 9
    lo, hi = sweep["band"]
    assert lo <= sweep["centre"] <= hi and sweep["correct"][sweep["values"].index(lo)] == sweep["labelled"]
    assert all(m is None or m >= 0 for m in sweep["min_margin"])
    assert all(type(v) is float for v in [*sweep["values"], *sweep["band"], sweep["centre"]])
    ints = client.get("/api/sweep", params={"param": "min_inliers", "lo": 4, "hi": 7, "steps": 5}).json()
    assert ints["values"] == [4, 5, 6, 7]
    # a whole number, one that was tried and worked: the settings take no 5.5
    assert ints["band"] == [4, 7] and ints["centre"] == 5
    # JSON whole numbers, not 4.0, 5.0: the page's chart took them for a continuous range
    assert all(type(v) is int for v in [*ints["values"], *ints["band"], ints["centre"]])
    swept = client.get("/api/sweep", params={"param": "min_inliers", "lo": 4, "hi": 30, "steps": 14}).json()
    assert swept["values"] == list(range(4, 31, 2)) and all(type(v) is int for v in swept["values"])
    assert_error(client.get("/api/sweep", params={"param": "detector"}), 422, "numeric setting", "threshold")
    assert_error(client.get("/api/sweep", params={"lo": 0.9, "hi": 0.3}), 422, "below")
    # a value between them was named, 1.15 for hi=2, or 1.0625 for hi=1.5
    for ends, words in (({"lo": 0.3, "hi": 2}, "hi (2): threshold must be between 0.0 and 1.0; got 2.0"),
                        ({"lo": -0.5, "hi": 0.5}, "lo (-0.5): threshold must be between 0.0 and 1.0; got -0.5")):
        assert client.get("/api/sweep", params={"param": "threshold", **ends}).json() == {"detail": words}
    # sizes min_crop_size (128) and max_crop_size (160) refuse are left out: 0 is never downscale
    crops = client.get("/api/sweep", params={"param": "max_crop_size", "lo": 0, "hi": 240, "steps": 4})
    assert crops.status_code == 200 and crops.json()["values"] == [0, 160, 240], crops.text
    crops = client.get("/api/sweep", params={"param": "min_crop_size", "lo": 0, "hi": 240, "steps": 4})
    assert crops.status_code == 200 and crops.json()["values"] == [0, 80, 160], crops.text
    assert_error(client.get("/api/sweep", params={"param": "min_crop_size", "lo": 200, "hi": 240, "steps": 2}), 422,
                 "no value of min_crop_size from lo (200) to hi (240) goes with the other settings: min_crop_size "
                 "(200) must be at most max_crop_size (160)")
    assert client.get("/api/sweep", params={"steps": 1}).status_code == 422
    for image_id in ids:
        client.delete(f"/api/images/{image_id}")


def test_the_sweep_leaves_signs_the_plaque_fallback_found_out_of_its_margins(tmp_path):
    """A min_inliers sweep from 4 to 30 answered min_margin 0 at every value, and the chart's margin
    axis became 0..1: a sign the plaque fallback recognised, which matches no features, counted as
    a correct recognition with margin 0."""
    plaque = (REPO / "sample_images" / "datasets" / "set2" / "scene_007.jpg").read_bytes()
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        upload(c, ("plaque.jpg", plaque, "ministry_of_torture"),
               ("compound.jpg", sign_photo(LIBRARY, "security_compound"), "security_compound"))
        wait_done(c)
        sweep = c.get("/api/sweep", params={"param": "min_inliers", "lo": 4, "hi": 30, "steps": 14}).json()
    assert any(sweep["by_plaque"]) and all(n <= c for n, c in zip(sweep["by_plaque"], sweep["correct"]))
    for correct, by_plaque, margin in zip(sweep["correct"], sweep["by_plaque"], sweep["min_margin"]):
        # the smallest margin of the signs recognised by features, the default min_margin at least
        assert margin >= 5 if correct > by_plaque else margin is None


def test_a_failure_at_one_value_leaves_the_rest_of_the_sweep(tmp_path, fail_segmentation):
    """The pipeline failing on one image at one value answered the whole sweep with 422, and every
    sweep after it too while the image stayed."""
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        upload(c, ("compound.jpg", sign_photo(LIBRARY, "security_compound"), "security_compound"))
        wait_done(c)
        fail_segmentation(lambda _, settings: settings.threshold == 0.6)  # the server runs in this process
        r = c.get("/api/sweep", params={"param": "threshold", "lo": 0.5, "hi": 0.7, "steps": 3})
    assert r.status_code == 200, r.text
    sweep = r.json()
    assert sweep["failed"] == [0, 1, 0] and sweep["correct"] == [1, 0, 1]


def test_sweep_needs_labelled_images(tmp_path):
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        upload(c, ("unlabelled.jpg", tiny_photo(), None))
        assert_error(c.get("/api/sweep"), 409, "no labelled images", "expected label")


# ---------------------------------------------------------------- camera

NO_CAMERA = {"camera": None, "assumed_hfov_deg": 60.0, "exif_images": 0, "warnings": []}


def test_camera_json_file_errors_and_reset(client):
    assert client.get("/api/camera").json() == NO_CAMERA
    r = client.put("/api/camera", json={"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480})
    assert r.status_code == 200 and r.json()["camera"]["fx"] == 600 and r.json()["camera"]["source"] == "json"
    assert r.json()["camera"]["kind"] == "typed"
    r = client.put("/api/camera", files={"file": ("cam.yaml", CAMERA_YAML, "application/x-yaml")})
    assert r.status_code == 200 and r.json()["camera"]["source"] == "upload:cam.yaml"
    assert r.json()["camera"]["kind"] == "file"
    assert client.get("/api/camera").json() == r.json()
    r = client.put("/api/camera", files={"file": ("cam.yaml", b"camera_matrix: {rows: 3, cols: 3, data: [1, 2]}",
                                                   "application/x-yaml")})
    assert_error(r, 422, "cam.yaml", "3x3")
    assert "/tmp" not in r.json()["detail"]
    assert_error(client.put("/api/camera", files={"file": ("c.yaml", b": : :", "application/x-yaml")}), 422, "c.yaml")
    assert_error(client.put("/api/camera", json={"fx": -5, "fy": 600, "cx": 320, "cy": 240}), 422, "positive")
    assert_error(client.put("/api/camera", json={"fx": 600}), 422, "fy")
    assert_error(client.put("/api/camera", content=b"fx=600", headers={"content-type": "text/plain"}), 415, "JSON")
    assert client.delete("/api/camera").json() == NO_CAMERA
    assert_error(client.get("/api/camera/file"), 404, "no camera is set")


@pytest.mark.parametrize("body", [
    {"K": [[500, 0, 320], [0, 510, 240], [0, 0, 1]], "D": [-0.1, 0.01, 0, 0, 0], "width": 640, "height": 480},
    {"camera_matrix": {"rows": 3, "cols": 3, "data": [500, 0, 320, 0, 510, 240, 0, 0, 1]},
     "distortion_coefficients": {"rows": 1, "cols": 5, "data": [-0.1, 0.01, 0, 0, 0]},
     "image_width": 640, "image_height": 480},
])
def test_camera_json_may_be_a_camera_files_keys(client, body):
    # scripts hold OpenCV's or ROS's JSON, not fx, fy, cx, cy
    r = client.put("/api/camera", json=body)
    assert r.status_code == 200, r.text
    camera = r.json()["camera"]
    assert [camera[k] for k in ("fx", "fy", "cx", "cy", "width", "height")] == [500, 510, 320, 240, 640, 480]
    assert camera["dist"] == [-0.1, 0.01, 0, 0, 0]
    assert_error(client.put("/api/camera", json={"K": [[500, 0, 320], [0, 510, 240]]}), 422, "3x3")
    assert_error(client.put("/api/camera", json={"D": [0, 0, 0, 0]}), 422, "camera_matrix", "K")


TYPED = {"fx": 554, "fy": 554, "cx": 320, "cy": 240, "width": 640, "height": 480}


def test_camera_json_gives_the_camera_its_file_gives(client):
    """PUT /api/camera took D beside fx, fy, cx, cy as no distortion: pydantic dropped the keys CameraModel has not."""
    body = TYPED | {"D": [-0.2, 0.05, 0, 0, 0]}
    typed = client.put("/api/camera", json=body)
    assert typed.status_code == 200, typed.text
    filed = client.put("/api/camera", files={"file": ("cam.json", json.dumps(body).encode(), "application/json")})
    assert filed.status_code == 200, filed.text
    assert typed.json()["camera"] | {"source": "", "kind": ""} == filed.json()["camera"] | {"source": "", "kind": ""}
    assert typed.json()["camera"]["dist"] == [-0.2, 0.05, 0, 0, 0]
    client.delete("/api/camera")


@pytest.mark.parametrize("body, message", [
    (TYPED | {"k1": 0.1}, "k1: not a key signpose reads, and without it the lens would be taken as distortion-free"),
    (TYPED | {"distortion": [-0.2, 0.05, 0, 0, 0]}, "distortion: not a key signpose reads"),
    (TYPED | {"distortion_model": "fisheye", "dist": [0.1, 0, 0, 0]}, "distortion_model 'fisheye' is not supported"),
    (TYPED | {"distortion_model": "plumb_bob"}, "distortion_model plumb_bob names a lens with distortion, but the "
                                                "file gives no coefficients"),
    (TYPED | {"distortion_model": "plumb_bob", "D": []}, "distortion_model plumb_bob names a lens with distortion, "
                                                         "but the file gives no coefficients (D is empty)"),
    (TYPED | {"K": [[600, 0, 320], [0, 600, 240], [0, 0, 1]]}, "the camera matrix is given twice, as K and fx"),
    (TYPED | {"dist": [0.1, 0, 0, 0], "D": [0.1, 0, 0, 0]}, "the distortion is given twice, as D and dist"),
    (TYPED | {"fx": "554"}, "fx must be a number, not text: write 554 without quotes"),
    (TYPED | {"fx": None}, "fx is null: give it a number"),
    (TYPED | {"width": None}, "width is null: give it a number, or leave out both the image width and height"),
    (TYPED | {"fx": math.nan}, "camera matrix has non-finite values"),  # NaN as Python's json writes it
], ids=["k1", "distortion", "fisheye", "plumb_bob without D", "plumb_bob with D empty", "K and fx", "dist and D",
        "fx text", "fx null", "width null", "fx NaN"])
def test_camera_json_is_read_as_the_same_camera_file(client, body, message):
    """Each was taken with 200 and the key dropped or misread (or refused with pydantic's words): the body is read
    by the camera file reader, which refuses it as it refuses the file of the same content, with its message."""
    before = client.get("/api/camera").json()
    r = client.put("/api/camera", content=json.dumps(body), headers={"content-type": "application/json"})
    assert_error(r, 422, message)
    filed = client.put("/api/camera", files={"file": ("cam.json", json.dumps(body).encode(), "application/json")})
    assert_error(filed, 422)
    assert filed.json()["detail"] == f"cam.json: {r.json()['detail']}"
    assert client.get("/api/camera").json() == before


@pytest.mark.parametrize("path, body, message", [
    # PUT /api/camera's body is read as a camera file is (test_camera_json_is_read_as_the_same_camera_file)
    ("/api/camera", {"fx": "500"}, "fx must be a number, not text: write 500 without quotes"),
    ("/api/camera", {"cy": True}, "cy must be a number; got true"),
    ("/api/camera", {"dist": [-0.1, "0.02"]}, "dist must be a number, not text: write 0.02 without quotes"),
    ("/api/camera", {"width": "640", "height": 480},
     "width must be a whole number, not text: write 640 without quotes"),
    ("/api/camera/assumed", {"hfov_deg": "75"}, 'body.hfov_deg: Input should be a number, not text: write 75, not "75"'),
    # the example was always 500, whatever was sent
    ("/api/calibration/board", {"cols": "9", "rows": 6, "square_m": 0.025},
     'body.cols: Input should be a number, not text: write 9, not "9"'),
    ("/api/calibration/board", {"cols": 9, "rows": 6, "square_m": "2.5e-2"},
     'body.square_m: Input should be a number, not text: write 2.5e-2, not "2.5e-2"'),
    ("/api/camera/assumed", {"hfov_deg": "wide"},
     "body.hfov_deg: Input should be a number, not text: write a number without quotes"),
])
def test_camera_numbers_must_be_json_numbers_not_text(client, path, body, message):
    typed = {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480}
    before = [client.get(p).json() for p in ("/api/camera", "/api/calibration")]
    assert_error(client.put(path, json=(typed if path == "/api/camera" else {}) | body), 422, message)
    assert [client.get(p).json() for p in ("/api/camera", "/api/calibration")] == before
    # Whole numbers may still be written as floats, and a camera file's numbers are read as before.
    r = client.put("/api/camera", json=typed | {"width": 640.0, "dist": [-0.1, 0, 0, 0.0]})
    assert r.status_code == 200 and r.json()["camera"]["width"] == 640
    r = client.put("/api/camera", files={"file": ("cam.yaml", CAMERA_YAML, "application/x-yaml")})
    assert r.status_code == 200 and r.json()["camera"]["kind"] == "file"
    client.delete("/api/camera")


# A 1280x960 sensor's calibration, its left half read out 640x480 from (0, 240) and binned 2x2: its images are
# 320x240 px, the principal point at their right edge.
SENSOR = {"fx": 554.0, "fy": 554.0, "cx": 640.0, "cy": 480.0, "width": 1280, "height": 960}
WINDOW = {"roi": {"x_offset": 0, "y_offset": 240, "width": 640, "height": 480}, "binning_x": 2, "binning_y": 2}
WINDOWED = {"fx": 277.0, "fy": 277.0, "cx": 319.75, "cy": 119.75, "width": 320, "height": 240}


@pytest.mark.parametrize("request_args", [
    {"json": SENSOR | WINDOW},
    {"files": {"file": ("cam.yaml", b"image_width: 1280\nimage_height: 960\ncamera_matrix: {rows: 3, cols: 3, "
                                    b"data: [554, 0, 640, 0, 554, 480, 0, 0, 1]}\nbinning_x: 2\nbinning_y: 2\n"
                                    b"roi: {x_offset: 0, y_offset: 240, width: 640, height: 480, do_rectify: false}\n",
                        "application/x-yaml")}},
], ids=["json", "file"])
def test_a_camera_of_part_of_its_sensor_is_taken_and_kept_as_its_file_gives_it(tmp_path, request_args):
    """PUT /api/camera's JSON dropped roi and binning: the camera became the whole sensor's, and a 320x240
    photo got its K scaled by 0.25. The state keeps the sensor's calibration with the roi (its camera.json
    is read by --camera), and answers give the intrinsics the images are taken with."""
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        r = c.put("/api/camera", **request_args)
        assert r.status_code == 200, r.text
        assert {k: r.json()["camera"][k] for k in WINDOWED} == WINDOWED and r.json()["warnings"] == []
        # GET /api/camera/file gives it as its file does, which PUT takes back as it is
        file = c.get("/api/camera/file").json()
        assert file == SENSOR | WINDOW | {"dist": [0.0] * 5, "source": file["source"]}
        again = c.put("/api/camera", json=file)
        assert again.json()["camera"] == r.json()["camera"] | {"source": "json", "kind": "typed"}
        assert c.get("/api/camera/file").json() == file | {"source": "json"}
    kept = load_camera(tmp_path / "state" / "camera.json")
    assert {k: kept.to_json()[k] for k in WINDOWED} == WINDOWED
    assert kept.file_json()["roi"] == WINDOW["roi"] and kept.file_json()["cx"] == 640


DEEP = 100_000  # levels of nesting, far past Python's stack
LONG = b"1" * 5000  # a whole number of more digits than Python reads (4300)


@pytest.mark.parametrize("path, request_args, words", [
    ("/api/camera", {"files": {"file": ("deep.yaml", b"k: " + b"[" * DEEP + b"]" * DEEP)}},
     ["deep.yaml: line 1, column 23: values nested more than 20 levels deep"]),
    ("/api/camera", {"content": b'{"K": ' + b"[" * DEEP + b"]" * DEEP + b"}"},
     ["the body is JSON nested too deep to read"]),
    ("/api/settings/import", {"files": {"file": ("deep.json", b'{"a": ' * DEEP + b"1" + b"}" * DEEP)}},
     ["deep.json is JSON nested too deep to read"]),
    ("/api/camera", {"files": {"file": ("long.yaml", b"fy: 500\ncx: 320\ncy: 240\nfx: " + LONG)}},
     ["long.yaml: line 4, column 5: a whole number of 5000 characters"]),
    ("/api/camera", {"content": b'{"K": [' + LONG + b", 0, 320, 0, 500, 240, 0, 0, 1]}"},
     ["the body is JSON with a whole number of over 4300 digits"]),
    ("/api/settings/import", {"files": {"file": ("long.json", b'{"threshold": ' + LONG + b"}")}},
     ["long.json is JSON with a whole number of over 4300 digits"]),
], ids=["deep camera file", "deep camera json", "deep settings file", "long camera file", "long camera json",
        "long settings file"])
def test_input_python_cannot_hold_is_a_422_and_changes_nothing(client, path, request_args, words):
    """Each was an HTTP 500: a RecursionError, nested some thousand levels deep, or a ValueError, a whole
    number longer than Python reads."""
    before = client.get("/api/camera").json(), client.get("/api/settings").json()
    if "content" in request_args:
        request_args = {**request_args, "headers": {"content-type": "application/json"}}
    method = client.put if path == "/api/camera" else client.post
    assert_error(method(path, **request_args), 422, *words)
    assert (client.get("/api/camera").json(), client.get("/api/settings").json()) == before


@pytest.mark.parametrize("path, body, key", [
    ("/api/camera", '{"fx": 500, "fy": 500, "cx": 320, "cy": 240, "fx": 600}', "fx"),
    ("/api/camera", '{"K": [[500, 0, 320], [0, 500, 240], [0, 0, 1]], "D": [0, 0, 0, 0], "D": [0.1, 0, 0, 0]}', "D"),
    ("/api/settings", '{"threshold": 0.7, "threshold": 0.8}', "threshold"),
], ids=["camera fx", "camera file's D", "setting"])
def test_a_key_given_twice_is_a_422_naming_it_and_changes_nothing(client, path, body, key):
    """PUT /api/camera took the last fx without a word (pydantic's parser), as the settings took the last threshold."""
    before = client.get("/api/camera").json(), client.get("/api/settings").json()
    r = client.put(path, content=body, headers={"content-type": "application/json"})
    assert_error(r, 422, f"the body is JSON in which the key '{key}' is given twice in one object: keep the one meant")
    assert (client.get("/api/camera").json(), client.get("/api/settings").json()) == before


@pytest.mark.parametrize("size, given", [({"width": 640}, "width"), ({"height": 480}, "height")])
def test_camera_json_with_the_image_width_or_height_alone_is_refused(client, size, given):
    """It was stored with the other null, and so never scaled to an image."""
    before = client.get("/api/camera").json()
    r = client.put("/api/camera", json={"fx": 500, "fy": 500, "cx": 320, "cy": 240} | size)
    assert_error(r, 422, f"the image {given} is given without", "give both", "or neither")
    assert client.get("/api/camera").json() == before


def test_a_camera_that_fits_no_image_held_is_kept_with_a_warning(tmp_path):
    fitting = {"fx": 600, "fy": 600, "cx": 320, "cy": 240, "width": 640, "height": 480}
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        # Before any photo a camera is for the photos to come: nothing to hold it against.
        assert c.put("/api/camera", json=MISFIT_CAMERA).json()["warnings"] == []
        upload(c, ("a.jpg", sign_photo(LIBRARY, "chief_of_security"), None), ("b.jpg", empty_photo(), None))
        r = c.put("/api/camera", json=MISFIT_CAMERA)
        assert r.status_code == 200 and r.json()["camera"]["width"] == 4000
        assert r.json()["warnings"] == [
            "the camera fits none of the 2 images held: this 640x480 px image has another aspect than the 4000x100 "
            "px the camera was calibrated at: a cropped or re-framed photo, whose intrinsics no scaling gives; "
            "calibrate the camera at 640x480"]
        # what the warning foretold, in the camera's words: no pipeline failure to report
        misfit = ("this 640x480 px image has another aspect than the 4000x100 px the camera was calibrated at: a "
                  "cropped or re-framed photo, whose intrinsics no scaling gives; calibrate the camera at 640x480")
        assert [(i["status"], i["error"]) for i in wait_done(c)] == 2 * [("error", misfit)]
        once = c.post("/api/recognize", files={"file": ("a.jpg", empty_photo())})
        assert once.status_code == 422 and once.json()["detail"] == misfit
        assert c.get("/api/camera").json() == r.json()

        assert c.put("/api/camera", json=fitting).json()["warnings"] == []
        upload(c, ("portrait.jpg", cv2.imencode(".jpg", np.full((640, 480), 90, np.uint8))[1].tobytes(), None))
        assert c.get("/api/camera").json()["warnings"] == [
            "the camera does not fit 1 of the 3 images held: this 480x640 px image is the camera's 640x480 px turned "
            "on its side: rotate the photo back, or calibrate the camera held this way"]


def test_the_camera_turns_with_each_photos_exif_orientation(tmp_path):
    """The camera set describes the pixels as the camera stored them, which a photo's EXIF orientation turns: the
    pose of a photo upside down (3) was 8 cm off, and one turned a quarter (6, 8) failed as on its side."""
    photos = turned_photos(1, 3, 6, 8)
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        r = c.put("/api/camera", files={"file": ("lens.yaml", ros_camera_yaml(OFF_CENTRE), "application/x-yaml")})
        assert r.status_code == 200, r.text
        ids = [i["id"] for i in upload(c, *[(f"turned_{o}.jpg", p, None) for o, p in photos.items()]).json()["images"]]
        wait_done(c)
        assert c.get("/api/camera").json()["warnings"] == []  # every photo fits, as turned
        for orientation, image_id in zip(photos, ids):
            detail = c.get(f"/api/images/{image_id}").json()
            position = detail["result"]["pose"]["camera_position"]
            assert np.linalg.norm(position - turned_scene_position()) < TURNED_WITHIN_M, (orientation, position)
            assert (detail["camera"]["width"], "turned" in detail["camera"]["source"]) == \
                ((480, True) if orientation in (6, 8) else (640, orientation != 1))
        once = c.post("/api/recognize", files={"file": ("turned_8.jpg", photos[8], "image/jpeg")}).json()
        assert np.linalg.norm(once["pose"]["camera_position"] - turned_scene_position()) < TURNED_WITHIN_M


def test_assumed_field_of_view_for_photos_without_camera_or_exif(client):
    plain, phone = (i["id"] for i in upload(client, ("plain.jpg", sign_photo(LIBRARY, "security_compound"), None), (
        "phone.jpg", with_focal_exif(sign_photo(LIBRARY, "chief_of_security"), 26), None)).json()["images"])
    wait_done(client)
    r = client.put("/api/camera/assumed", json={"hfov_deg": 75})
    assert r.status_code == 200 and r.json() == NO_CAMERA | {"assumed_hfov_deg": 75.0, "exif_images": 1}
    wait_done(client)
    camera = client.get(f"/api/images/{plain}").json()["camera"]
    assert camera["kind"] == "assumed" and "75°" in camera["source"]
    assert camera["fx"] == pytest.approx(320 / math.tan(math.radians(75 / 2)))
    warnings = client.get(f"/api/images/{plain}").json()["result"]["warnings"]
    assert any("75°" in w and "approximate" in w for w in warnings), warnings
    assert client.get(f"/api/images/{phone}").json()["camera"]["kind"] == "exif"  # EXIF comes first
    for bad, said in ((5, "5"), (170, "170"), (float("nan"), "nan"), (-0.0, "-0")):  # -0 was "got -0.0"
        r = client.put("/api/camera/assumed", content=json.dumps({"hfov_deg": bad}),
                       headers={"content-type": "application/json"})
        assert_error(r, 422, "10° to 140°")
        assert r.json()["detail"].endswith(f"; got {said}")
    for bad in ("wide", None):
        assert_error(client.put("/api/camera/assumed", json={"hfov_deg": bad}), 422, "hfov_deg")
    assert client.get("/api/camera").json()["assumed_hfov_deg"] == 75.0
    client.put("/api/camera/assumed", json={"hfov_deg": 60})
    for image_id in (plain, phone):
        client.delete(f"/api/images/{image_id}")


def test_an_implausible_exif_focal_length_is_said_where_the_field_of_view_is_assumed(client):
    photo = sign_photo(LIBRARY, "security_compound")
    ids = [i["id"] for i in upload(client, *[(f"f{mm}.jpg", with_focal_exif(photo, mm), None)
                                             for mm in (0, 65535)]).json()["images"]]
    wait_done(client)
    assert client.get("/api/camera").json()["exif_images"] == 0
    for mm, image_id in zip((0, 65535), ids):
        detail = client.get(f"/api/images/{image_id}").json()
        note = f"the photo's EXIF 35 mm-equivalent focal length of {mm} mm is implausible and was ignored"
        assert detail["camera"]["kind"] == "assumed" and detail["camera"]["source"] == (
            f"assumed 60° horizontal field of view ({note})")
        assert any(note in w and "approximate" in w for w in detail["result"]["warnings"])
    r = client.post("/api/recognize", files={"file": ("f0.jpg", with_focal_exif(photo, 0), "image/jpeg")})
    assert any("focal length of 0 mm is implausible" in w for w in r.json()["warnings"])
    for image_id in ids:
        client.delete(f"/api/images/{image_id}")


# ---------------------------------------------------------------- viser

def test_viser_client_is_served_and_its_websocket_relayed(client, base_url):
    page = client.get("/viser/")
    assert page.status_code == 200 and "<title>Viser</title>" in page.text
    assert client.get("/viser", follow_redirects=False).headers["location"] == "/viser/"
    ws_url = base_url.replace("http://", "ws://")
    for path in ("/viser", "/viser/"):  # what the client derives from its page URL, and the page URL itself
        with connect(ws_url + path, subprotocols=[VISER_PROTOCOL], max_size=None, open_timeout=10) as ws:
            assert ws.subprotocol == VISER_PROTOCOL
            assert isinstance(ws.recv(timeout=10), bytes)  # viser's first (msgpack) message batch
    with connect(ws_url + "/viser/", subprotocols=["viser-v0.0.0"], open_timeout=10) as ws:
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
    assert closed.value.rcvd.code == 1002 and "Version mismatch" in closed.value.rcvd.reason


def test_the_3d_views_page_tells_the_server_its_canvas_scale(client):
    """viser's client reports its canvas in device px and draws the camera labels at a size in CSS
    px: its page gets our script, which says how many device px its canvas has to the CSS px, naming
    its viewer (the viser client) as the server named it."""
    page = client.get("/viser/").text
    assert "<title>Viser</title>" in page and page.count(CANVAS_SCRIPT) == 1
    assert "setInterval" in client.get("/viser-canvas.js").text
    canvas = {"width": 892, "height": 1800, "px_per_css_px": 2.0}
    assert client.put("/api/scene/canvas?viewer=0", json=canvas).status_code == 204
    for bad in ({"width": 0}, {"height": 1e6}, {"px_per_css_px": 0}, {"px_per_css_px": "2"}):
        r = client.put("/api/scene/canvas?viewer=0", json=canvas | bad)
        assert r.status_code == 422, (bad, r.text)
    for viewer in ("", "?viewer=-1", "?viewer=a"):
        assert client.put(f"/api/scene/canvas{viewer}", json=canvas).status_code == 422, viewer
    assert client.put("/api/scene/canvas?viewer=0", content=json.dumps(canvas)).status_code == 415


def test_remove_every_image_at_once(tmp_path):
    """The page's "remove all" sent a DELETE per image, one after another: 77 took 17 s."""
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        upload(c, *[(f"{i}.jpg", sign_photo(LIBRARY, "chief_of_security", seed=i), None) for i in range(3)])
        images = tmp_path / "state" / "images"
        assert len([f for f in images.iterdir() if f.suffix == ".jpg"]) == 3
        r = c.delete("/api/images")
        assert r.status_code == 200 and r.json() == {"removed": 3}
        assert c.get("/api/images").json()["images"] == [] and c.get("/api/health").json()["images"] == 0
        assert [f for f in images.iterdir() if f.suffix == ".jpg"] == []
        assert c.delete("/api/images").json() == {"removed": 0}
        kept = upload(c, ("kept.jpg", tiny_photo(), None)).json()["images"][0]["id"]   # the workspace goes on
        wait_done(c)
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        assert [i["id"] for i in c.get("/api/images").json()["images"]] == [kept]


# ---------------------------------------------------------------- restart and CLI

def test_state_survives_a_restart(tmp_path):
    photo = sign_photo(LIBRARY, "chief_of_security")
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        image_id = upload(c, ("chief.jpg", photo, "chief_of_security")).json()["images"][0]["id"]
        c.put("/api/settings", json={"threshold": 0.65})
        c.put("/api/camera", json={"fx": 550, "fy": 550, "cx": 320, "cy": 240})
    with running(create_app(config(tmp_path / "state"))) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        assert c.get("/api/settings").json()["settings"]["threshold"] == 0.65
        assert c.get("/api/camera").json()["camera"]["fx"] == 550
        (image,) = wait_done(c)
        assert (image["id"], image["name"], image["status"]) == (image_id, "chief.jpg", "correct")
        assert c.get(f"/api/images/{image_id}/file").content == photo


def test_serve_keeps_an_idle_connection_longer_than_clients_reuse_one(tmp_path):
    """httpx reuses an idle connection for 5 s, and uvicorn closed it after 5 s: a request sent as the
    server closed it was reset (a browser test's teardown did, once in a CI run). Idle for 6 s, the
    connection still answers."""
    proc, url = start_serve(tmp_path / "state")
    try:
        host, port = url.removeprefix("http://").rstrip("/").split(":")
        request = f"GET /api/health HTTP/1.1\r\nHost: {host}\r\n\r\n".encode()
        with socket.create_connection((host, int(port)), timeout=TIMEOUT_S) as sock:
            for pause in (0, 6):
                time.sleep(pause)
                sock.sendall(request)
                response = b""
                while b'"status":"ok"' not in response and (data := sock.recv(65536)):
                    response += data
                assert response.startswith(b"HTTP/1.1 200") and b'"status":"ok"' in response, pause
    finally:
        stop_serve(proc)


def test_serve_command_prints_its_url_stops_on_ctrl_c_and_refuses_a_taken_port(tmp_path):
    proc, url = start_serve(tmp_path / "state")
    try:
        assert url.startswith("http://127.0.0.1:") and "token" not in url
        url = url.rstrip("/")
        assert httpx.get(url + "/api/health", timeout=TIMEOUT_S).json()["status"] == "ok"
        taken = [sys.executable, "-m", "signpose.app.cli", "serve", "--port", url.rsplit(":", 1)[1],
                 "--state-dir", str(tmp_path / "other")]
        refused = subprocess.run(taken, cwd=REPO, capture_output=True, text=True, timeout=TIMEOUT_S)
        assert refused.returncode == 2 and "cannot listen" in refused.stderr and "--port" in refused.stderr
    finally:
        _, stderr = stop_serve(proc)
    assert proc.returncode == 0 and "Traceback" not in stderr


def serve_with(state_dir: Path, what: str, file: Path, put: dict | None = None) -> tuple[dict, str]:
    """Start `signpose serve --<what> file` (`what`: camera or settings), PUT `put` to /api/<what> if
    given, stop it; the <what> it started with and its stderr."""
    proc, url = start_serve(state_dir, f"--{what}", str(file))
    try:
        started = httpx.get(url + f"api/{what}", timeout=TIMEOUT_S).json()[what]
        if put is not None:
            httpx.put(url + f"api/{what}", json=put, timeout=TIMEOUT_S).raise_for_status()
    finally:
        _, stderr = stop_serve(proc)
    return started, stderr


@pytest.mark.parametrize("what, file_name, data, put, kept_as", [
    ("camera", "camera.yaml", CAMERA_YAML, {"fx": 900, "fy": 900, "cx": 640, "cy": 480, "width": 1280, "height": 960},
     "camera, which is kept in {kept}: to use that one"),  # e.g. a calibration applied in the page
    ("settings", "settings.json", b'{"ratio": 0.7}', {"threshold": 0.6, "min_inliers": 12},
     "settings, which are kept in {kept}: to use them"),  # e.g. sliders moved or a preset chosen in the page
])
def test_serve_camera_or_settings_keeps_what_the_state_held_that_differs_and_says_where(tmp_path, what, file_name,
                                                                                        data, put, kept_as):
    """`serve --camera FILE` and `serve --settings FILE` replace a camera or settings set in the page since the
    last start, and keep the one replaced where the log says, never overwriting it silently."""
    state, file = tmp_path / "state", tmp_path / file_name
    file.write_bytes(data)
    first, stderr = serve_with(state, what, file, put=put)
    assert "replaced" not in stderr  # a fresh state held none
    again, stderr = serve_with(state, what, file)
    assert again == first  # the file still wins...
    (kept,) = state.glob(f"{what}.replaced-*.json")  # ...but what was set in the page is kept
    assert put.items() <= json.loads(kept.read_text()).items()
    (line,) = [line for line in stderr.splitlines() if "replaced" in line]
    assert line == (f"--{what} {file} replaced the state's {kept_as.format(kept=kept)} again, start with "
                    f"--{what} {kept}")
    # The same values again, though the state's file is not written as `file` is: nothing to keep or say.
    _, stderr = serve_with(state, what, file)
    assert "replaced" not in stderr and list(state.glob(f"{what}.replaced-*.json")) == [kept]
    restored, _ = serve_with(state, what, kept)  # as the line says
    assert put.items() <= restored.items() and len(list(state.glob(f"{what}.replaced-*"))) == 2


def distance_m(url: str) -> float:
    """How far the camera of `sign_photo` of security_compound is from the sign, by POST /api/recognize."""
    photo = sign_photo(LIBRARY, "security_compound")
    result = httpx.post(url + "api/recognize", files={"file": ("s.jpg", photo, "image/jpeg")}, timeout=TIMEOUT_S)
    assert result.json()["label"] == "security_compound", result.text
    return float(np.linalg.norm(result.json()["pose"]["t"]))


def test_serve_reads_its_library_folder_again_when_it_was_edited(tmp_path):
    """`serve --library DIR` kept its first copy of DIR: a sign's width corrected in DIR/library.json was
    ignored at every later start with the same DIR, every pose off by the ratio."""
    state = tmp_path / "state"
    proc, url = start_serve(state)
    try:
        before = distance_m(url)
    finally:
        stop_serve(proc)
    folder = tmp_path / "library"  # the copy `start_serve` gives as --library
    meta = json.loads((folder / "library.json").read_text(encoding="utf-8"))
    meta["signs"][0] |= {"width_m": 0.3, "height_m": 0.12}  # re-measured: half the size
    (folder / "library.json").write_text(json.dumps(meta, ensure_ascii=False), encoding="utf-8")
    proc, url = start_serve(state)
    try:
        assert httpx.get(url + "api/library", timeout=TIMEOUT_S).json()[0]["width_m"] == 0.3
        assert distance_m(url) == pytest.approx(before / 2, rel=1e-3)
    finally:
        _, stderr = stop_serve(proc)
    (kept,) = state.glob("library.replaced-*")
    (line,) = [line for line in stderr.splitlines() if "--library" in line]
    assert line == (f"--library {folder} was read again (it changed since the state copied it); changed: "
                    "security_compound (width_m from 0.6 to 0.3 m, height_m from 0.24 to 0.12 m); the state's library "
                    f"as it was is kept in {kept} (to use it again, start with --library {kept})")


@pytest.mark.parametrize("what, file_name, data", [("camera", "camera.yaml", CAMERA_YAML),
                                                   ("settings", "settings.json", b'{"ratio": 0.7}')],
                         ids=("camera", "settings"))
def test_serve_camera_or_settings_replaces_a_damaged_state_file_and_keeps_it(tmp_path, what, file_name, data):
    """A damaged camera.json or settings.json in the state does not stop `serve` when --camera or --settings
    gives the one to use instead: it is moved aside, kept to mend by hand."""
    state, file = tmp_path / "state", tmp_path / file_name
    file.write_bytes(data)
    state.mkdir()
    damaged = b'{"fx": 900, "fy": '  # e.g. cut short by a full disk
    (state / f"{what}.json").write_bytes(damaged)
    expected, _ = serve_with(tmp_path / "fresh", what, file)
    started, stderr = serve_with(state, what, file)
    assert started == expected
    (kept,) = state.glob(f"{what}.replaced-*.json")
    assert kept.read_bytes() == damaged  # as it was, to mend by hand
    (line,) = [line for line in stderr.splitlines() if "replaced" in line]
    assert line == (f"--{what} {file} replaced the state's {what}, which could not be read; it is kept as it "
                         f"was in {kept}")
