"""The studio end to end: `asm-studio` in its own process, driven by Playwright through Debian's Chromium, checked
from outside by an ordinary ASM client over Zenoh. Screenshots go to tests/artifacts/ (and the README's picture)."""

from __future__ import annotations

import os
import re
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from asm_py import Node
from asm_py.transport.zenoh import ZenohTransport
from tests.helpers import wait_until
from tests.transports import free_port

CHROMIUM = "/usr/bin/chromium"
ARTIFACTS = Path(__file__).resolve().parent / "artifacts"
pytestmark = [
    pytest.mark.timeout(240),
    pytest.mark.skipif(not os.path.exists(CHROMIUM), reason="needs Debian's chromium (make test installs it)"),
]


@pytest.fixture
def studio():
    port, zenoh_port = free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{zenoh_port}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "server.studio", "--port", str(port), "--zenoh-listen", endpoint],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    lines: list[str] = []
    ready = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if line.startswith("READY studio"):
                ready.set()

    threading.Thread(target=read, daemon=True).start()
    try:
        assert ready.wait(60), "".join(lines[-30:])
        yield f"http://127.0.0.1:{port}", endpoint, lines
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _number(text: str, pattern: str) -> float:
    match = re.search(pattern, text)
    assert match, f"{pattern!r} not in {text[:500]!r}"
    return float(match.group(1))


def test_edit_preview_deploy_watch_and_estop(studio):
    from playwright.sync_api import expect, sync_playwright

    url, endpoint, log = studio
    ARTIFACTS.mkdir(exist_ok=True)
    client = Node("e2e-client", ZenohTransport(connect=[endpoint]))
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.goto(url)
            # open the page, load a gait
            expect(page.get_by_role("button", name="E-STOP")).to_be_visible(timeout=30_000)
            page.get_by_role("button", name="Open from library").click()
            expect(page.get_by_text("Opened", exact=False).first).to_be_visible(timeout=15_000)
            # change a cell: state 1 of the wave automaton to 42°; the table view shows it
            angle = page.get_by_label("Angle (deg)")
            angle.fill("42")
            angle.press("Enter")
            expect(page.locator("td", has_text="42.0°").first).to_be_visible(timeout=15_000)
            page.screenshot(path=str(ARTIFACTS / "studio-editor.png"))
            # the preview moves: simulated time and distance grow
            page.get_by_role("tab", name="Preview").click()
            metrics = page.get_by_text("distance", exact=False).first
            expect(metrics).to_be_visible(timeout=15_000)
            first = metrics.inner_text()
            time.sleep(2.0)
            second = metrics.inner_text()
            assert _number(second, r"t = ([\d.]+) s") > _number(first, r"t = ([\d.]+) s")
            assert _number(second, r"distance ([\d.]+) m") > 0.0
            page.screenshot(path=str(ARTIFACTS / "studio-preview.png"))
            # deploy to the simulated modules: every checksum verified, all started
            page.get_by_role("tab", name="Deploy").click()
            page.get_by_role("button", name="Deploy", exact=True).click()
            expect(page.get_by_text("module 8 verified", exact=False)).to_be_visible(timeout=30_000)
            assert wait_until(lambda: all(client.lookup(f"m{i}", "gait.service", timeout=2).running
                                          for i in range(1, 9)), timeout=15)  # fmt: skip
            # the deployed (edited) table is what module 1 holds: its first state is 42°
            table = client.lookup("m1", "gait.table", timeout=2).peek()
            assert abs(struct.unpack_from("<f", table, 5)[0] - 42.0) < 1e-4
            # roster and a live plot
            page.get_by_role("tab", name="Monitor").click()
            expect(page.get_by_text(re.compile(r"m8\s*live")).first).to_be_visible(timeout=15_000)
            expect(page.get_by_text("gait running", exact=False).first).to_be_visible(timeout=15_000)
            plot = page.locator("canvas").last
            before = plot.screenshot()
            time.sleep(1.0)
            assert plot.screenshot() != before, "the live plot did not change"
            page.screenshot(path=str(ARTIFACTS / "studio-monitor.png"))
            # e-stop: every module stops
            page.get_by_role("button", name="E-STOP").click()
            assert wait_until(lambda: not any(client.lookup(f"m{i}", "gait.service", timeout=2).started
                                              for i in range(1, 9)), timeout=15)  # fmt: skip
            expect(page.get_by_text("gait stopped", exact=False).first).to_be_visible(timeout=15_000)
            page.screenshot(path=str(ARTIFACTS / "studio-estop.png"))
            browser.close()
        # a browser that disconnected leaves the server and the modules alive
        assert client.lookup("m1", "joint.angle", timeout=5).peek() is not None
    finally:
        client.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
