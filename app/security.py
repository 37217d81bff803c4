"""Who may use `signpose serve`, and what browsers may do with what it serves.

`AccessGuard` decides who gets in:

- With an access token (required whenever the server listens beyond loopback) every request and
  websocket must carry it: `Authorization: Bearer <token>`, the `signpose_token` cookie, or
  `?token=<token>`. A page opened with `?token=` gets the cookie and is redirected to its address
  without it, so the browser keeps working (fetch, EventSource, the viser iframe and its
  websocket all send the cookie) and the token does not stay in the address bar or history.
- Without a token the server is for this machine only: a request naming a host other than a
  loopback one is refused, so a web page whose domain is made to resolve to 127.0.0.1 (DNS
  rebinding) cannot reach it.
- Either way a browser's cross-site write or websocket is refused by its Origin header (CSRF,
  cross-site websocket hijacking: no token or cookie is needed for those on loopback). Scripts
  and command-line tools send no Origin and are unaffected. The heavy routes (app/heavy.py) refuse
  a cross-site GET too (`cross_site_refusal`, which app/api/deps.py applies to them).
- A Host header that is not `host[:port]` (`evil.example@127.0.0.1:8000` names a user before the
  host, and would read as 127.0.0.1) is refused with 400 whoever sends it.

`SecurityHeaders` adds nosniff, same-origin framing (the page iframes `/viser/`), no referrer,
and a Content-Security-Policy per area: strict for the page and the API (only its own scripts,
styles and connections); viser's prebuilt client and FastAPI's /docs (Swagger UI, served locally
from the fastapi-offline package) get what they need to run and no more. No CORS headers are ever sent: other origins cannot read
anything.
"""

from __future__ import annotations

import ipaddress
import secrets
from urllib.parse import parse_qsl, urlencode, urlsplit

from starlette import status
from starlette.datastructures import Headers, MutableHeaders
from starlette.requests import cookie_parser
from starlette.responses import JSONResponse, RedirectResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send

TOKEN_COOKIE = "signpose_token"
TOKEN_QUERY = "token"
TOKEN_ENV = "SIGNPOSE_TOKEN"
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")

_COMMON_CSP = "object-src 'none'; base-uri 'self'; form-action 'self'; frame-ancestors 'self'"
PAGE_CSP = f"default-src 'self'; img-src 'self' data: blob:; {_COMMON_CSP}"
# viser's client unpacks itself into inline scripts and styles with a WebAssembly decoder, and a
# WebAssembly module of its scene builds JavaScript functions from strings (eval).
VISER_CSP = ("default-src 'self'; script-src 'self' 'unsafe-inline' 'unsafe-eval' 'wasm-unsafe-eval' blob:; "
             "style-src 'self' 'unsafe-inline'; img-src 'self' data: blob:; font-src 'self' data:; "
             f"connect-src 'self' data: blob:; worker-src 'self' blob:; {_COMMON_CSP}")
# Swagger UI's page starts it from an inline script and styles itself inline; ReDoc runs a blob: worker.
DOCS_CSP = ("default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
            f"img-src 'self' data:; worker-src 'self' blob:; {_COMMON_CSP}")
DOCS_PATHS = ("/docs", "/docs/oauth2-redirect", "/redoc")
DOCS_ASSETS = "/docs-assets"  # where Swagger UI's and ReDoc's own files are served


def is_loopback(host: str) -> bool:
    """Whether `host` (a name or an address, IPv6 possibly in brackets) is this machine only."""
    host = host.strip("[]").lower()
    if host == "localhost" or host.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def access_token(host: str, given: str | None) -> str | None:
    """The token a server listening on `host` requires: `given` (--token or $SIGNPOSE_TOKEN),
    else a new random one unless `host` is loopback, where no token is needed."""
    if given:
        return given
    return None if is_loopback(host) else secrets.token_urlsafe(18)


# What a Host header may hold besides a name, an address and a port: no user before an "@", no path.
NOT_IN_HOST = frozenset("@/\\?#")
# Sec-Fetch-Site values of a browser's request from a page of another origin. "same-site" too: on
# 127.0.0.1 every other port's page, any local program's, is the same site.
FOREIGN_FETCHES = ("cross-site", "same-site")


def _netloc(url: str) -> tuple[str, str]:
    """(host name, host[:port]) of `url`, lower case; empty for what does not parse (a stray "[")."""
    try:
        parts = urlsplit(url)
        return parts.hostname or "", parts.netloc.lower()
    except ValueError:
        return "", ""


def _origin_refusal(origin: str | None, netloc: str) -> str | None:
    """Why a browser's request from `origin` is refused: not the page of the server addressed as
    `netloc` (host[:port]); None without an Origin or from that page."""
    if origin is None or (netloc and _netloc(origin)[1] == netloc):
        return None
    return f"cross-site request from {origin!r} refused; use the page this server serves"


def cross_site_refusal(headers: Headers) -> str | None:
    """Why a browser's request is refused as coming from another origin's page, even a GET (an `<img>`
    tag sends no Origin, but Sec-Fetch-Site); None for the server's own page (same-origin), a typed
    address or bookmark (none), and scripts and command-line tools, which send neither header."""
    refusal = _origin_refusal(headers.get("origin"), _netloc(f"//{headers.get('host', '')}")[1])
    site = headers.get("sec-fetch-site", "").lower()
    if refusal is None and site in FOREIGN_FETCHES:
        refusal = (f"request from another site's page refused (Sec-Fetch-Site: {site}): this route runs heavy "
                   "work; use the page this server serves, or call it from a script")
    return refusal


class AccessGuard:
    """Pure ASGI middleware for HTTP and websockets (see the module docstring)."""

    def __init__(self, app: ASGIApp, token: str | None) -> None:
        self.app = app
        self.token = token

    def _refusal(self, scope: Scope) -> tuple[int, str] | None:
        """(status, message) when the request may not proceed whoever sends it; None when it may."""
        headers = Headers(scope=scope)
        host = headers.get("host", "")
        if NOT_IN_HOST.intersection(host):
            return 400, f"the Host header must be host[:port], got {host!r}"
        host_name, netloc = _netloc(f"//{host}")
        if self.token is None and not is_loopback(host_name):
            return 403, (f"this signpose server only answers requests for this machine (got Host {host!r}); "
                         "open it as http://127.0.0.1:<port>/, or restart it with --host and share its token")
        writes = scope["type"] == "websocket" or scope["method"] not in SAFE_METHODS
        refusal = _origin_refusal(headers.get("origin"), netloc) if writes else None
        return None if refusal is None else (403, refusal)

    def _token_source(self, scope: Scope) -> str | None:
        """Where the request's valid token is: "header", "cookie" or "query"; None when it has none."""
        headers = Headers(scope=scope)
        scheme, _, bearer = headers.get("authorization", "").partition(" ")
        assert self.token is not None  # asked only of a server that has a token
        query = dict(parse_qsl(scope.get("query_string", b"").decode("latin-1")))
        # The query first: a page opened with it is redirected without it even when it has the cookie.
        for source, candidate in (("query", query.get(TOKEN_QUERY)),
                                  ("header", bearer.strip() if scheme.lower() == "bearer" else None),
                                  ("cookie", cookie_parser(headers.get("cookie", "")).get(TOKEN_COOKIE))):
            if candidate is not None and secrets.compare_digest(candidate.encode(), self.token.encode()):
                return source
        return None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        refusal = self._refusal(scope)
        if refusal is None and self.token is not None:
            source = self._token_source(scope)
            if source is None:
                refusal = 401, ("this signpose server needs its access token: open the address `signpose serve` "
                                "printed (it ends in ?token=...), or send the header 'Authorization: Bearer <token>'")
            elif source == "query" and scope["type"] == "http" and scope["method"] == "GET" \
                    and not scope["path"].startswith("/api/"):
                await self._remember(scope, receive, send)
                return
        if refusal is None:
            await self.app(scope, receive, send)
            return
        response = JSONResponse({"detail": refusal[1]}, refusal[0])
        if scope["type"] == "http":
            await response(scope, receive, send)
        elif "websocket.http.response" in scope.get("extensions", {}):
            await receive()  # the websocket.connect the server queued
            await response(scope, receive, send)
        else:  # the server cannot send a body: closing before accepting makes it answer 403
            await send({"type": "websocket.close", "code": 1008})

    async def _remember(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Set the token cookie and redirect to the same address without the token."""
        query = parse_qsl(scope.get("query_string", b"").decode("latin-1"), keep_blank_values=True)
        rest = urlencode([(k, v) for k, v in query if k != TOKEN_QUERY])
        assert self.token is not None  # a token in the query is remembered only by a server that has one

        response = RedirectResponse(scope["path"] + (f"?{rest}" if rest else ""), status.HTTP_303_SEE_OTHER)
        response.set_cookie(TOKEN_COOKIE, self.token, httponly=True, samesite="lax")
        await response(scope, receive, send)


class SecurityHeaders:
    """Pure ASGI middleware adding the security headers to every HTTP response."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    @staticmethod
    def policy(path: str) -> str:
        if path == "/viser" or path.startswith("/viser/"):
            return VISER_CSP
        return DOCS_CSP if path in DOCS_PATHS else PAGE_CSP

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        csp = self.policy(scope["path"])

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                headers.setdefault("X-Content-Type-Options", "nosniff")
                headers.setdefault("X-Frame-Options", "SAMEORIGIN")
                headers.setdefault("Referrer-Policy", "no-referrer")
                headers.setdefault("Content-Security-Policy", csp)
            await send(message)

        await self.app(scope, receive, send_with_headers)
