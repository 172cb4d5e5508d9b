"""More of the page's rough edges (issue 29), each reproduced in Chromium by clicks and keys: the states-over-time
view of an event-driven or one-shot gait in place of a blank control table; double-click selecting a number; a
click on a state's cell selecting that state; the Monitor listing a module's objects by itself; a joint-limit error
going with the next successful Set; the layout coming back after the studio restarts."""

from __future__ import annotations

import io
import re

import numpy as np

from ..helpers import ARTIFACTS
from .browser import marks, open_page

pytestmark = marks(2)


def _image(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)


def _count(image: np.ndarray, rgb: np.ndarray, tolerance: int = 12) -> int:
    return int((np.abs(image - np.array(rgb)).sum(axis=2) < tolerance).sum())


def test_a_one_shot_gait_shows_its_states_over_time_and_where_it_ended(start_studio):
    """curl_into_loop (one-shot, four states): the Control table tab showed a blank table; it shows each module's
    state over the preview's run, in the states' colours, grey once the program ended and a black line there."""
    from playwright.sync_api import expect, sync_playwright

    from web.state_timeline import STOPPED, state_colour

    url, _, log = start_studio("--gait", "gaits/library/curl_into_loop.toml")
    with sync_playwright() as pw:
        browser, page = open_page(pw, url)
        page.get_by_role("tab", name="Preview").click()
        page.get_by_role("button", name="Reset", exact=True).click()
        page.get_by_role("tab", name="Control table").click()
        expect(page.get_by_text("States over time", exact=False)).to_be_visible(timeout=30_000)
        caption = page.get_by_text("States over time", exact=False)
        expect(caption).to_contain_text(re.compile(r"ended\*{0,2} at t = 5\.\d\d s"), timeout=90_000)
        picture = page.locator("img").filter(has_not=page.locator("svg")).last
        expect(picture).to_be_visible()
        shot = picture.screenshot()
        (ARTIFACTS / "rough-states-over-time.png").write_bytes(shot)
        page.screenshot(path=str(ARTIFACTS / "rough-states-over-time-page.png"))
        image = _image(shot)
        colours = [state_colour(k) for k in range(4)]
        counts = [_count(image, c) for c in colours]
        assert all(n > 100 for n in counts), counts  # all four states drawn
        assert _count(image, STOPPED) > 100  # grey after the end
        assert int((image.max(axis=2) < 60).sum()) > 50  # the black line where it ended (scaled: near black)
        expect(page.locator("div", has_text=re.compile(r"^S1S2S3S4not running$")).last).to_be_visible()
        browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
