"""The studio layer's fixtures: ``asm-studio`` as its own process for the browser tests (its URL, its Zenoh endpoint
for an outside checker, its output lines). The studio in this process (``studio``) is the root conftest's: the
server layer's tests use it too."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from ..processes import Process
from ..transports import free_port
from .browser import CHROMIUM, MAX_FPS

StudioProcess = tuple[str, str, list[str]]


@pytest.fixture
def start_studio(tmp_path_factory) -> Iterator[Callable[..., StudioProcess]]:
    """Start ``asm-studio`` processes (extra arguments as given) on free ports; every one is stopped at the end.
    Each writes its recordings and keeps its last layout in a directory of its own unless given ``--recordings``
    (a layout kept in the checkout's recordings/ would be restored by the next test's studio), and draws at most
    MAX_FPS frames a second unless given ``--max-fps`` (a moving robot drawn 60 times a second, sent to the page
    and drawn there in software, took most of the suite's two cores)."""
    started: list[Process] = []

    def start(*args: str) -> StudioProcess:
        if "--recordings" not in args:
            args = (*args, "--recordings", str(tmp_path_factory.mktemp("recordings")))
        if "--max-fps" not in args:
            args = (*args, "--max-fps", str(MAX_FPS))
        port, zenoh_port = free_port(), free_port()
        endpoint = f"tcp/127.0.0.1:{zenoh_port}"
        proc = Process("-m", "server.studio", "--port", str(port), "--zenoh-listen", endpoint, *args)
        started.append(proc)
        proc.wait_for_line("READY studio", timeout=60)
        return f"http://127.0.0.1:{port}", endpoint, proc.output

    try:
        yield start
    finally:
        for proc in started:
            proc.stop()


@pytest.fixture
def studio_process(start_studio) -> StudioProcess:
    """``asm-studio`` with the default gait: (URL, Zenoh endpoint, output lines)."""
    return start_studio()


@pytest.fixture(scope="module")
def _chromium_of_module() -> Iterator[list]:
    """Playwright's driver and one Chromium for a test module's browser tests, launched when the first asks, closed
    after the module. Launched per test they cost 2.5-3.6 s of the browser tests' one worker each (the driver 0.7-0.9 s,
    the launch 0.5-1.4 s, the close 0.3-0.5 s, measured under the suite's load; docs/benchmarks.md, "The suite's
    time"). Per module, not per worker: between two sync calls Playwright leaves its event loop marked as this
    thread's running loop, so a later test of another module calling ``asyncio.run`` would fail; stopping the driver
    with the module clears it. Holds [playwright, browser], the browser relaunched by ``chromium`` if it went away."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        launched: list = [pw, None]
        try:
            yield launched
        finally:
            if launched[1] is not None and launched[1].is_connected():
                launched[1].close()


@pytest.fixture
def chromium(_chromium_of_module):
    """Debian's Chromium (a Playwright ``Browser``) for one test: pages are opened in contexts of their own
    (``browser.open_page``, or ``chromium.new_context``), so no test sees another's pages, storage or cookies; any
    context the test left open is closed after it, even when it failed."""
    pw, browser = _chromium_of_module
    if browser is None or not browser.is_connected():
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        _chromium_of_module[1] = browser
    before = set(browser.contexts)
    try:
        yield browser
    finally:
        if browser.is_connected():
            for context in browser.contexts:
                if context not in before:
                    context.close()
