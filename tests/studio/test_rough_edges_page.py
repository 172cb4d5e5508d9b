"""More of the page's rough edges (issue 29), each reproduced in Chromium by clicks and keys: the states-over-time
view of an event-driven or one-shot gait in place of a blank control table; double-click selecting a number; a
click on a state's cell selecting that state; the Monitor listing a module's objects by itself; a joint-limit error
going with the next successful Set; the layout coming back after the studio restarts."""

from __future__ import annotations

import io
import re
import time

import numpy as np

from ..helpers import ARTIFACTS
from .browser import choose, marks, open_page, page_until, plot

pytestmark = marks(__name__)


def _image(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)


def _count(image: np.ndarray, rgb: np.ndarray, tolerance: int = 12) -> int:
    return int((np.abs(image - np.array(rgb)).sum(axis=2) < tolerance).sum())


def test_a_one_shot_gait_shows_its_states_over_time_and_where_it_ended(start_studio, chromium):
    """curl_into_loop (one-shot, four states): the Control table tab showed a blank table; it shows each module's
    state over the preview's run, in the states' colours, grey once the program ended and a black line there."""
    from playwright.sync_api import expect

    from web.state_timeline import STOPPED, state_colour

    url, _, log = start_studio("--gait", "gaits/library/curl_into_loop.toml")
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Preview").click()
    page.get_by_role("button", name="Reset", exact=True).click()
    page.get_by_role("tab", name="Control table").click()
    expect(page.get_by_text("States over time", exact=False)).to_be_visible(timeout=30_000)
    caption = page.get_by_text("States over time", exact=False)
    expect(caption).to_contain_text(re.compile(r"ended\*{0,2} at t = 5\.\d\d s"), timeout=90_000)
    picture = page.locator("img").filter(has_not=page.locator("svg")).last
    expect(picture).to_be_visible()
    # the grey after the end grows as the preview runs on: the caption says "ended" as soon as it has (a picture
    # taken at once, at t = 5.6 s, held 4 grey pixels), so the picture is taken again until it shows some
    deadline = time.monotonic() + 30
    while True:
        shot = picture.screenshot()
        image = _image(shot)
        if _count(image, STOPPED) > 100 or time.monotonic() > deadline:
            break
        time.sleep(0.5)
    (ARTIFACTS / "rough-states-over-time.png").write_bytes(shot)
    page.screenshot(path=str(ARTIFACTS / "rough-states-over-time-page.png"))
    colours = [state_colour(k) for k in range(4)]
    counts = [_count(image, c) for c in colours]
    assert all(n > 100 for n in counts), counts  # all four states drawn
    assert _count(image, STOPPED) > 100  # grey after the end
    assert int((image.max(axis=2) < 60).sum()) > 50  # the black line where it ended (scaled: near black)
    expect(page.locator("div", has_text=re.compile(r"^S1S2S3S4not running$")).last).to_be_visible()
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def _slider_box(page, label: str):
    """The number box beside a viser slider (the slider's own label names the slider)."""
    row = page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::*[.//input[@inputmode]][1]")
    return row.locator("input.mantine-NumberInput-input")


SELECTED = "el => el.value.substring(el.selectionStart, el.selectionEnd)"


def test_a_double_click_selects_the_number_and_a_click_on_a_state_selects_it(studio_process, chromium):
    """A double-click in a number field holding -33.5 selected "33.5" (the browser's word), so typing over it kept
    the minus; clicking a state's row in the grid, or its cell in the states table, did not select the state."""
    from playwright.sync_api import expect

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Gait").click()
    angle = page.get_by_label("Angle (deg)", exact=True)
    expect(angle).to_be_visible(timeout=15_000)
    angle.click()
    angle.press("Control+a")
    angle.press_sequentially("-33.5")
    angle.press("Tab")
    expect(page.get_by_text("wave S1 (°, s)", exact=True)).to_be_visible()
    expect(angle).to_have_value("-33.5", timeout=15_000)
    angle.dblclick()
    assert angle.evaluate(SELECTED) == "-33.5"
    angle.press_sequentially("12")  # typed over the whole number
    angle.press("Tab")
    expect(angle).to_have_value("12", timeout=15_000)
    state = _slider_box(page, "State")
    expect(state).to_have_value("1")
    page.get_by_text("wave S5 (°, s)", exact=True).click()  # a row of the state grid
    expect(state).to_have_value("5", timeout=15_000)
    expect(angle).to_have_value(re.compile(r"^46\.(19|2)"), timeout=15_000)
    page.locator('[data-asm-state="wave:8"]').click()  # S9's cell in the states table
    expect(state).to_have_value("9", timeout=15_000)
    expect(angle).to_have_value(re.compile(r"^-19\.1"), timeout=15_000)
    expect(page.locator('[data-asm-state="wave:8"]')).to_have_attribute("style", re.compile("background"))
    grid_input = page.get_by_label("wave S3 (°, s)").first  # a click into a row's input selects it too
    grid_input.click()
    expect(state).to_have_value("3", timeout=15_000)
    expect(page.get_by_label("Clicked state")).to_be_hidden()  # the script's field is not shown
    page.screenshot(path=str(ARTIFACTS / "rough-click-selects-state.png"))
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_the_monitor_lists_a_module_s_objects_by_itself(studio_process, chromium):
    """The Monitor's object list showed "-" until List was pressed: it lists the first module's objects once the
    robot is up, another module's when it is chosen, and again after a deploy restarted the robot."""
    from playwright.sync_api import expect

    from .browser import deploy_and_start

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Monitor").click()
    objects = page.get_by_label("Object")
    expect(objects).to_have_value("joint.goal", timeout=60_000)  # m1's first object, no List pressed
    expect(page.get_by_text("gait.state", exact=False).first).to_be_visible()
    choose(page, "Node", "m3")
    expect(page.get_by_label("joint.goal (float32)")).to_be_visible(timeout=30_000)  # m3's, its input shown
    deploy_and_start(page, 8)
    page.get_by_role("tab", name="Monitor").click()
    expect(objects).to_have_value("joint.goal", timeout=60_000)
    expect(page.get_by_label("joint.goal (float32)")).to_be_visible(timeout=30_000)
    page.screenshot(path=str(ARTIFACTS / "rough-monitor-lists.png"))
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_a_refused_set_s_error_goes_when_a_set_succeeds_and_stays_gone_after_a_reload(studio_process, chromium):
    """joint.limits of (-200, 90) is refused by the module; the error stayed in the status line after a successful
    Set, and after a reload."""
    from playwright.sync_api import expect

    from .browser import PAGE_QUERY, type_and_set

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Monitor").click()
    choose(page, "Node", "m2")
    type_and_set(page, "joint.limits", "joint.limits (float32[2])", "-200")
    error = page.get_by_text("joint limits must satisfy", exact=False)
    expect(error.first).to_be_visible(timeout=15_000)
    page.screenshot(path=str(ARTIFACTS / "rough-limit-refused.png"))
    type_and_set(page, "joint.limits", "joint.limits (float32[2])", "-45")
    expect(page.get_by_text("set to", exact=False).first).to_be_visible(timeout=15_000)
    expect(error).to_have_count(0, timeout=15_000)
    page.goto(f"{url}/{PAGE_QUERY}")
    expect(page.get_by_role("button", name=re.compile(r"^E-STOP"))).to_be_visible(timeout=60_000)
    page.get_by_role("tab", name="Monitor").click()
    expect(page.get_by_label("Node")).to_be_visible(timeout=15_000)
    expect(page.get_by_text("set to", exact=False).first).to_be_visible(timeout=15_000)
    expect(error).to_have_count(0, timeout=15_000)
    page.screenshot(path=str(ARTIFACTS / "rough-limit-cleared.png"))
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_the_layout_comes_back_after_the_studio_restarts(tmp_path, chromium):
    """m3's joint.angle plotted into Live plot 2 with a 60 s window; the studio process stopped and started again
    (the same recordings directory): the page shows the same plots and window without a Load layout."""
    import json

    from playwright.sync_api import expect

    from ..processes import Process
    from ..transports import free_port

    layout_file = tmp_path / "studio-layout.json"
    started: list[Process] = []

    def start() -> str:
        port = free_port()
        proc = Process("-m", "server.studio", "--port", str(port), "--zenoh-listen",
                       f"tcp/127.0.0.1:{free_port()}", "--recordings", str(tmp_path))  # fmt: skip
        started.append(proc)
        proc.wait_for_line("READY studio", timeout=60)
        return f"http://127.0.0.1:{port}"

    try:
        url = start()
        browser, page = open_page(chromium, url)
        page.get_by_role("tab", name="Monitor").click()
        choose(page, "Node", "m3")
        choose(page, "Object", "joint.angle")
        choose(page, "Plot into", "Live plot 2")
        page.get_by_role("button", name="Plot", exact=True).click()
        choose(page, "Window (s)", "60")
        expected = {"Live plot 1": [], "Live plot 2": ["m3/joint.angle"]}

        def kept() -> bool:
            try:
                saved = json.loads(layout_file.read_text())
            except (OSError, ValueError):
                return False
            return saved["plots"] == expected and saved["window"] == 60.0

        assert page_until(kept, timeout=30), layout_file.read_text() if layout_file.exists() else "no file"
        browser.close()
        first = started.pop()
        first.stop()
        assert not any("Traceback" in line for line in first.output), "".join(first.output[-40:])
        url = start()  # the studio again, as after a restart
        browser, page = open_page(chromium, url)
        page.get_by_role("tab", name="Monitor").click()
        expect(page.get_by_label("Window (s)")).to_have_value("60", timeout=30_000)
        expect(page.get_by_text("the last one restored", exact=False).first).to_be_visible(timeout=60_000)
        page.get_by_role("tab", name="Plots").click()
        second = plot(page, "Live 2")
        second.scroll_into_view_if_needed()
        expect(second).to_contain_text("m3 joint.angle", timeout=30_000)
        page.screenshot(path=str(ARTIFACTS / "rough-layout-after-restart.png"))
        browser.close()
        assert json.loads(layout_file.read_text())["plots"] == expected  # still the same layout
        assert not any("Traceback" in line for line in started[0].output), "".join(started[0].output[-40:])
    finally:
        for proc in started:
            proc.stop()
