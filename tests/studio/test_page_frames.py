"""``?maxFps=N`` caps the page's animation frames (web/page_script.py), by Chromium against an ``asm-studio``
process: a browser without a GPU draws a moving robot in software, and the cap is what keeps it from taking a
laptop's core."""

from __future__ import annotations

import re
import time

from .browser import VIEW_DPR, marks

pytestmark = marks(__name__)

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


def test_max_fps_caps_the_frames_the_view_still_moves_and_other_values_change_nothing(studio_process, chromium) -> None:
    url, _, log = studio_process
    browser = chromium.new_context(viewport={"width": 1400, "height": 900})
    try:
        page = browser.new_page()
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


def _scene_updates_per_second(url: str, seconds: float) -> float:
    """Windows that move the robot, per second, as a client that keeps up receives them."""
    import viser
    from websockets.sync.client import connect

    from web.viewer_client import camera_message, carries_poses

    ws_url = url.replace("http://", "ws://")
    with connect(ws_url, subprotocols=[f"viser-v{viser.__version__}"], max_size=None, open_timeout=10) as ws:  # type: ignore[list-item]  # viser's subprotocol is a plain string
        ws.send(camera_message())
        end = time.monotonic() + 2.0  # the scene is built, the preview plays on for this client
        while time.monotonic() < end:
            ws.recv(timeout=10)
        received, began = [], time.monotonic()
        while time.monotonic() - began < seconds:
            received.append(ws.recv(timeout=10))
        elapsed = time.monotonic() - began
    return sum(1 for m in received if isinstance(m, bytes) and carries_poses(m)) / elapsed


def test_the_studio_s_max_fps_caps_what_it_sends_and_the_page_s_frames_unless_the_url_says(
    start_studio, chromium
) -> None:
    url, _, log = start_studio("--max-fps", "10")
    rate = _scene_updates_per_second(url, 3.0)
    assert 2 <= rate <= 10 * 1.25, f"{rate:.1f} scene updates a second from a studio at --max-fps 10"
    browser = chromium.new_context(viewport={"width": 1400, "height": 900})
    try:
        page = browser.new_page()
        _open(page, url, "")  # no maxFps in the URL: the studio's
        assert page.evaluate("window.__asmMaxFps") == 10
        assert page.evaluate(COUNT_FRAMES, 2) <= 10 * 1.25
        page.goto(f"{url}/?maxFps=60", wait_until="domcontentloaded")  # the URL's own: no cap for this page
        assert page.evaluate("window.__asmMaxFps") is None
    finally:
        browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_software_webgl_draws_the_view_at_a_lower_resolution_unless_the_url_chooses_one(
    studio_process, chromium
) -> None:
    """Chromium here has no GPU (SwiftShader, as viser's own notice says): the page adds viser's ``fixedDpr`` to its
    URL before viser reads it; a URL that chooses one keeps it; the token and other parameters stay."""

    from web.page_script import SOFTWARE_RENDER_SCALE

    url, _, log = studio_process
    browser = chromium.new_context(viewport={"width": 1280, "height": 800})
    try:
        page = browser.new_page()
        renderer = page.evaluate("""() => { const gl = document.createElement('canvas').getContext('webgl');
            const info = gl.getExtension('WEBGL_debug_renderer_info');
            return gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER); }""")
        assert re.search(r"swiftshader|llvmpipe|software", renderer, re.I), renderer
        _open(page, url, "&maxFps=30")  # fixedDpr given (the tests' own 0.25): kept
        assert page.evaluate("new URLSearchParams(location.search).get('fixedDpr')") == str(VIEW_DPR)
        assert page.evaluate("window.__asmSoftwareScale") is None
        page.goto(f"{url}/?maxFps=30")
        assert page.evaluate("new URLSearchParams(location.search).get('fixedDpr')") == str(SOFTWARE_RENDER_SCALE)
        assert page.evaluate("new URLSearchParams(location.search).get('maxFps')") == "30"
        assert page.evaluate("window.__asmSoftwareScale") == SOFTWARE_RENDER_SCALE
    finally:
        browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
