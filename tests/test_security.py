"""Exposure of `signpose serve`: the access token (HTTP, the page's cookie, the viser websocket),
loopback-only answers without one, cross-site writes, no CORS, and the security headers."""

from __future__ import annotations

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from signpose.app.security import PAGE_CSP, TOKEN_COOKIE, VISER_CSP, access_token, is_loopback
from signpose.app.server import create_app
from signpose.app.workspace import Workspace, WorkspaceConfig
from tests.support.serving import (TIMEOUT_S, VISER_PROTOCOL, assert_error, http_exchange, running, start_serve,
                                   stop_serve)

# The token and origin checks of a real uvicorn server and of `signpose serve`.
pytestmark = pytest.mark.server

TOKEN = "team-token-for-tests"


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    ws = Workspace.open(WorkspaceConfig(state_dir=tmp_path_factory.mktemp("security") / "state", load_samples=False,
                                   workers=1, max_upload_bytes=1_000_000))
    yield ws
    ws.close()


@pytest.fixture(scope="module")
def guarded(workspace):
    """Base URL of a server that needs TOKEN."""
    with running(create_app(workspace, token=TOKEN)) as url:
        yield url


@pytest.fixture(scope="module")
def open_url(workspace):
    """Base URL of a server without a token: this machine only."""
    with running(create_app(workspace)) as url:
        yield url


def ws_url(base: str, path: str = "/viser") -> str:
    return base.replace("http://", "ws://") + path


def test_a_token_is_needed_beyond_loopback():
    for host in ("127.0.0.1", "127.0.0.2", "::1", "[::1]", "localhost"):
        assert is_loopback(host) and access_token(host, None) is None, host
    for host in ("0.0.0.0", "::", "192.168.1.20", "signpose-laptop"):
        assert not is_loopback(host)
        token = access_token(host, None)
        assert token is not None and len(token) >= 20 and token != access_token(host, None)
    assert access_token("0.0.0.0", "given") == access_token("127.0.0.1", "given") == "given"


def test_http_without_the_token_is_refused(guarded):
    for path in ("/api/health", "/", "/viser/", "/docs", "/openapi.json", "/api/images"):
        assert_error(httpx.get(guarded + path), 401, "access token", "Bearer")
    assert_error(httpx.get(guarded + "/api/health", headers={"Authorization": "Bearer wrong"}), 401)
    assert_error(httpx.get(guarded + "/api/health", cookies={TOKEN_COOKIE: "wrong"}), 401)
    # Refused before the body is read: an unauthenticated upload costs nothing.
    head = (b"POST /api/images HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: multipart/form-data; boundary=b\r\n"
            b"Content-Length: 900000000\r\nConnection: close\r\n\r\n")
    status, body = http_exchange(guarded, head)
    assert status == 401 and "access token" in body["detail"]


def test_http_with_the_token_is_served(guarded):
    assert httpx.get(guarded + "/api/health", headers={"Authorization": f"Bearer {TOKEN}"}).status_code == 200
    assert httpx.get(guarded + "/api/health", cookies={TOKEN_COOKIE: TOKEN}).status_code == 200
    assert httpx.get(guarded + f"/api/health?token={TOKEN}").status_code == 200


def test_the_page_takes_the_token_once_and_keeps_it_in_a_cookie(guarded):
    with httpx.Client(base_url=guarded, timeout=TIMEOUT_S) as browser:
        r = browser.get(f"/?token={TOKEN}")
        assert r.status_code == 303 and r.headers["location"] == "/"  # out of the address bar and history
        cookie = r.headers["set-cookie"].lower()
        assert f"{TOKEN_COOKIE}={TOKEN}".lower() in cookie and "httponly" in cookie and "samesite=lax" in cookie
        assert browser.get("/").headers["content-type"].startswith("text/html")
        assert browser.get("/api/settings").status_code == 200
        assert "<title>Viser</title>" in browser.get("/viser/").text
        r = browser.get(f"/viser/?a=1&token={TOKEN}")
        assert r.status_code == 303 and r.headers["location"] == "/viser/?a=1"


def test_the_viser_websocket_needs_the_token(guarded):
    with pytest.raises(InvalidStatus) as refused:
        connect(ws_url(guarded), subprotocols=[VISER_PROTOCOL], open_timeout=10)
    assert refused.value.response.status_code == 401
    with pytest.raises(InvalidStatus):
        connect(ws_url(guarded, "/viser/?token=wrong"), subprotocols=[VISER_PROTOCOL], open_timeout=10)
    for path, headers in (("/viser", {"Cookie": f"{TOKEN_COOKIE}={TOKEN}"}), (f"/viser/?token={TOKEN}", {}),
                          ("/viser", {"Authorization": f"Bearer {TOKEN}"})):
        with connect(ws_url(guarded, path), subprotocols=[VISER_PROTOCOL], additional_headers=headers,
                     max_size=None, open_timeout=10) as ws:
            assert isinstance(ws.recv(timeout=10), bytes)  # viser's first message batch


def test_without_a_token_only_requests_for_this_machine_are_answered(open_url):
    port = open_url.rsplit(":", 1)[1]
    for host in ("127.0.0.1", f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}"):
        assert httpx.get(open_url + "/api/health", headers={"Host": host}).status_code == 200, host
    # DNS rebinding: a page on evil.example whose name now resolves to 127.0.0.1.
    assert_error(httpx.get(open_url + "/api/images", headers={"Host": f"evil.example:{port}"}), 403, "this machine")
    assert_error(httpx.get(open_url + "/api/images", headers={"Host": "["}), 403, "this machine")


def test_a_host_with_a_user_or_a_path_in_it_is_refused(open_url, guarded):
    """`evil.example@127.0.0.1` names the user evil.example at 127.0.0.1: read as a URL it passed the
    loopback check, though a proxy or a browser may have taken evil.example for the host."""
    port = open_url.rsplit(":", 1)[1]
    for host in (f"evil.example@127.0.0.1:{port}", f"127.0.0.1:{port}/evil", "evil.example#@127.0.0.1"):
        assert_error(httpx.get(open_url + "/api/health", headers={"Host": host}), 400, "host[:port]", host)
    r = httpx.get(guarded + "/api/health", headers={"Host": "evil.example@127.0.0.1", "Authorization": f"Bearer {TOKEN}"})
    assert_error(r, 400, "host[:port]")


def test_a_cross_site_get_of_heavy_work_is_refused(open_url):
    """An `<img>` tag on another site's page sends a GET without Origin, but with Sec-Fetch-Site: the
    heavy routes refuse it as writes are refused; the page itself, typed addresses and scripts pass."""
    for site in ("cross-site", "same-site"):
        r = httpx.get(open_url + "/api/sweep", headers={"Sec-Fetch-Site": site})
        assert_error(r, 403, f"Sec-Fetch-Site: {site}", "heavy work", "use the page this server serves")
        r = httpx.post(open_url + "/api/calibrate/threshold", json={"image_id": "0123456789ab"},
                       headers={"Sec-Fetch-Site": site})
        assert_error(r, 403, "another site's page")
    assert_error(httpx.get(open_url + "/api/sweep", headers={"Origin": "http://evil.example"}), 403, "cross-site",
                 "evil.example")
    # Past the check: no labelled images to sweep over.
    for headers in ({"Sec-Fetch-Site": "same-origin", "Origin": open_url}, {"Sec-Fetch-Site": "none"}, {}):
        assert_error(httpx.get(open_url + "/api/sweep", headers=headers), 409, "no labelled images")
    # Light GETs are as they were: other sites' pages may show them, never read them (no CORS).
    assert httpx.get(open_url + "/api/settings", headers={"Sec-Fetch-Site": "cross-site"}).status_code == 200


def test_cross_site_writes_and_websockets_are_refused(open_url):
    origin = open_url  # what a browser sends from the page itself
    before = httpx.get(open_url + "/api/settings").json()
    for method, path in (("PUT", "/api/settings"), ("POST", "/api/settings/preset/paper"),
                         ("DELETE", "/api/camera"), ("POST", "/api/images")):
        r = httpx.request(method, open_url + path, json={"threshold": 0.5}, headers={"Origin": "http://evil.example"})
        assert_error(r, 403, "cross-site", "evil.example")
    assert_error(httpx.put(open_url + "/api/settings", json={}, headers={"Origin": "http://["}), 403, "cross-site")
    assert httpx.get(open_url + "/api/settings").json() == before
    assert httpx.get(open_url + "/api/settings", headers={"Origin": "http://evil.example"}).status_code == 200
    r = httpx.put(open_url + "/api/settings", json={"threshold": before["settings"]["threshold"]},
                  headers={"Origin": origin})
    assert r.status_code == 200
    with pytest.raises(InvalidStatus) as refused:
        connect(ws_url(open_url), origin="http://evil.example", subprotocols=[VISER_PROTOCOL], open_timeout=10)
    assert refused.value.response.status_code == 403
    with connect(ws_url(open_url), origin=origin, subprotocols=[VISER_PROTOCOL], max_size=None, open_timeout=10) as ws:
        assert isinstance(ws.recv(timeout=10), bytes)


def test_no_cors(open_url):
    preflight = httpx.options(open_url + "/api/settings", headers={
        "Origin": "http://evil.example", "Access-Control-Request-Method": "PUT"})
    read = httpx.get(open_url + "/api/settings", headers={"Origin": "http://evil.example"})
    for r in (preflight, read):
        assert not any(h.startswith("access-control-") for h in r.headers), r.headers


def test_security_headers(open_url, guarded):
    for base, path, status, csp in ((open_url, "/", 200, PAGE_CSP), (open_url, "/api/health", 200, PAGE_CSP),
                                    (open_url, "/api/images/nope", 404, PAGE_CSP), (guarded, "/", 401, PAGE_CSP),
                                    (open_url, "/viser/", 200, VISER_CSP)):
        r = httpx.get(base + path)
        assert r.status_code == status
        assert r.headers["x-content-type-options"] == "nosniff"
        assert r.headers["x-frame-options"] == "SAMEORIGIN"  # the page iframes /viser/
        assert r.headers["referrer-policy"] == "no-referrer"
        assert r.headers["content-security-policy"] == csp, path
    script_src = next(d for d in PAGE_CSP.split(";") if d.strip().startswith("default-src"))
    assert "unsafe" not in PAGE_CSP and script_src.strip() == "default-src 'self'"


def test_serve_takes_its_token_from_the_option_or_the_environment(tmp_path):
    from_option, option_url = start_serve(tmp_path / "a" / "state", "--token", TOKEN,
                                          env={"SIGNPOSE_TOKEN": "not-this-one"})
    from_env, env_url = start_serve(tmp_path / "b" / "state", env={"SIGNPOSE_TOKEN": "from-env"})
    try:
        for url, token in ((option_url, TOKEN), (env_url, "from-env")):
            base = url.split("?")[0].rstrip("/")
            assert url.endswith(f"/?token={token}")
            assert_error(httpx.get(base + "/api/health", timeout=TIMEOUT_S), 401)
            r = httpx.get(base + "/api/health", headers={"Authorization": f"Bearer {token}"}, timeout=TIMEOUT_S)
            assert r.status_code == 200
        assert httpx.get(option_url.split("?")[0] + "api/health", timeout=TIMEOUT_S,
                         headers={"Authorization": "Bearer not-this-one"}).status_code == 401
    finally:
        for proc in (from_option, from_env):
            stop_serve(proc)
