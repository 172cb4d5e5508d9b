"""The studio's Modules tab (issue 28), by clicks in Chromium: the roster of the simulated robot's modules with their
firmware and calibration, a calibration typed and applied (the module holds it, as an outside tool reads), one the
module refuses (said on the page, nothing changed), and "Set current pose as zero"."""

from __future__ import annotations

import re
import time

import pytest

from asm_py.node import Node
from asm_py.remote import RemoteAttribute
from asm_py.transport.zenoh import ZenohTransport

from ..helpers import ARTIFACTS
from .browser import marks, open_page, page_until

pytestmark = marks(__name__)


def _fill(page, label: str, value: str) -> None:
    field = page.get_by_label(label)
    field.fill(value)
    field.press("Enter")


def _pick(page, label: str, option: str) -> None:
    page.get_by_role("combobox", name=label).click()
    page.get_by_role("option", name=option, exact=True).click()


def attribute(client: Node, node: str, name: str) -> RemoteAttribute:
    remote = client.lookup(node, name, timeout=5)
    assert isinstance(remote, RemoteAttribute)
    return remote


def test_the_modules_tab_reads_calibrates_refuses_and_zeros_by_clicks(studio_process, chromium):
    from playwright.sync_api import expect

    url, endpoint, _ = studio_process
    client = Node("modules-check", ZenohTransport(connect=[endpoint]))
    try:
        browser, page = open_page(chromium, url)
        page.get_by_role("tab", name="Modules").click()
        read = page.get_by_text(re.compile(r"Read 8 modules: 8 said their firmware, 8 their calibration"))
        deadline = time.monotonic() + 120  # the simulated robot's modules come up after the page
        while True:
            page.get_by_role("button", name="Read modules").click()
            try:
                expect(read).to_be_visible(timeout=15_000)
                break
            except AssertionError:
                if time.monotonic() > deadline:
                    raise
        expect(page.locator("td", has_text=re.compile(r"Python 0\.1\.0 [0-9a-f]{8} 1024 states"))).to_have_count(8)
        # m3: a joint mounted the other way round, its zero 10° off, soft limits -60..70
        _pick(page, "Calibrate module", "m3")
        _fill(page, "Zero (raw °)", "10")
        _pick(page, "Joint direction", "-1")
        _fill(page, "Soft min (°)", "-60")
        _fill(page, "Soft max (°)", "70")
        page.get_by_role("button", name="Apply calibration").click()
        expect(page.get_by_text("m3 calibrated: zero 10°, direction -1, soft limits -60..70°")).to_be_visible(
            timeout=30_000
        )
        expect(page.locator("td", has_text="10° -1 -60..70°")).to_have_count(1, timeout=15_000)
        wanted = {"zero": 10.0, "direction": -1, "min": -60.0, "max": 70.0}
        assert attribute(client, "m3", "joint.calibration").get(timeout=5) == wanted
        # min above max: refused naming the fields, nothing sent
        _fill(page, "Soft min (°)", "80")
        page.get_by_role("button", name="Apply calibration").click()
        expect(page.get_by_text("⚠ Soft min (80°) must be below Soft max (70°)")).to_be_visible(timeout=30_000)
        # a calibration the module refuses: a limit's raw angle (zero - limit) past the joint's ±90°; the page
        # names the fields and their raw angles, and nothing changes
        _fill(page, "Soft min (°)", "-60")
        _fill(page, "Zero (raw °)", "40")
        page.get_by_role("button", name="Apply calibration").click()
        expect(page.get_by_text(re.compile(r"⚠ m3 refused the calibration .*Soft min -60° and Soft max 70° are "
                                           r"raw -30\.\.100°"))).to_be_visible(timeout=30_000)  # fmt: skip
        assert attribute(client, "m3", "joint.calibration").get(timeout=5) == wanted
        # m5, turned to 20° by a tool: that pose becomes its zero
        attribute(client, "m5", "joint.goal").set(20.0, wait=True)
        m5_angle = attribute(client, "m5", "joint.angle")
        assert page_until(lambda: abs(m5_angle.get(timeout=5) - 20.0) < 3.0, timeout=20)
        _pick(page, "Calibrate module", "m5")
        page.get_by_role("button", name="Set current pose as zero").click()
        expect(page.get_by_text("m5: its pose now is its zero", exact=False)).to_be_visible(timeout=30_000)
        page.screenshot(path=str(ARTIFACTS / "modules-tab.png"))
        browser.close()
        zeroed = attribute(client, "m5", "joint.calibration").get(timeout=5)
        # where the joint stood when the page read it (the simulated chain still settles under its goal of 20°)
        assert abs(zeroed["zero"] - 20.0) < 6.0 and zeroed["direction"] == 1, zeroed
        raw_limits = (zeroed["zero"] + zeroed["min"], zeroed["zero"] + zeroed["max"])
        # exact to 0.01°, or 0.01° inward where the module refused them exact (float32 a hair past ±90°)
        assert raw_limits == (pytest.approx(-89.995, abs=0.011), pytest.approx(89.995, abs=0.011)), "on the joint"
        goal = attribute(client, "m5", "joint.goal").get(timeout=5)
        assert goal == pytest.approx(20.0 - zeroed["zero"], abs=0.01), "the joint kept where it was commanded"
    finally:
        client.close()
