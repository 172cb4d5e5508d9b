"""Who may command the robot from a browser: same-origin pages only, and a token when served beyond loopback.

A websocket is not bound by the browser's same-origin policy: any page the operator opens (``http://evil.example``)
may open one to ``ws://127.0.0.1:8080`` and press E-STOP or "Start all". Browsers do send the page's ``Origin``
with the upgrade request, so the server refuses an upgrade whose Origin is not this server's own (``http://`` +
the ``Host`` it was asked as, and that Host one of this server's names: DNS rebinding gets no further). Clients
that are not browsers send no Origin; on loopback they are this machine's own programs.

Served beyond loopback (``--host 0.0.0.0``), every request must also carry the token printed at start (like
Jupyter's): ``http://HOST:PORT/?token=…`` once, after which a cookie carries it (the page's websocket URL drops the
query). Without it the server answers 403.

viser has no hook for checking requests (its ``process_request`` is private to its server thread), so
:func:`guarded_server` wraps the ``serve`` call viser makes while it starts, chaining our check before viser's own
handler. The wrap is in force only while the server starts, under a lock.
"""

from __future__ import annotations

import hmac
import http
import ipaddress
import logging
import secrets
import threading
from collections.abc import Callable
from http.cookies import SimpleCookie
from typing import Any
from urllib.parse import parse_qs, urlsplit

import viser
import viser.infra._infra as viser_infra
import websockets.asyncio.server
from websockets.datastructures import Headers
from websockets.exceptions import InvalidMessage
from websockets.http11 import Request, Response

from . import viser_events
from .page_script import inject

COOKIE = "asm_studio_token"
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]")
_STARTING = threading.Lock()


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a bind address or name) is this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def new_token() -> str:
    return secrets.token_urlsafe(24)


class AccessGuard:
    """Decides whether one HTTP or websocket request may reach the dashboard; see the module docstring."""

    def __init__(self, host: str, token: str | None = None, *, max_fps: float | None = None) -> None:
        self.host = host
        self.token = token
        self.max_fps = max_fps
        """The frame cap the page gets when its URL gives none (web/page_script.py); None: none."""
        self.port = 0
        self.refused = 0

    def names(self) -> set[str]:
        """The Host header values this server answers to (what an Origin must name)."""
        hosts: set[str] = set(LOOPBACK_NAMES)
        if not is_loopback(self.host) and self.host not in ("0.0.0.0", "::", ""):
            hosts.add(self.host)
        return {f"{h}:{self.port}" for h in hosts}

    def check(self, request: Request) -> Response | None:
        """A refusal for ``request``, or None to let it through."""
        hosts, origins = request.headers.get_all("Host"), request.headers.get_all("Origin")
        if len(hosts) != 1 or len(origins) > 1:
            return self._refuse("a request names one Host and at most one Origin")
        host, origin = hosts[0], (origins[0] if origins else None)
        if self.token is None and host not in self.names():
            return self._refuse(f"unknown host {host!r}: this server answers as {sorted(self.names())}")
        if origin is not None and urlsplit(origin).netloc != host:
            return self._refuse(f"cross-origin request from {origin!r} refused")
        if self.token is not None and not self._has_token(request):
            return self._refuse("this studio needs its access token: open the URL printed when it started")
        return None

    def _has_token(self, request: Request) -> bool:
        assert self.token is not None
        query = parse_qs(urlsplit(request.path).query).get("token", [])
        cookies = SimpleCookie()
        try:
            cookies.load(request.headers.get("Cookie", ""))
        except Exception:
            return False
        given = [*query, *([cookies[COOKIE].value] if COOKIE in cookies else [])]
        return any(hmac.compare_digest(g.encode(), self.token.encode()) for g in given)

    def _refuse(self, why: str) -> Response:
        self.refused += 1
        body = why.encode("utf-8")
        headers = Headers({"Content-Type": "text/plain; charset=utf-8", "Content-Length": str(len(body))})
        return Response(http.HTTPStatus.FORBIDDEN, "Forbidden", headers, body)

    def wrap(self, inner: Callable[..., Any] | None) -> Callable[..., Any]:
        """viser's request handler with this check in front, and the token's cookie set on the page."""

        def process_request(connection: Any, request: Request) -> Response | None:
            refusal = self.check(request)
            if refusal is not None:
                return refusal
            response = inner(connection, request) if inner is not None else None
            if response is None:
                return None
            if response.status_code == 200 and response.headers.get("Content-Type", "").startswith("text/html"):
                response = _with_page_script(response, self.max_fps)
            if self.token is not None:
                response.headers["Set-Cookie"] = f"{COOKIE}={self.token}; HttpOnly; SameSite=Strict; Path=/"
            return response

        return process_request


def _with_page_script(response: Response, max_fps: float | None) -> Response:
    """The page with the studio's script and style in it (web/page_script.py)."""
    gzipped = response.headers.get("Content-Encoding") == "gzip"
    body = inject(bytes(response.body), gzipped=gzipped, max_fps=max_fps)
    headers = Headers(response.headers)
    del headers["Content-Length"]  # a Headers item set twice holds both values
    headers["Content-Length"] = str(len(body))
    return Response(response.status_code, response.reason_phrase, headers, body)


class _ServerModule:
    """Stands in for ``websockets.asyncio.server`` inside viser while it starts: ``serve`` gets the guard."""

    def __init__(self, guard: AccessGuard) -> None:
        self._guard = guard

    def serve(self, *args: Any, process_request: Callable[..., Any] | None = None, **kwargs: Any) -> Any:
        return websockets.asyncio.server.serve(*args, process_request=self._guard.wrap(process_request), **kwargs)

    def __getattr__(self, name: str) -> Any:
        return getattr(websockets.asyncio.server, name)


class _Namespace:
    def __init__(self, real: Any, **overrides: Any) -> None:
        self._real = real
        self.__dict__.update(overrides)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._real, name)


class _ClosedBeforeAsking(logging.Filter):
    """Drops websockets' "opening handshake failed" for a connection closed before it sent a request line: a
    browser's speculative preconnect (Chromium opens one beside the page's and closes it unused) or a port probe.
    It was logged as an error with three chained tracebacks, in the terminal of a studio nothing was wrong with."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not (isinstance(exc, InvalidMessage) and isinstance(exc.__cause__, EOFError))


_QUIET = _ClosedBeforeAsking()


def guarded_server(guard: AccessGuard, **options: Any) -> viser.ViserServer:
    """A ViserServer whose every request passes ``guard`` first (and whose message buffers any thread may push to
    while a tab closes: web/viser_events.py)."""
    viser_events.install()
    if _QUIET not in logging.getLogger("websockets.server").filters:
        logging.getLogger("websockets.server").addFilter(_QUIET)
    # viser imports websockets into its _infra module without re-exporting it; the shim swaps that one name
    real: Any = getattr(viser_infra, "websockets")  # noqa: B009  (a name the module does not export)
    shim = _Namespace(real, asyncio=_Namespace(real.asyncio, server=_ServerModule(guard)))
    with _STARTING:
        setattr(viser_infra, "websockets", shim)  # noqa: B010  (the same unexported name)
        try:
            server = viser.ViserServer(**options)
        finally:
            setattr(viser_infra, "websockets", real)  # noqa: B010  (put back)
    guard.port = server.get_port()
    wanted = options.get("port", 0)
    if wanted and guard.port != wanted:  # viser moves to the next free port; a user who asked for one means it
        server.stop()
        raise OSError(f"port {wanted} on {options.get('host', '127.0.0.1')} is in use (choose another, or 0 for any)")
    return server
