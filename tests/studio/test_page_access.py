"""Only the operator commands the robot from a browser: foreign origins are refused, and a token beyond loopback."""

from __future__ import annotations

import http.client
import logging
import urllib.error
import urllib.request

import pytest
import viser
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from server.studio import Studio, StudioOptions
from web.guard import COOKIE, AccessGuard, is_loopback

pytestmark = pytest.mark.timeout(120)
PROTOCOL = f"viser-v{viser.__version__}"


def _open(url: str, origin: str | None = None, cookie: str | None = None, host: str | None = None):
    headers = {**({"Cookie": cookie} if cookie else {}), **({"Host": host} if host else {})}
    return connect(url, origin=origin, subprotocols=[PROTOCOL], additional_headers=headers, open_timeout=10)


def test_a_websocket_from_a_foreign_origin_is_refused(studio) -> None:
    url = f"ws://127.0.0.1:{studio.port}"
    for origin in ("http://evil.example", "http://127.0.0.1:1", "null"):
        with pytest.raises(InvalidStatus) as info:
            _open(url, origin)
        assert info.value.response.status_code == 403
    with pytest.raises(InvalidStatus):  # two Host headers
        _open(url, f"http://127.0.0.1:{studio.port}", host=f"evil.example:{studio.port}")
    rebound = http.client.HTTPConnection("127.0.0.1", studio.port, timeout=10)  # DNS rebinding: a foreign name
    rebound.request("GET", "/", headers={"Host": f"evil.example:{studio.port}"})
    assert rebound.getresponse().status == 403
    rebound.close()
    for origin in (f"http://127.0.0.1:{studio.port}", None):
        _open(url, origin).close()  # the page itself, and programs on this machine
    assert studio.app.guard.refused == 5


def test_beyond_loopback_every_request_needs_the_token() -> None:
    studio = Studio(StudioOptions(port=0, token="s3cret-token"))
    try:
        base = f"127.0.0.1:{studio.port}"
        with pytest.raises(urllib.error.HTTPError) as info:
            urllib.request.urlopen(f"http://{base}/", timeout=10)
        assert info.value.code == 403
        with pytest.raises(InvalidStatus):
            _open(f"ws://{base}", f"http://{base}")
        with pytest.raises(InvalidStatus):
            _open(f"ws://{base}", f"http://{base}", cookie=f"{COOKIE}=wrong")
        page = urllib.request.urlopen(f"http://{base}/?token=s3cret-token", timeout=10)
        cookie = page.headers["Set-Cookie"].split(";")[0]
        assert page.status == 200 and cookie == f"{COOKIE}=s3cret-token"
        _open(f"ws://{base}", f"http://{base}", cookie=cookie).close()
    finally:
        studio.close()


def test_a_studio_served_beyond_loopback_makes_a_token_and_loopback_does_not() -> None:
    assert is_loopback("127.0.0.1") and is_loopback("::1") and is_loopback("localhost")
    assert not is_loopback("0.0.0.0") and not is_loopback("192.0.2.1")
    assert AccessGuard("0.0.0.0").token is None  # the studio passes one (tested above); the guard only checks it


def test_a_connection_closed_before_its_request_logs_no_error_but_a_bad_request_still_does(studio, monkeypatch) -> None:
    """A browser's unused preconnect (Chromium opens one and closes it) or a port probe: websockets logged it as
    "opening handshake failed" with three chained tracebacks in the studio's terminal. A malformed request is
    still an error worth its line."""
    import socket
    import time

    from ..helpers import wait_until

    records: list[logging.LogRecord] = []
    handler = logging.Handler(logging.INFO)
    handler.emit = records.append  # type: ignore[method-assign]
    logger = logging.getLogger("websockets.server")
    monkeypatch.setattr(logger, "disabled", False)  # another test's logging set-up may have disabled it
    monkeypatch.setattr(logger, "level", logging.INFO)
    # viser silences every failed handshake (its NoHttpErrors filter), but only from its server's first answered
    # request on: the studio's terminal showed the ones before (a preconnect at the page's first load). Without
    # viser's, as before that request, only ours is in force here
    monkeypatch.setattr(logger, "filters", [f for f in logger.filters if type(f).__name__ != "NoHttpErrors"])
    logger.addHandler(handler)
    try:
        with socket.create_connection(("127.0.0.1", studio.port), timeout=10):
            pass  # closed without a word
        with socket.create_connection(("127.0.0.1", studio.port), timeout=10) as garbage:
            garbage.sendall(b"\xff\xfe not http\r\n\r\n")
            garbage.recv(100)
        assert wait_until(lambda: any(r.getMessage() == "opening handshake failed" for r in records), timeout=20), [
            (r.getMessage(), r.exc_info) for r in records
        ]
        time.sleep(0.5)  # the first connection's handling, had it been logged, would be by now
    finally:
        logger.removeHandler(handler)
    failed = [r for r in records if r.getMessage() == "opening handshake failed"]
    assert len(failed) == 1 and failed[0].exc_info is not None
    assert not isinstance(failed[0].exc_info[1].__cause__, EOFError)  # the garbage one, not the silent one
