"""Number fields take what was typed, whole: viser's number inputs round typed text to a display precision it derives
from the field's step (``step=1``: none), so 2.5 typed into Node ID was sent as 2 (an ID the user never typed), an
integer attribute of 2.5 was written as 2, and an angle of 12.25 (step 0.5) became 12.3. Every number field of the
page now keeps the digits typed (web/inputs.py's ``precise``): a whole-number field refuses a fraction, naming
itself, and a float field takes the value exactly."""

from __future__ import annotations

import re
import tomllib

from asm_py import Node
from asm_py.transport.zenoh import ZenohTransport

from ..helpers import ARTIFACTS
from .browser import choose, marks, open_page, page_until

pytestmark = marks(__name__)


def _commit(field, text: str) -> None:
    """``text`` typed key by key into ``field`` (emptied first), then Enter: what a user does."""
    field.click()
    field.press("Control+a")
    field.press("Backspace")
    field.press_sequentially(text, delay=30)
    field.press("Enter")


def test_float_fields_take_the_digits_typed(studio_process, chromium):
    """An angle of 12.25 (step 0.5) and a duration of 0.0725 (step 0.005) are what the gait document holds."""
    from playwright.sync_api import expect

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Gait").click()
    angle = page.get_by_label("Angle (deg)", exact=True)
    expect(angle).to_be_visible(timeout=15_000)
    _commit(angle, "12.25")
    expect(page.locator("td", has_text="12.2°").first).to_be_visible(timeout=15_000)  # the table's 1 decimal
    duration = page.get_by_label("Duration (s)", exact=True)
    _commit(duration, "0.0725")
    expect(angle).to_have_value("12.25", timeout=15_000)
    expect(duration).to_have_value("0.0725", timeout=15_000)
    expect(page.get_by_label("wave S1 (°, s)")).to_have_value("12.25", timeout=15_000)  # the grid row too
    with page.expect_download() as download:
        page.get_by_role("button", name="Download .toml").click()
    gait = tomllib.loads(download.value.path().read_text(encoding="utf-8"))
    first = next(iter(gait["automata"].values()))["states"][0]
    assert (first["angle"], first["duration"]) == (12.25, 0.0725), first
    # more decimals than a field takes: refused under the field, never rounded into the document
    _commit(angle, "12.1234567")
    expect(page.locator("[data-asm-refused]")).to_have_text(re.compile(r"has more than 6 decimal places"),
                                                             timeout=5_000)  # fmt: skip
    page.screenshot(path=str(ARTIFACTS / "precision-gait-fields.png"))
    with page.expect_download() as download:
        page.get_by_role("button", name="Download .toml").click()
    gait = tomllib.loads(download.value.path().read_text(encoding="utf-8"))
    assert next(iter(gait["automata"].values()))["states"][0]["angle"] == 12.25
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_whole_number_fields_refuse_a_fraction_by_name(studio_process, chromium):
    """8.5 robot modules and Node ID 2.5 are refused, naming the field: never taken as 8 or assigned as 2."""
    from playwright.sync_api import expect

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Gait").click()
    modules = page.get_by_label("Modules", exact=True)
    expect(modules).to_be_visible(timeout=15_000)
    _commit(modules, "8.5")
    expect(page.get_by_text("Modules must be a whole number, not 8.5").first).to_be_visible(timeout=15_000)
    expect(modules).to_have_value("8.5")
    with page.expect_download() as download:
        page.get_by_role("button", name="Download .toml").click()
    assert tomllib.loads(download.value.path().read_text(encoding="utf-8"))["robot"]["modules"] == 8
    page.get_by_role("tab", name="Modules").click()
    node_id = page.get_by_label("Node ID", exact=True)
    expect(node_id).to_be_visible(timeout=15_000)
    _commit(node_id, "2.5")
    page.get_by_role("button", name="Assign ID").click()
    expect(page.get_by_text("⚠ a node ID is a whole number 1..253 (0 erases), not 2.5")).to_be_visible(timeout=15_000)
    expect(node_id).to_have_value("2.5")
    page.screenshot(path=str(ARTIFACTS / "precision-node-id.png"))
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_the_attribute_browser_refuses_a_fraction_for_an_integer_attribute(studio_process, chromium):
    """m2's gait.signal (uint8) typed 2.5 is refused and nothing is written (it was written as 2); 7 is written."""
    from playwright.sync_api import expect

    url, endpoint, log = studio_process
    client = Node("precision-client", ZenohTransport(connect=[endpoint]))
    try:
        browser, page = open_page(chromium, url)
        before = client.lookup("m2", "gait.signal", timeout=5).get()
        page.get_by_role("tab", name="Monitor").click()
        choose(page, "Node", "m2")
        choose(page, "Object", "gait.signal")
        signal = page.get_by_label("gait.signal (uint8)", exact=True)
        expect(signal).to_be_visible(timeout=15_000)
        _commit(signal, "2.5")
        page.get_by_role("button", name="Set").click()
        refusal = page.get_by_text(re.compile(r"gait\.signal.? not set: gait\.signal must be a whole number, not 2\.5"))
        expect(refusal.first).to_be_visible(timeout=15_000)
        expect(signal).to_have_value("2.5")
        page.screenshot(path=str(ARTIFACTS / "precision-attribute.png"))
        assert not page_until(lambda: client.lookup("m2", "gait.signal", timeout=5).get() != before, 2, 0.2)
        _commit(signal, "7")  # a whole number is written, as typed
        page.get_by_role("button", name="Set").click()
        expect(page.get_by_text("set to", exact=False).first).to_be_visible(timeout=15_000)
        assert page_until(lambda: client.lookup("m2", "gait.signal", timeout=5).get() == 7, 15, 0.2)
        browser.close()
    finally:
        client.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def _refused(page, box, text: str, pattern: str) -> None:
    """``text`` committed into the number box ``box`` is refused under it, in words matching ``pattern``."""
    from playwright.sync_api import expect

    expect(box).to_be_visible(timeout=15_000)
    _commit(box, text)
    expect(page.locator("[data-asm-refused]").first).to_have_text(re.compile(pattern), timeout=5_000)


def test_a_sliders_box_refuses_more_decimals_than_its_slider_takes(studio_process, chromium):
    """A slider's number box rounded what was typed to its step without a word: 2.5 into State picked state 2, 0.25
    into the preview's Speed ran at 0.3. Refused under the box now, the slider where it was."""
    from playwright.sync_api import expect

    from .test_replay_page import _slider_box

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Gait").click()
    _refused(
        page, _slider_box(page, "State"), "2.5", r"not sent: 2\.5 is not a whole number: State takes whole numbers"
    )
    _commit(_slider_box(page, "State"), "2")  # a whole number goes through: the refusal goes
    expect(page.locator("[data-asm-refused]")).to_have_count(0, timeout=5_000)
    page.get_by_role("tab", name="Preview").click()
    _refused(page, _slider_box(page, "Speed"), "0.25", r"0\.25 has more decimal places than Speed takes \(1\)")
    page.screenshot(path=str(ARTIFACTS / "precision-slider-boxes.png"))
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
