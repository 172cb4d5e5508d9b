"""Driving from the page (issue 16's "done when"): open the steerable caterpillar, steer the preview with the arrow
keys, deploy it, and steer the deployed robot the same way — as a user does it in Chromium, checked from outside."""

from __future__ import annotations

import re

import pytest

from asm_py import Node
from asm_py.transport.zenoh import ZenohTransport
from tests.helpers import wait_until
from tests.processes import Process
from tests.test_studio_e2e import ARTIFACTS, CHROMIUM, _number, _open, pytestmark  # noqa: F401
from tests.transports import free_port

GAIT = "gaits/library/steerable_caterpillar.toml"


@pytest.fixture
def steerable_studio():
    port, zenoh_port = free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{zenoh_port}"
    proc = Process("-m", "server.studio", "--port", str(port), "--zenoh-listen", endpoint, "--gait", GAIT)
    try:
        proc.wait_for_line("READY studio", timeout=60)
        yield f"http://127.0.0.1:{port}", endpoint, proc.output
    finally:
        proc.stop()


def _heading(page) -> float:
    return _number(page.get_by_text("heading", exact=False).first.inner_text(), r"heading (-?\d+)°")


def test_a_user_steers_the_preview_and_the_deployed_robot_with_the_arrow_keys(steerable_studio) -> None:
    from playwright.sync_api import expect, sync_playwright

    url, endpoint, log = steerable_studio
    client = Node("checker", ZenohTransport(connect=[endpoint]))
    try:
        with sync_playwright() as pw:
            browser, page = _open(pw, url)
            page.get_by_role("tab", name="Preview").click()
            assert wait_until(lambda: _number(page.get_by_text("t = ", exact=False).first.inner_text(),
                                              r"t = ([\d.]+) s") > 3.0, timeout=60)  # fmt: skip
            straight = _heading(page)
            assert abs(straight) < 10  # forward: it crawls straight
            page.mouse.click(200, 800)  # the 3D view has the focus, not a field
            page.keyboard.press("ArrowLeft")
            page.get_by_role("tab", name="Drive").click()
            expect(page.get_by_text("Preview: left", exact=False)).to_be_visible(timeout=10_000)
            # the heading is the travel since the start: turning left swings it counter-clockwise
            assert wait_until(lambda: _heading(page) > straight + 20, timeout=60), _heading(page)
            page.screenshot(path=str(ARTIFACTS / "drive_preview_left.png"))
            page.mouse.click(200, 800)
            page.keyboard.press("ArrowUp")
            expect(page.get_by_text("Preview: forward", exact=False)).to_be_visible(timeout=10_000)
            page.get_by_role("tab", name="Deploy").click()
            page.get_by_role("button", name="Deploy", exact=True).click()
            page.get_by_role("button", name="Start", exact=True).click()
            expect(page.get_by_text("12 modules confirmed running", exact=False).first).to_be_visible(timeout=60_000)
            page.mouse.click(200, 800)
            page.keyboard.press("ArrowRight")  # the View shows Live after a deploy: this steers the robot
            page.get_by_role("tab", name="Drive").click()
            expect(page.get_by_text(re.compile(r"Robot: right, confirmed by 12 of 12"))).to_be_visible(timeout=30_000)
            assert client.lookup("m2", "gait.mode", timeout=5).get(timeout=5) == 2  # program gait 2: right
            goal = client.lookup("m2", "joint.goal", timeout=5)
            assert wait_until(lambda: goal.get(timeout=5) < -19, timeout=10)  # its yaw joint bends right, blended
            page.screenshot(path=str(ARTIFACTS / "drive_robot_right.png"))
            page.mouse.click(200, 800)
            page.keyboard.press("S")
            expect(page.get_by_text("Robot: stop", exact=False)).to_be_visible(timeout=30_000)
            assert wait_until(lambda: not client.lookup("m1", "gait.service", timeout=5).running, timeout=10)
            browser.close()
    finally:
        client.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
