"""The studio layer's fixtures: ``asm-studio`` as its own process for the browser tests (its URL, its Zenoh endpoint
for an outside checker, its output lines). The studio in this process (``studio``) is the root conftest's: the
server layer's tests use it too."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from ..processes import Process
from ..transports import free_port
from .browser import MAX_FPS

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
