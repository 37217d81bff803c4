"""Limits of `signpose serve`: the request time limit on pipeline work, the CLI's limit options,
and the bounded settings history that results are checked against.

(The upload, pixel and image-count limits are tested in test_api.py and test_hostile_input.py,
the slider storm's single pending re-run in test_workspace.py.)
"""

from __future__ import annotations

import threading
import time

import httpx
import pytest

import signpose.app.settings_history as settings_history
import signpose.pipeline.recognize as recognize_module
from signpose.app.cli import main
from signpose.app.server import create_app
from signpose.app.workspace import WorkspaceConfig
from signpose.pipeline.library import SAMPLE_LIBRARY, load_library
from tests.support.scene_images import sign_photo
from tests.support.serving import TIMEOUT_S, assert_error, running, upload, wait_done

# Time and size limits of a real uvicorn server.
pytestmark = pytest.mark.server

LIBRARY = load_library(SAMPLE_LIBRARY)
LIMIT_S = 0.5


def test_a_stuck_pipeline_call_answers_503_and_the_server_goes_on(tmp_path, monkeypatch):
    config = WorkspaceConfig(state_dir=tmp_path / "state", load_samples=False, workers=1, request_timeout_s=LIMIT_S)
    with running(create_app(config)) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        photo = sign_photo(LIBRARY, "security_compound")
        upload(c, ("compound.jpg", photo, "security_compound"))
        wait_done(c)
        release, calls = threading.Event(), []

        def stuck(*args, **kwargs):  # returns, so only the stop request can end the sweep early
            calls.append(args)
            release.wait(TIMEOUT_S)

        monkeypatch.setattr(recognize_module, "recognize", stuck)
        started = time.monotonic()
        r = c.post("/api/recognize", files={"file": ("stuck.jpg", photo, "image/jpeg")})
        assert_error(r, 503, "stuck.jpg", f"{LIMIT_S:g} s limit", "--request-timeout")
        assert_error(c.get("/api/sweep", params={"steps": 13}), 503, "sweep", "--request-timeout")
        assert time.monotonic() - started < 10 * LIMIT_S
        assert c.get("/api/health").json()["status"] == "ok"  # answered while both calls hang
        release.set()
        time.sleep(5 * LIMIT_S)
        # The abandoned sweep stopped after the run in progress instead of doing all 13.
        assert len(calls) == 2


@pytest.mark.parametrize("option, value, problem", [
    ("--max-upload-mb", "0", "is not above 0"), ("--max-megapixels", "-1", "is not above 0"),
    ("--max-images", "0", "is not a whole number of at least 1"), ("--max-memory-gb", "0", "is not above 0"),
    ("--request-timeout", "nan", "is not a finite number"), ("--request-timeout", "inf", "is not a finite number"),
])
def test_serve_refuses_limits_that_are_not_positive(tmp_path, capsys, option, value, problem):
    # argparse rejects the value while parsing: it exits with code 2 instead of returning it.
    with pytest.raises(SystemExit) as exited:
        main(["serve", "--port", "0", "--state-dir", str(tmp_path / "state"), option, value])
    assert exited.value.code == 2
    assert f"{option}: {value!r} {problem}" in capsys.readouterr().err
    assert not (tmp_path / "state").exists()


def test_results_can_be_checked_against_the_settings_of_their_version(tmp_path, monkeypatch):
    monkeypatch.setattr(settings_history, "SETTINGS_HISTORY", 3)
    config = WorkspaceConfig(state_dir=tmp_path / "state", load_samples=False, workers=1)
    with running(create_app(config)) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        image_id = upload(c, ("compound.jpg", sign_photo(LIBRARY, "security_compound"), None)) \
            .json()["images"][0]["id"]
        sent = {}
        for ratio in (0.7, 0.71, 0.72, 0.73):
            body = c.put("/api/settings", json={"ratio": ratio}).json()
            sent[body["version"]] = body["settings"]
        wait_done(c)
        detail = c.get(f"/api/images/{image_id}").json()
        assert detail["settings_version"] == max(sent) and detail["settings"] == sent[max(sent)]
        for version in sorted(sent)[-3:]:
            assert c.get("/api/settings", params={"version": version}).json() == \
                {"version": version, "settings": sent[version]}
        kept = f"versions {max(sent) - 2} to {max(sent)} are"
        assert_error(c.get("/api/settings", params={"version": min(sent)}), 404, "not kept", kept)
        assert_error(c.get("/api/settings", params={"version": 99}), 404, kept)
        assert c.get("/api/settings", params={"version": 0}).status_code == 422
