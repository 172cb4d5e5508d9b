"""The page's rough edges (issue 29), each reproduced in Chromium by clicks and keys: number fields that refuse and
never clamp, validated when the value is committed (Tab, Enter, leaving the field) and not at every keystroke, with
refused values kept out of the undo history; the state slider's range following the gait."""

from __future__ import annotations

import re
import time

from ..helpers import ARTIFACTS
from .browser import choose, deploy_and_start, marks, open_page, page_until

pytestmark = marks(__name__)


def _number(page, label: str):
    return page.get_by_label(label, exact=True)


def _commit(page, field, text: str, *, over: bool = False) -> None:
    """``text`` typed into ``field`` (emptied first, or ``over`` what it holds, selected), then Tab."""
    field.click()
    field.press("Control+a")
    if not over:
        field.press("Backspace")
    if text:
        field.press_sequentially(text, delay=50)
    field.press("Tab")


def test_number_fields_refuse_on_commit_never_clamp_and_keep_refusals_out_of_undo(studio_process, chromium):
    from playwright.sync_api import expect

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Gait").click()
    duration = _number(page, "Duration (s)")
    expect(duration).to_be_visible(timeout=15_000)
    # a negative duration, typed key by key: refused as typed, never made positive
    duration.click()
    duration.press("Control+a")
    duration.press_sequentially("-0.1", delay=250)
    duration.press("Tab")
    expect(page.get_by_text("wave S1 duration", exact=False).first).to_be_visible(timeout=15_000)
    expect(duration).to_have_value("-0.1", timeout=5_000)
    page.screenshot(path=str(ARTIFACTS / "rough-negative-duration.png"))
    # a valid value again: the problem goes; Undo gives back the last valid value, not the refused one
    duration.click()
    duration.press("Control+a")
    duration.press_sequentially("0.07", delay=100)
    duration.press("Tab")
    expect(page.get_by_text("✓ valid", exact=False).first).to_be_visible(timeout=15_000)
    time.sleep(1.2)  # past the typing window: Undo is one step of its own
    page.get_by_role("button", name="Undo").click()
    expect(duration).to_have_value(re.compile(r"^0\.06(25|3)$"), timeout=15_000)
    expect(page.get_by_text("✓ valid", exact=False).first).to_be_visible(timeout=5_000)
    # Phase 1.5 typed slowly: no complaint at "1." (nothing is validated before the value is committed)
    phase = _number(page, "Phase")
    phase.click()
    phase.press("Control+a")
    phase.press_sequentially("1.", delay=200)
    time.sleep(1.5)
    expect(page.get_by_text("module 1 phase", exact=False)).to_have_count(0)
    phase.press_sequentially("5")
    phase.press("Enter")
    expect(page.get_by_text("module 1 phase", exact=False).first).to_be_visible(timeout=15_000)
    expect(phase).to_have_value("1.5")
    page.screenshot(path=str(ARTIFACTS / "rough-phase-on-commit.png"))
    _commit(page, phase, "0.25")
    expect(page.get_by_text("✓ valid", exact=False).first).to_be_visible(timeout=15_000)
    # a review: text the field's formatter made another number ("0,1" 1, "1e400" 1400, "2e-1" -21), or an
    # emptied field that kept its old value, is not sent: marked and said under the field
    _commit(page, duration, "0.08")
    expect(page.get_by_text("✓ valid", exact=False).first).to_be_visible(timeout=15_000)
    time.sleep(1.2)  # past the typing window: the next valid value is an undo step of its own
    refused = page.locator("[data-asm-refused]")
    for text in ("0,1", "1e400", "2e-1", ""):
        _commit(page, duration, text)
        expect(refused).to_have_text(re.compile(r"(is not|was not) (a number|part of a number)"), timeout=5_000)
        assert duration.get_attribute("aria-invalid") == "true"
    page.screenshot(path=str(ARTIFACTS / "rough-not-a-number.png"))
    _commit(page, duration, "0.09", over=True)
    expect(refused).to_have_count(0, timeout=5_000)
    expect(page.get_by_text("✓ valid", exact=False).first).to_be_visible(timeout=15_000)
    time.sleep(1.2)
    page.get_by_role("button", name="Undo").click()
    expect(duration).to_have_value(re.compile(r"^0\.08$"), timeout=15_000)  # nothing the refusals sent between
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_status_lines_follow_the_modules_after_an_estop(studio_process, chromium):
    """Deploy, drive forward (confirmed), E-STOP: Drive no longer says "confirmed by 8 of 8", and a deploy while
    every module is latched is refused naming all of them, not module 1 alone."""
    from playwright.sync_api import expect

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    deploy_and_start(page, 8)
    page.get_by_role("tab", name="Drive").click()
    page.get_by_role("button", name="▲ Forward").click()
    confirmed = page.get_by_text(re.compile(r"Robot: forward, confirmed by 8 of 8"))
    expect(confirmed).to_be_visible(timeout=30_000)
    page.get_by_role("button", name=re.compile(r"^E-STOP")).click()
    expect(page.get_by_role("button", name="E-STOP — LATCHED on 8 modules")).to_be_visible(timeout=15_000)
    expect(confirmed).to_have_count(0, timeout=15_000)
    expect(page.get_by_text("Robot: stopped, E-STOP latched on 8 modules", exact=False)).to_be_visible()
    page.screenshot(path=str(ARTIFACTS / "rough-drive-after-estop.png"))
    page.get_by_role("tab", name="Deploy").click()
    page.get_by_role("button", name="Deploy", exact=True).click()
    every = ", ".join(f"module {k} \\(m{k}\\)" for k in range(1, 9))
    expect(page.get_by_text(re.compile(f"emergency stop is latched on {every};")).first).to_be_visible(timeout=30_000)
    page.screenshot(path=str(ARTIFACTS / "rough-deploy-refusal.png"))
    # released: Drive no longer says latched (a review found it did, 15 s after "released on 8 of 8")
    page.get_by_role("button", name="Release e-stop").click()
    page.get_by_role("button", name="Yes, release").click()
    expect(page.get_by_text("released on 8 of 8 modules", exact=False).first).to_be_visible(timeout=20_000)
    page.get_by_role("tab", name="Drive").click()
    expect(page.get_by_text("Robot: stopped, e-stop released", exact=False)).to_be_visible(timeout=15_000)
    expect(page.get_by_text("Robot: stopped, E-STOP latched", exact=False)).to_have_count(0)
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_the_state_slider_follows_the_gait_and_an_error_line_goes_when_the_gait_is_valid(studio_process, chromium):
    """State 8 of the caterpillar selected, then curl_into_loop (4 states) opened: the slider shows a state of the
    new gait, not "State 8" on a 4-state slider. A refused robot size's error line goes with the next valid edit."""
    from playwright.sync_api import expect

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Gait").click()
    row = page.locator("xpath=//label[normalize-space()='State']/ancestor::*[.//input[@inputmode]][1]")
    state = row.locator("input.mantine-NumberInput-input")  # the number box beside the slider
    state.click()
    state.press("Control+a")
    state.press_sequentially("8")
    state.press("Tab")
    expect(_number(page, "Duration (s)")).to_have_value(re.compile(r"^0\.06"), timeout=15_000)
    expect(state).to_have_value("8", timeout=15_000)
    choose(page, "Library", "curl_into_loop")
    page.get_by_role("button", name="Open from library").click()
    expect(page.get_by_text("✓ valid (curl_into_loop)", exact=False)).to_be_visible(timeout=15_000)
    expect(state).to_have_value("4", timeout=15_000)  # its last state, the nearest to the one selected
    expect(_number(page, "Angle (deg)")).to_have_value("45", timeout=15_000)
    page.screenshot(path=str(ARTIFACTS / "rough-state-slider.png"))
    modules = _number(page, "Modules")
    modules.click()
    modules.press("Control+a")
    modules.press_sequentially("300")
    modules.press("Tab")
    error = page.locator("p").filter(has_text=re.compile(r"Error: a robot has 1 to \d+ modules, not 300"))
    page.screenshot(path=str(ARTIFACTS / "rough-refused-size.png"))
    expect(error.first).to_be_visible(timeout=15_000)
    angle = _number(page, "Angle (deg)")
    angle.click()
    angle.press("Control+a")
    angle.press_sequentially("40")
    angle.press("Tab")
    expect(page.get_by_text("is valid again", exact=False).first).to_be_visible(timeout=15_000)
    expect(error).to_have_count(0, timeout=15_000)
    expect(modules).to_have_value("8", timeout=15_000)  # the size the document has
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def _slider_box(page, label: str):
    """The number box beside a viser slider (the slider's own label names the slider)."""
    row = page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::*[.//input[@inputmode]][1]")
    return row.locator("input.mantine-NumberInput-input")


def test_the_preview_plays_on_from_a_scrubbed_point_and_stepping_moves_the_frame_box(studio_process, chromium):
    from playwright.sync_api import expect

    from .browser import number

    url, _, log = studio_process

    def seconds(page) -> float:
        return number(page.get_by_text("Preview: t = ", exact=False).first.inner_text(), r"t = ([\d.]+) s")

    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Preview").click()
    frame = _slider_box(page, "Preview timeline (frame)")
    expect(frame).to_be_visible(timeout=15_000)
    assert page_until(lambda: seconds(page) > 6.0, 60, 0.2)
    page.get_by_role("button", name="Pause", exact=True).click()
    time.sleep(0.5)
    paused = int(frame.input_value())
    page.get_by_role("button", name="◀ back").click()
    page.get_by_role("button", name="◀ back").click()
    expect(frame).to_have_value(str(paused - 2), timeout=10_000)  # the frame box follows the steps
    frame.click()
    frame.press("Control+a")
    frame.press_sequentially("60")  # back to t = 1 s
    expect(frame).to_have_value("60", timeout=10_000)  # typed (a loaded machine lags), then committed
    frame.press("Enter")
    if not page_until(lambda: abs(seconds(page) - 1.0) < 0.1, 15, 0.2):
        # once, in a fresh clone's run, the typed frame was not taken in 30 s (the preview stayed where it was
        # paused; not reproduced in 5 runs beside two busy cores): committed again, as stop 40 did for a lost
        # key press. A seek to the same frame is idempotent, so this hides nothing but the lost press.
        frame.click()
        frame.press("Control+a")
        frame.press_sequentially("60")
        frame.press("Enter")
    assert page_until(lambda: abs(seconds(page) - 1.0) < 0.1, 30, 0.2), seconds(page)
    page.get_by_role("button", name="Play", exact=True).click()
    time.sleep(1.0)
    played = seconds(page)
    assert 1.2 < played < paused / 60 - 1.0, (played, paused)  # on from 1 s, not a jump to the newest frame
    assert 60 < int(frame.input_value()) < paused
    page.screenshot(path=str(ARTIFACTS / "rough-replay-from-scrubbed.png"))
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_a_one_shot_gait_says_it_ended(start_studio, chromium):
    """curl_into_loop's one-shot program ends after 5.5 s: the preview says so instead of counting on silently."""
    from playwright.sync_api import expect

    url, _, log = start_studio("--gait", "gaits/library/curl_into_loop.toml")
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Preview").click()
    page.get_by_role("button", name="Reset", exact=True).click()
    ended = page.get_by_text(re.compile(r"ended at t = 5\.\d\d s"))
    expect(page.get_by_text(re.compile(r"Preview: t = [0-4]\.\d\d s"))).to_be_visible(timeout=15_000)
    expect(ended).to_have_count(0)  # restarted: running again
    expect(ended).to_be_visible(timeout=60_000)
    page.screenshot(path=str(ARTIFACTS / "rough-one-shot-ended.png"))
    page.get_by_role("tab", name="Gait").click()
    choose(page, "Library", "caterpillar")
    page.get_by_role("button", name="Open from library").click()  # a periodic gait: it never ends
    page.get_by_role("tab", name="Preview").click()
    expect(page.get_by_text("Preview: t = ", exact=False).first).to_be_visible(timeout=15_000)
    time.sleep(7.0)
    expect(ended).to_have_count(0)
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_two_tabs_editing_one_gait_are_told(studio_process, chromium):
    """An edit in tab 2 appears in tab 1 (one document) and tab 1 is told it was edited elsewhere; Undo in tab 1
    says it takes back tab 2's edit."""
    from playwright.sync_api import expect

    from .browser import PAGE_QUERY

    url, _, log = studio_process
    browser, first = open_page(chromium, url)
    second = browser.new_page()  # a second tab of the same user
    second.goto(f"{url}/{PAGE_QUERY}")
    for page in (first, second):
        page.get_by_role("tab", name="Gait").click()
        expect(_number(page, "Angle (deg)")).to_be_visible(timeout=60_000)
    angle = _number(second, "Angle (deg)")
    angle.click()
    angle.press("Control+a")
    angle.press_sequentially("33")
    angle.press("Tab")
    expect(_number(first, "Angle (deg)")).to_have_value("33", timeout=15_000)
    expect(first.get_by_text("edited in another tab", exact=False).first).to_be_visible(timeout=15_000)
    expect(second.get_by_text("edited in another tab", exact=False)).to_have_count(0)
    first.screenshot(path=str(ARTIFACTS / "rough-edited-elsewhere.png"))
    first.get_by_role("button", name="Undo").click()
    expect(first.get_by_text("Undo took back an edit made in another tab", exact=False).first).to_be_visible(
        timeout=15_000
    )
    expect(_number(second, "Angle (deg)")).to_have_value("19.134", timeout=15_000)  # the gait's, not rounded
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_the_robot_leaves_a_trail_and_shows_its_heading(studio_process, chromium):
    """The preview's robot draws where it went (green) and the way it goes (magenta); the live robot too once it
    is shown (Live after a deploy)."""

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Preview").click()
    page.get_by_role("button", name="Reset", exact=True).click()
    view = {"x": 0, "y": 0, "width": 1000, "height": 540}  # the 3D view above the plots panel
    assert page_until(lambda: _hue(page.screenshot(clip=view), "green") > 20, 60, 0.5)
    assert page_until(lambda: _hue(page.screenshot(clip=view), "magenta") > 10, 30, 0.5)
    page.screenshot(path=str(ARTIFACTS / "rough-trail-preview.png"))
    page.get_by_role("tab", name="Deploy").click()
    page.get_by_role("button", name="Deploy", exact=True).click()
    page.get_by_role("button", name="Start", exact=True).click()
    assert page_until(lambda: _hue(page.screenshot(clip=view), "blue") > 200, 60, 0.5)  # Live
    assert page_until(lambda: _hue(page.screenshot(clip=view), "green") > 20, 60, 0.5)
    assert page_until(lambda: _hue(page.screenshot(clip=view), "magenta") > 10, 30, 0.5)
    page.screenshot(path=str(ARTIFACTS / "rough-trail-live.png"))
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def _hue(png: bytes, name: str) -> int:
    """Pixels of a screenshot clearly of one hue (the view tone-maps colours: the trail's (40, 170, 60) shows as
    (7..130, 190..220, 7..130), the arrow's (210, 30, 200) as (234, 107, 222), the live robot's blue as blue)."""
    import io

    import numpy as np
    from PIL import Image

    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    mask = {"green": (g - r > 60) & (g - b > 40), "magenta": (r - g > 100) & (b - g > 100),
            "blue": (b - r > 80) & (b > g)}[name]  # fmt: skip
    return int(mask.sum())
