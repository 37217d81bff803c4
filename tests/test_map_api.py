"""The sign map through the HTTP API (`/api/map`), against a real uvicorn server serving the sample
survey (its library and camera): a map file loaded, a bad one refused naming the field with the map
held kept, a map built from the survey's photos and downloaded, loading back as it was; a survey whose
signs form two groups no photo links refused, naming both, and one without photos refused saying so."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import httpx
import numpy as np
import pytest

from signpose.app.workspace import WorkspaceConfig
from signpose.pipeline.sign_map import load_sign_map, read_sign_map
from tests.support.serving import TIMEOUT_S, assert_error, running_workspace, upload, wait_idle

pytestmark = pytest.mark.server

ROOM = Path(__file__).resolve().parents[1] / "sample_images" / "surveys" / "room"
TRUTH = load_sign_map(ROOM / "truth_map.yaml")
# Photos that link every sign of the room to the next: two of each neighbouring pair.
LINKED = [2, 9, 3, 11, 5, 12, 6, 14, 8, 15]
# Photos of {security_compound, ministry_of_torture} and of {directors_office, emergency_exit} only.
TWO_GROUPS = [2, 9, 17, 8, 15, 23]


def survey_config(state_dir: Path) -> WorkspaceConfig:
    return WorkspaceConfig(state_dir=state_dir, library_dir=ROOM / "library", camera_file=ROOM / "camera.yaml",
                           load_samples=False, workers=2)


def photos(numbers: list[int]) -> list[tuple[str, bytes, None]]:
    return [(f"photo_{n:03d}.jpg", (ROOM / f"photo_{n:03d}.jpg").read_bytes(), None) for n in numbers]


def serve_photos(tmp_path_factory, numbers: list[int]):
    """A server on the survey's library and camera holding `numbers`' photos, processed."""
    with running_workspace(survey_config(tmp_path_factory.mktemp("map") / "state")) as url:
        with httpx.Client(base_url=url, timeout=TIMEOUT_S) as client:
            assert upload(client, *photos(numbers)).status_code == 201
            wait_idle(client)
        yield url


@pytest.fixture(scope="module")
def base_url(tmp_path_factory):
    yield from serve_photos(tmp_path_factory, LINKED)


@pytest.fixture
def client(base_url):
    with httpx.Client(base_url=base_url, timeout=120) as c:
        yield c


def put_map(client, name: str, text: str) -> httpx.Response:
    return client.put("/api/map", files={"file": (name, text.encode(), "application/x-yaml")})


def test_a_map_file_loads_and_a_bad_one_is_refused_naming_the_field_keeping_the_map(client):
    r = put_map(client, "truth_map.yaml", (ROOM / "truth_map.yaml").read_text())
    assert r.status_code == 200, r.text
    held = r.json()
    assert held["source"] == "truth_map.yaml" and held["frame"] == "map"
    assert [s["id"] for s in held["signs"]] == list(TRUTH.signs)
    archives = next(s for s in held["signs"] if s["id"] == "archives")
    np.testing.assert_allclose(archives["position_m"], TRUTH.signs["archives"].position_m)
    assert archives["yaw_pitch_roll_deg"][1] == pytest.approx(90.0)
    assert archives["sigma_position_m"] is None and archives["covariance"] is None   # the file gives none
    assert client.get("/api/map").json() == held

    # JSON is read too.
    r = put_map(client, "truth.json", json.dumps(TRUTH.to_json()))
    assert r.status_code == 200 and r.json()["revision"] == held["revision"] + 1
    kept = r.json()

    bad = {"signs[0].id": "signs:\n  - id: no_such_sign\n    position_m: [0, 0, 0]\n    orientation_wxyz: [1, 0, 0, 0]\n",
           "signs[0].orientation_wxyz": "signs:\n  - id: archives\n    position_m: [0, 0, 0]\n"
                                        "    orientation_wxyz: [1, 1, 0, 0]\n",
           "neither valid YAML nor JSON": "signs: [\n"}
    for field, text in bad.items():
        assert_error(put_map(client, "bad.yaml", text), 422, "bad.yaml", field)
    assert client.get("/api/map").json() == kept

    # A sign the map places is not deleted from under it: the map would name a sign the library lacks, and be
    # dropped at the next start.
    assert_error(client.delete("/api/library/archives"), 409, "'archives' is in the sign map held", "clear the map")
    assert "archives" in [s["id"] for s in client.get("/api/library").json()]


def test_results_locate_the_camera_in_the_map_held_from_every_sign_in_view(client):
    """`recognize --map` gave the camera in the map frame; the server, with the map held, did not."""
    assert put_map(client, "truth_map.yaml", (ROOM / "truth_map.yaml").read_text()).status_code == 200
    truth = json.loads((ROOM / "truth.json").read_text())["photos"][2]   # photo_002: two signs in view
    r = client.post("/api/recognize", files={"file": photos([2])[0][:2]})
    assert r.status_code == 200, r.text
    answer = r.json()
    assert {s["label"] for s in answer["signs"]} == set(truth["signs"]) and answer["signs"][0]["label"] == answer["label"]
    located = answer["camera_in_map"]
    assert sorted(located["signs_used"]) == sorted(truth["signs"])
    assert np.linalg.norm(np.subtract(located["position_m"], truth["camera_position"])) < 0.05
    assert client.delete("/api/map").status_code == 204
    assert client.post("/api/recognize", files={"file": photos([2])[0][:2]}).json()["camera_in_map"] is None


def test_a_map_built_from_the_photos_is_downloaded_and_loads_back(client):
    r = client.post("/api/map/build", json={"anchor": "security_compound"})
    assert r.status_code == 200, r.text
    built = r.json()
    assert built["source"] == f"built from {len(LINKED)} photo(s) and 0 flight(s)" and not built["warnings"]
    signs = {s["id"]: s for s in built["signs"]}
    assert set(signs) == set(TRUTH.signs)
    anchor = signs["security_compound"]
    assert anchor["fixed"] == "anchor" and np.allclose(anchor["position_m"], 0, atol=1e-6)
    for sign_id, sign in signs.items():
        error = np.linalg.norm(np.subtract(sign["position_m"], TRUTH.signs[sign_id].position_m))
        assert error < 0.15, (sign_id, error)
        if sign_id != "security_compound":
            assert 0 < sign["sigma_position_m"] < 0.3 and sign["images"] >= 2 and sign["seen_with"], sign
    assert signs["ministry_of_torture"]["seen_with"]["security_compound"] >= 1

    r = client.get("/api/map/file")
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/x-yaml")
    assert 'filename="map.yaml"' in r.headers["content-disposition"]
    assert "# 1-sigma" in r.text   # the build's report, as `signpose map build` writes it
    again = read_sign_map(r.content, "map.yaml")
    for sign_id, sign in again.signs.items():
        np.testing.assert_allclose(sign.position_m, signs[sign_id]["position_m"], atol=1e-12)
        np.testing.assert_allclose(sign.covariance, signs[sign_id]["covariance"], atol=1e-15)
    r = put_map(client, "map.yaml", r.text)
    assert r.status_code == 200
    assert [s["position_m"] for s in r.json()["signs"]] == [s["position_m"] for s in built["signs"]]

    assert_error(client.post("/api/map/build", json={"anchor": "nope"}), 422, "anchor 'nope'", "archives")
    assert client.delete("/api/map").status_code == 204
    assert client.get("/api/map").json() is None
    assert_error(client.get("/api/map/file"), 404, "no sign map is held")


def test_a_survey_in_two_unlinked_groups_is_refused_naming_both_and_one_without_signs_saying_so(tmp_path_factory):
    for url in serve_photos(tmp_path_factory, TWO_GROUPS):
        with httpx.Client(base_url=url, timeout=120) as client:
            assert_error(client.post("/api/map/build"), 409, "2 groups",
                         "{ministry_of_torture, security_compound}", "{directors_office, emergency_exit}")
            assert client.get("/api/map").json() is None
            assert client.delete("/api/images").status_code == 200
            assert_error(client.post("/api/map/build"), 409, "no sign with a pose in the photos and flights held")


def test_the_map_held_is_kept_in_the_state_across_a_restart_and_map_overrides_it(tmp_path):
    """A map loaded in the server is held again after a restart on the same state; `serve --map` holds its
    own instead, the one the state kept moved aside (nothing lost); a map cleared leaves none; a kept map
    that no longer fits the library is moved aside and the server starts without one."""
    state = tmp_path / "state"
    one_sign = tmp_path / "one_sign.yaml"
    one_sign.write_text("signs:\n  - id: archives\n    position_m: [1, 2, 3]\n    orientation_wxyz: [1, 0, 0, 0]\n")

    def served(map_file: Path | None = None):
        return running_workspace(dataclasses.replace(survey_config(state), map_file=map_file))

    with served() as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as client:
        assert put_map(client, "truth_map.yaml", (ROOM / "truth_map.yaml").read_text()).status_code == 200
        held = client.get("/api/map").json()
    with served() as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as client:
        again = client.get("/api/map").json()
        assert again is not None and "kept" in again["source"]
        assert [s["id"] for s in again["signs"]] == [s["id"] for s in held["signs"]]
        np.testing.assert_allclose([s["position_m"] for s in again["signs"]], [s["position_m"] for s in held["signs"]])
    with served(one_sign) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as client:
        assert [s["id"] for s in client.get("/api/map").json()["signs"]] == ["archives"]
        [aside] = state.glob("map.replaced-*.yaml")
        assert list(load_sign_map(aside).signs) == list(TRUTH.signs)
        assert client.delete("/api/map").status_code == 204
        assert not (state / "map.yaml").exists()
    # A kept map that no longer fits the library: the server starts without it, and it is moved aside.
    (state / "map.yaml").write_text(one_sign.read_text().replace("archives", "gone_since"))
    with served() as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as client:
        assert client.get("/api/map").json() is None
        assert len(list(state.glob("map.replaced-*.yaml"))) == 2 and not (state / "map.yaml").exists()
