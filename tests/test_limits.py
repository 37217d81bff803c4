"""Limits of `signpose serve`: the request time limit on pipeline work, the queue heavy requests
wait in, the CLI's limit options, and the bounded settings history that results are checked against.

(The upload, pixel and image-count limits are tested in test_api.py and test_hostile_input.py,
the slider storm's single pending re-run in test_workspace.py.)
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest

import signpose.app.settings_history as settings_history
import signpose.pipeline.every_sign as every_sign_module
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

        # where each call looks it up: a sweep runs `recognize`, POST /api/recognize `recognize_every_sign`
        monkeypatch.setattr(recognize_module, "recognize", stuck)
        monkeypatch.setattr(every_sign_module, "recognize", stuck)
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


def test_a_full_heavy_queue_answers_busy_at_once(tmp_path, monkeypatch):
    """Heavy requests beyond the running and the waiting ones are answered 503 at once, with
    Retry-After, while the others wait their turn and are answered in full."""
    config = WorkspaceConfig(state_dir=tmp_path / "state", load_samples=False, workers=1)
    app = create_app(config)
    queue = app.state.work_queue
    release, recognize = threading.Event(), recognize_module.recognize
    monkeypatch.setattr(recognize_module, "recognize",
                        lambda *a, **k: release.wait(TIMEOUT_S) and recognize(*a, **k))
    photo = sign_photo(LIBRARY, "security_compound")
    answers: list[httpx.Response] = []

    def post(c: httpx.Client) -> None:
        answers.append(c.post("/api/recognize", files={"file": ("held.jpg", photo, "image/jpeg")}))

    with running(app) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        held = [threading.Thread(target=post, args=(c,)) for _ in range(queue.workers + queue.max_waiting)]
        try:
            for thread in held:
                thread.start()
            deadline = time.monotonic() + TIMEOUT_S
            while queue.queued < len(held):
                assert time.monotonic() < deadline, f"{queue.queued} of {len(held)} queued"
                time.sleep(0.02)
            started = time.monotonic()
            r = c.post("/api/recognize", files={"file": ("more.jpg", photo, "image/jpeg")})
            assert_error(r, 503, f"busy: {len(held)} requests queued; try again in a moment")
            assert int(r.headers["Retry-After"]) > 0 and time.monotonic() - started < 1
            assert c.get("/api/health").json()["status"] == "ok"
        finally:
            release.set()
            for thread in held:
                thread.join(TIMEOUT_S)
        assert [a.status_code for a in answers] == [200] * len(held)
        assert c.post("/api/recognize", files={"file": ("after.jpg", photo, "image/jpeg")}).status_code == 200


def test_health_answers_within_a_second_through_a_storm_of_sweeps(tmp_path):
    """45 sweeps at once held all 40 of the threads the plain routes share for two minutes, and
    /api/health with them. They wait in a queue of their own now, and what it cannot hold is
    answered 503 busy: nothing else is a 5xx."""
    config = WorkspaceConfig(state_dir=tmp_path / "state", load_samples=False, workers=2)
    storm, polls = 45, []
    with running(create_app(config)) as url, httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        upload(c, *[(f"{sid}.jpg", sign_photo(LIBRARY, sid, seed=i), sid)
                    for i, sid in enumerate(("security_compound", "chief_of_security"))])
        wait_done(c)
        done = threading.Event()

        def sweep(_: int) -> httpx.Response:
            with httpx.Client(base_url=url, timeout=2 * TIMEOUT_S) as own:
                return own.get("/api/sweep", params={"param": "threshold", "lo": 0.5, "hi": 0.9, "steps": 5})

        def poll() -> None:
            while not done.is_set():
                started = time.monotonic()
                assert c.get("/api/health").status_code == 200
                polls.append(time.monotonic() - started)
                time.sleep(0.05)

        poller = threading.Thread(target=poll)
        poller.start()
        try:
            with ThreadPoolExecutor(storm) as pool:
                answers = list(pool.map(sweep, range(storm)))
        finally:
            done.set()
            poller.join(TIMEOUT_S)
    codes = Counter(a.status_code for a in answers)
    assert set(codes) == {200, 503} and codes[200] >= 2, codes
    for a in answers:
        if a.status_code == 503:
            assert a.json()["detail"].startswith("busy: ") and "Retry-After" in a.headers, a.text
    assert len(polls) >= 5 and sorted(polls)[int(0.99 * (len(polls) - 1))] < 1.0, max(polls)
