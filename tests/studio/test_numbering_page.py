"""Issue 28's "Done when" on a short robot, by clicks: the studio's own robot runs chain positions 1 and 2 as a
fresh batch of emulated boards (``--emulated-modules 1,2``, their flash in the studio's recordings folder by
default); on the Modules tab a user finds them by serial (no IDs), numbers them along the chain — each wiggled in
turn, the user saying which chain position moved — and the roster then shows m1 and m2 as boards with their
firmware; the caterpillar deploys to them and runs."""

from __future__ import annotations

import re
import shutil
import time

import pytest

from asm_module.board_batch import BoardBatch

from ..helpers import ARTIFACTS
from .browser import deploy_and_start, marks, open_page

pytestmark = [
    pytest.mark.timeout(600),  # before marks()'s 240 s: the closest timeout mark is the first
    *marks(__name__),
    pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None, reason="make test installs gcc-arm-none-eabi"),
]


def test_fresh_boards_are_found_numbered_along_the_chain_and_deployed_to_from_the_modules_tab(
    start_studio, tmp_path, chromium
):
    from playwright.sync_api import expect

    recordings = tmp_path / "recordings"
    url, _, log = start_studio("--emulated-modules", "1,2", "--recordings", str(recordings))
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Modules").click()
    deadline = time.monotonic() + 180  # the robot child and its emulated boards come up after the page
    while True:
        page.get_by_role("button", name="Find modules").click()
        try:
            expect(page.get_by_text("Found 2 modules, 2 without a node ID.")).to_be_visible(timeout=30_000)
            break
        except AssertionError:
            if time.monotonic() > deadline:
                raise
    # the studio keeps its boards in RECORDINGS/boards: what the user sees move, the test reads from there
    position_of = {BoardBatch(recordings / "boards").serial(p).hex(): p for p in (1, 2)}
    for serial in position_of:
        expect(page.locator("td", has_text=serial)).to_have_count(1)
    expect(page.locator("td", has_text=re.compile(r"^none$"))).to_have_count(2)
    page.get_by_role("button", name="Confirm position").click()  # hostile: nothing was wiggled to confirm
    expect(page.get_by_text("⚠ start with Number along the chain")).to_be_visible(timeout=30_000)
    field = page.get_by_label("Node ID")
    field.fill("5")  # hostile: Python module m5 has it
    field.press("Enter")
    page.get_by_role("button", name="Assign ID").click()
    expect(page.get_by_text(re.compile(r"⚠ node ID 5 is taken by a module alive on the bus"))).to_be_visible(
        timeout=60_000
    )
    field.fill("-1")  # hostile: refused, never clamped to 0 (which erases a module's ID)
    field.press("Enter")
    page.get_by_role("button", name="Assign ID").click()
    expect(page.get_by_text("⚠ a node ID is a whole number 1..253 (0 erases), not -1")).to_be_visible(timeout=30_000)
    expect(page.locator("td", has_text=re.compile(r"^none$"))).to_have_count(2)
    page.get_by_role("button", name="Number along the chain").click()
    for round_ in range(2):
        asked = page.get_by_text(re.compile(r"Which chain position moved\? [0-9a-f]{24} was wiggled"))
        try:
            expect(asked).to_be_visible(timeout=120_000)
        except AssertionError as exc:  # say what the page said instead (a refusal, a timeout of the robot)
            said = [t for t in page.inner_text("body").splitlines() if "⚠" in t or "iggl" in t]
            raise AssertionError(f"the page said {said}") from exc
        serial = re.search(r"[0-9a-f]{24}", asked.inner_text()).group(0)  # type: ignore[union-attr]
        field = page.get_by_label("Chain position that moved")
        if round_ == 0:  # hostile: the robot has 8 modules, so there is no position 9
            field.fill("9")
            field.press("Enter")
            page.get_by_role("button", name="Confirm position").click()
            expect(page.get_by_text("⚠ a chain position is a whole number 1..8 (the robot's modules), not 9"))\
                .to_be_visible(timeout=30_000)  # fmt: skip
            expect(page.locator("td", has_text=re.compile(r"^none$"))).to_have_count(2)
        field.fill(str(position_of[serial]))
        field.press("Enter")
        page.get_by_role("button", name="Confirm position").click()
        expect(asked).to_be_hidden(timeout=120_000)
    expect(page.get_by_text("Every module has a node ID: m1, m2.")).to_be_visible(timeout=120_000)
    expect(page.locator("td", has_text=re.compile(r"^none$"))).to_have_count(0)
    for name in ("m1", "m2"):  # the roster, read again: m1 and m2 are boards, with their firmware
        row = page.locator("tr", has=page.locator("td", has_text=re.compile(f"^{name}$")))
        expect(row.locator("td", has_text=re.compile(r"^C 0\.1\.0"))).to_have_count(1, timeout=120_000)
    page.screenshot(path=str(ARTIFACTS / "modules-numbered.png"))
    page.get_by_role("tab", name="Monitor").click()  # the ID each board was lent to wiggle is not a lost module
    expect(page.get_by_text(re.compile(r"`?m2`? live"))).to_be_visible(timeout=30_000)
    time.sleep(6)  # past a heartbeat's loss: a node the roster kept would show LOST by now
    expect(page.get_by_text(re.compile(r"m199"))).to_have_count(0)
    page.get_by_role("tab", name="Modules").click()
    deploy_and_start(page, 8)  # the caterpillar onto the numbered boards and the Python modules
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_the_list_says_none_for_a_module_without_an_id_and_names_a_shared_one() -> None:
    from web.numbering_panel import modules_markdown

    table = modules_markdown([{"serial": "aa" * 12, "id": 0}, {"serial": "bb" * 12, "id": 3},
                              {"serial": "cc" * 12, "id": 3}], {"3": ["bb" * 12, "cc" * 12]})  # fmt: skip
    assert f"| `{'aa' * 12}` | none |" in table and f"| `{'bb' * 12}` | 3 |" in table
    assert f"⚠ node ID 3 is held by 2 modules: {'bb' * 12}, {'cc' * 12}" in table
    assert "No module answers" in modules_markdown([], {})
