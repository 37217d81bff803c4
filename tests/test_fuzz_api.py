"""Fuzzing of the HTTP API against a real server, where no answer may be a 5xx: schemathesis
generates requests from the app's own OpenAPI schema (valid and not), and every JSON body is
sent the non-finite numbers that schemathesis never writes."""

from __future__ import annotations

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error

from signpose.app.server import create_app
from signpose.app.workspace import WorkspaceConfig
from signpose.pipeline.library import SAMPLE_LIBRARY, load_library
from tests.support.scene_images import sign_photo
from tests.support.serving import TIMEOUT_S, running, upload, wait_done

# Fuzzing the API of a real uvicorn server.
pytestmark = pytest.mark.server


def an_image(c: httpx.Client) -> str:
    """The id of an image held, uploaded (and processed) when there is none: something for sweeps
    and figures to use, which the fuzzing may have removed (DELETE /api/images)."""
    held = c.get("/api/images").json()["images"]
    if held:
        return held[0]["id"]
    r = upload(c, ("compound.jpg", sign_photo(load_library(SAMPLE_LIBRARY), "security_compound"), "security_compound"))
    wait_done(c)
    return r.json()["images"][0]["id"]


@pytest.fixture(scope="module")
def base_url(tmp_path_factory):
    config = WorkspaceConfig(state_dir=tmp_path_factory.mktemp("fuzz") / "state", load_samples=False, workers=2,
                             max_upload_bytes=2_000_000)
    with running(create_app(config)) as url:
        with httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
            an_image(c)
        yield url


@pytest.fixture
def api_schema(base_url):
    return schemathesis.openapi.from_url(f"{base_url}/openapi.json")


# The event stream never ends, so a request to it is never answered.
schema = schemathesis.pytest.from_fixture("api_schema").exclude(path="/api/events")


@schema.parametrize()
@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
def test_no_request_gets_a_server_error(case):
    case.call_and_validate(checks=[not_a_server_error])


def non_finite_bodies(api: dict, number: str):
    """(method, path, raw body) for every JSON operation in the OpenAPI document `api`: `number`
    as the whole body, in a list, and as (or in a list in) each top-level field."""
    for path, operations in api["paths"].items():
        for method, operation in operations.items():
            content = operation.get("requestBody", {}).get("content", {})
            if "application/json" not in content:
                continue
            schema = content["application/json"]["schema"]
            if "$ref" in schema:
                schema = api["components"]["schemas"][schema["$ref"].rsplit("/", 1)[1]]
            bodies = [number, f"[{number}]"]
            for field in schema.get("properties", {}):
                bodies += [f'{{"{field}": {number}}}', f'{{"{field}": [{number}]}}']
            yield from ((method.upper(), path, body) for body in bodies)


# Python's json, and so FastAPI, reads NaN, Infinity and 1e999 (inf) though JSON has no such numbers.
@pytest.mark.parametrize("number", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_non_finite_numbers_in_json_bodies_get_a_4xx(base_url, number):
    with httpx.Client(base_url=base_url, timeout=TIMEOUT_S) as c:
        image_id = an_image(c)
        for method, path, body in non_finite_bodies(c.get("/openapi.json").json(), number):
            # No flight is held: a flight's routes answer 404 or 422, both what is asked of them.
            r = c.request(method, path.format(image_id=image_id, flight_id="0123456789ab"), content=body,
                          headers={"content-type": "application/json"})
            assert 400 <= r.status_code < 500 and isinstance(r.json()["detail"], str), (method, path, body, r.text)
