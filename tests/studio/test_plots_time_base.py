"""Live plots that never go blank and share one time base (issue 29), driven in Chromium by clicks: the page's
uPlots are read through viser's own test point (``window.__viserTestpoints.uplots``: each chart's x scale and data)."""

from __future__ import annotations

import time

from ..helpers import ARTIFACTS
from .browser import LINE_COLOR, choose, deploy_and_start, marks, open_page, pixels, plot

pytestmark = marks(__name__)

CHARTS = """() => Object.values((window.__viserTestpoints || {}).uplots || {}).map(({chart}) => ({
  title: chart.root.querySelector('.u-title')?.textContent || '',
  min: chart.scales.x.min, max: chart.scales.x.max,
  first: chart.data[0][0], last: chart.data[0][chart.data[0].length - 1]}))"""


def _live(page) -> dict[str, dict]:
    return {c["title"][:6]: c for c in page.evaluate(CHARTS) if c["title"].startswith("Live ")}


def _plot_into(page, module: str, target: str) -> None:
    choose(page, "Node", module)
    page.get_by_role("button", name="List").click()
    choose(page, "Object", "joint.angle")
    choose(page, "Plot into", target)
    page.get_by_role("button", name="Plot", exact=True).click()


def _choose_window(page, seconds: str) -> None:
    """Pick the plots' window, and see the picker took it before watching the plots (under the suite's load a
    pick once did not reach the page: the plots kept their 10 s window for 30 s)."""
    from playwright.sync_api import expect

    for attempt in range(3):
        page.get_by_label("Window (s)").click()
        page.get_by_role("option", name=seconds, exact=True).click()
        try:
            expect(page.get_by_label("Window (s)")).to_have_value(seconds, timeout=10_000)
            return
        except AssertionError:
            if attempt == 2:
                raise


def _wrong(charts: dict[str, dict], window: float) -> str | None:
    """What is wrong with the two live plots' time base (None: nothing)."""
    if set(charts) != {"Live 1", "Live 2"}:
        return f"not two live plots: {charts}"
    one, two = charts["Live 1"], charts["Live 2"]
    if (one["min"], one["max"]) != (two["min"], two["max"]):
        return f"two time bases: {charts}"
    if (one["min"], one["max"]) != (-window, 0.0):
        return f"not the window ending at now: {charts}"
    for chart in (one, two):
        if not -window <= chart["first"] <= chart["last"] <= 0.0:
            return f"samples outside the window (a blank plot): {charts}"
        if chart["last"] <= -FRESH:
            return f"no recent sample: {charts}"
    return None


FRESH = 5.0
"""Seconds within which the newest sample must be (the line reaches now); generous for the suite's load."""


def _watch(page, window: float, seconds: float) -> list[dict[str, dict]]:
    """Once the page has taken the last change (within 30 s: a loaded machine draws late), every half second for
    ``seconds``: both live plots show the same x range, the window ending at now, and their newest samples inside it
    (a plot whose axis stays behind its samples is blank)."""
    settle = time.monotonic() + 30.0
    while (wrong := _wrong(_live(page), window)) is not None:
        assert time.monotonic() < settle, wrong
        time.sleep(0.5)
    seen = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        charts = _live(page)
        seen.append(charts)
        wrong = _wrong(charts, window)
        assert wrong is None, wrong
        time.sleep(0.5)
    return seen


def test_live_plots_share_one_time_base_and_never_go_blank(studio_process, chromium):
    """m2's then m7's joint.angle into Live plot 2 beside the deploy's angles in Live plot 1: both plots keep the
    same window ending at now, through re-targeting, a Clear, a window change and a redeploy."""
    from playwright.sync_api import expect

    url, _, log = studio_process
    browser, page = open_page(chromium, url)
    deploy_and_start(page, 8)
    page.get_by_role("tab", name="Monitor").click()
    _plot_into(page, "m2", "Live plot 2")
    _watch(page, 10.0, 4.0)
    _plot_into(page, "m7", "Live plot 2")  # re-targeted: a new series on the same plot
    _watch(page, 10.0, 6.0)
    page.get_by_role("button", name="Live plot 2", exact=True).last.click()  # Clear
    _plot_into(page, "m7", "Live plot 2")
    _choose_window(page, "30")
    _watch(page, 30.0, 4.0)
    deploy_and_start(page, 8)  # deployed again: the plots go on on the same clock
    page.get_by_role("tab", name="Monitor").click()
    _plot_into(page, "m7", "Live plot 2")
    _watch(page, 30.0, 4.0)
    page.get_by_role("tab", name="Plots").click()
    second = plot(page, "Live 2").locator("canvas").first
    second.scroll_into_view_if_needed()
    expect(plot(page, "Live 2")).to_contain_text("m7 joint.angle", timeout=15_000)
    assert pixels(second.screenshot(), LINE_COLOR) > 50, "no line in Live plot 2"
    page.screenshot(path=str(ARTIFACTS / "rough-plots-one-time-base.png"))
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
