"""``?maxFps=N`` caps the page's animation frames (web/page_script.py), by Chromium against an ``asm-studio``
process: a browser without a GPU draws a moving robot in software, and the cap is what keeps it from taking a
laptop's core."""

from __future__ import annotations

import re
import time

from .browser import CHROMIUM, VIEW_DPR, marks

pytestmark = marks(2)

COUNT_FRAMES = """async (seconds) => {
  let frames = 0, running = true;
  const tick = () => { frames++; if (running) requestAnimationFrame(tick); };
  requestAnimationFrame(tick);
  await new Promise((done) => setTimeout(done, seconds * 1000));
  running = false;
  return frames / seconds;
}"""


def _open(page, url: str, query: str) -> None:
    from playwright.sync_api import expect

    page.goto(f"{url}/?fixedDpr={VIEW_DPR}{query}")
    expect(page.get_by_role("button", name=re.compile(r"^E-STOP"))).to_be_visible(timeout=60_000)


def test_max_fps_caps_the_frames_the_view_still_moves_and_other_values_change_nothing(studio_process) -> None:
    from playwright.sync_api import sync_playwright

    url, _, log = studio_process
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            _open(page, url, "&maxFps=8")
            assert page.evaluate("window.__asmMaxFps") == 8
            rate = page.evaluate(COUNT_FRAMES, 3)
            assert 1 <= rate <= 8 * 1.25, f"{rate:.1f} frames a second with maxFps=8"
            # the preview plays on: the 3D view is still drawn, only less often
            view = {"x": 300, "y": 120, "width": 500, "height": 400}
            before = page.screenshot(clip=view)
            time.sleep(1.5)
            assert page.screenshot(clip=view) != before, "the 3D view stopped moving under the cap"
            # a cancelled frame never runs (three.js and the panels cancel theirs)
            ran = page.evaluate("""async () => { let ran = false;
                cancelAnimationFrame(requestAnimationFrame(() => { ran = true; }));
                await new Promise((done) => setTimeout(done, 500)); return ran; }""")
            assert ran is False
            for hostile in ("abc", "-3", "60", "1e9", "8&maxFps=abc", ""):
                # the script runs in the page's head, before its bundle: the loaded document is enough to read
                page.goto(f"{url}/?maxFps={hostile}" if hostile else f"{url}/?maxFps", wait_until="domcontentloaded")
                capped = page.evaluate("window.__asmMaxFps")
                # the first of two values is the one URLSearchParams gives: "8&maxFps=abc" caps at 8
                assert capped == (8 if hostile.startswith("8&") else None), (hostile, capped)
        finally:
            browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
