"""Property-based fuzzing of the HTTP API: schemathesis generates requests from the app's own
OpenAPI schema (valid and not), sends them to a real server, and no answer may be a 5xx."""

from __future__ import annotations

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error

from app.server import create_app
from app.workspace import WorkspaceConfig
from pipeline.library import SAMPLE_LIBRARY, load_library
from scene_images import sign_photo
from serving import TIMEOUT_S, running, upload, wait_done


@pytest.fixture(scope="module")
def base_url(tmp_path_factory):
    config = WorkspaceConfig(state_dir=tmp_path_factory.mktemp("fuzz") / "state", load_samples=False, workers=2,
                             max_upload_bytes=2_000_000)
    with running(create_app(config)) as url:
        with httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:  # something for sweeps and figures to use
            upload(c, ("compound.jpg", sign_photo(load_library(SAMPLE_LIBRARY), "security_compound"),
                       "security_compound"))
            wait_done(c)
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
