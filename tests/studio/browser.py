"""What the browser tests share: Debian's Chromium (never one a tool downloads), the page opened the way a user
opens it, and readers of what it shows (pixels of a drawn line, the robot in the 3D view, a number in a text).

The browser test modules are one xdist group, ``browser``, under `make test`'s three workers, and two, ``browser-a``
and ``browser-b`` (:data:`SECOND_CHROMIUM`), from four workers on: one worker per group runs them one after another
from the start (a group is scheduled before single tests), one Chromium per group at a time, while the other workers
run the rest of the suite beside them. Spread over the workers
(a group per module; or no group at all, as under pytest 9.2, whose test IDs pytest-xdist 3.8's groups cannot
rename), the browser tests ran last, all workers on Chromiums at once and CPU-bound, after the rest of the suite had
left a core idle waiting on processes; in one group, on one worker, they were the suite's longest pole (485 s of
three workers' 503 s; docs/benchmarks.md, "The suite's time")."""

from __future__ import annotations

import os
import re
import time
from collections.abc import Callable
from typing import Any

import pytest

from ..helpers import ARTIFACTS, wait_until

CHROMIUM = "/usr/bin/chromium"


SECOND_CHROMIUM = frozenset({
    "test_drive_e2e", "test_estop_reach_e2e", "test_numbering_page", "test_page_frames", "test_record_page",
    "test_replay_export_page", "test_rough_edges_page", "test_tune_e2e",
})  # fmt: skip
"""The browser test modules of group ``browser-b``; every other one is in ``browser-a``. Chosen by their times in a
three-worker run (longest first, each to the group with less so far): 240 s here, 245 s in the other. A new module
joins ``browser-a`` unless named here."""


def browser_group(module: str, workers: int | None = None) -> str:
    """The xdist group of the browser test module ``module`` (its dotted name) when ``workers`` run the suite (by
    default pytest-xdist's count in this worker): two groups from four workers on, else one (two Chromiums beside
    two workers left no worker for the rest)."""
    if workers is None:
        workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT") or 0)
    if workers < 4:
        return "browser"
    return "browser-b" if module.rsplit(".", 1)[-1] in SECOND_CHROMIUM else "browser-a"


def marks(module: str) -> list[pytest.MarkDecorator]:
    """What every browser test module sets as ``pytestmark`` (``marks(__name__)``): its browser group, a generous
    timeout."""
    return [
        pytest.mark.timeout(240),
        pytest.mark.xdist_group(browser_group(module)),
        pytest.mark.skipif(not os.path.exists(CHROMIUM), reason="needs Debian's chromium (make test installs it)"),
    ]


VIEW_DPR = 0.25
"""The 3D view's canvas at half resolution (viser's ``fixedDpr``; the panels stay sharp): Chromium draws WebGL in
software here, and a full-resolution canvas took most of a core of the two the suite has. viser's adaptive DPR
would lower it on its own on a slow machine; fixing it keeps the screenshots the same from run to run."""


MAX_FPS = 20
"""The page's frames capped at 20 a second (web/page_script.py's ``?maxFps``; the studios the tests start draw no
more, ``--max-fps``): a moving robot kept Chromium drawing at 60 frames a second in software, about a core of the
suite's two, whatever the test looked at."""
PAGE_QUERY = f"?fixedDpr={VIEW_DPR}&maxFps={MAX_FPS}"
"""What every browser test opens the page with (after the studio's URL)."""


PAGE_POLL = 0.05
"""Seconds between two looks of :func:`page_until`. Each look that reads the page is a round trip from the test
through Playwright's driver to Chromium's renderer; wait_until's 2 ms kept all three busy: test_drive_e2e's renderer
took 14.9 CPU-s at 2 ms, 5.4-9.2 at 50 ms, in runs of ~29 s (docs/benchmarks.md, "The suite's time")."""


def page_until(predicate: Callable[[], object], timeout: float = 5.0, interval: float = PAGE_POLL) -> bool:
    """wait_until for the browser tests: the same generous deadline, a look every PAGE_POLL seconds unless told (a
    person reading the page sees nothing faster than that)."""
    return wait_until(predicate, timeout, interval=interval)


def plot(page, title: str):
    """The plot titled ``title`` (a uPlot). The studio replaces a plot whose series change by adding the new one
    before removing the old (web/monitor.py), so for a moment the page holds both, and a locator of the title alone
    broke Playwright's strictness (test_record_page, 1 run of 2): the last one is the newest."""
    return page.locator(".uplot", has_text=title).last


VIEWPORT = {"width": 1400, "height": 900}
"""The page's size in the browser tests unless a test chooses one."""


def open_page(chromium, url: str, viewport: dict[str, int] | None = None):
    """The studio's page in a browser context of its own on ``chromium`` (the ``chromium`` fixture), once the page is
    up (its E-STOP shows): (context, page). The context is what the test closes; a second tab of the same user is
    ``context.new_page()``."""
    from playwright.sync_api import expect

    context = chromium.new_context(viewport=viewport or VIEWPORT)
    page = context.new_page()
    page.goto(f"{url}/{PAGE_QUERY}")
    # generous: the suite's other worker may hold a core while Chromium builds the page in software WebGL
    expect(page.get_by_role("button", name=re.compile(r"^E-STOP"))).to_be_visible(timeout=60_000)
    return context, page


FOCUS_3D = (650, 200)
"""A point of the 3D view clear of the side panel, the toast and the plots panel over its lower left: a click there
gives the 3D view the focus (a click on a plot's legend would hide a series)."""
LINE_COLOR = (0x1F, 0x77, 0xB4)
"""The first series' colour in the page's plots (web.monitor.PALETTE)."""


def pixels(png: bytes, rgb: tuple[int, int, int], tolerance: int = 40) -> int:
    """How many pixels of a screenshot are close to ``rgb`` (a drawn line, not just moving axis labels)."""
    import io

    import numpy as np
    from PIL import Image

    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)
    return int((np.abs(image - np.array(rgb)).sum(axis=2) < tolerance).sum())


def robot_point(png: bytes, right_edge: int = 950) -> tuple[int, int]:
    """A pixel well inside the preview's robot (its modules are tan: red well above blue) left of the side panel,
    clear of the plots panel over the lower left (its orange line is not the robot): of the pixels whose 9×9
    neighbourhood is all robot — not an edge, a gap of the wave or a module's label — the one nearest the middle."""
    import io

    import numpy as np
    from PIL import Image

    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)[:, :right_edge]
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    robot = (r - b > 70) & (r > g) & (g > b) & (r > 90)
    robot[:150] = False  # the page's notification toasts
    height = robot.shape[0]
    robot[height - 12 - 360 :, :600] = False  # the plots panel
    inner = robot.copy()
    for dy in range(-4, 5):
        for dx in range(-4, 5):
            inner &= np.roll(np.roll(robot, dy, axis=0), dx, axis=1)
    ys, xs = np.nonzero(inner if inner.any() else robot)
    if not len(xs):
        raise AssertionError("no robot in the screenshot")
    k = int(np.argmin((xs - xs.mean()) ** 2 + (ys - ys.mean()) ** 2))
    return int(xs[k]), int(ys[k])


class PoseWatch:
    """The robot's pose feed as a viewer receives it: how far its first body moved across the frames kept."""

    def __init__(self, client) -> None:
        import threading

        from asm_module.feed import decode_poses, poses_key

        self._lock = threading.Lock()
        self._points: list = []
        self._times: list[float] = []
        self._decode = decode_poses
        self._sub = client.transport.session.declare_subscriber(poses_key("robot"), self._on)

    def _on(self, sample) -> None:
        frame = self._decode(sample.payload.to_bytes())
        with self._lock:
            self._points.append(frame.positions[0].copy())
            self._times.append(frame.time)
            del self._points[:-120], self._times[:-120]

    def spread(self) -> float:
        import numpy as np

        with self._lock:
            points = np.array(self._points[-60:])
        return float(np.ptp(points, axis=0).max()) if len(points) > 1 else 0.0

    def count(self) -> int:
        with self._lock:
            return len(self._points)

    def seconds(self) -> float:
        """Simulated time the frames of ``spread`` span (a robot at rest sends a frame every 0.5 s, not 60 a
        second: server/rest.py)."""
        with self._lock:
            times = self._times[-60:]
        return times[-1] - times[0] if len(times) > 1 else 0.0

    def clear(self) -> None:
        with self._lock:
            self._points.clear()
            self._times.clear()

    def close(self) -> None:
        self._sub.undeclare()


def text_input(page, label: str):
    """viser's text inputs carry a label whose ``for`` names no element (its number inputs are fine): the input in
    the nearest enclosing row of the label instead."""
    row = page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::*[.//input or .//textarea][1]")
    return row.locator("input, textarea").first


def type_and_set(page, name: str, label: str, text: str):
    """In the attribute browser: choose object ``name``, type ``text`` into its input, press Set; the input."""
    from playwright.sync_api import expect

    page.get_by_label("Object").click()
    page.get_by_role("option", name=name, exact=True).click()
    field = page.get_by_label(label)
    expect(field).to_be_visible(timeout=15_000)
    field.fill(text)
    field.press("Enter")
    page.get_by_role("button", name="Set").click()
    return field


def number(text: str, pattern: str) -> float:
    match = re.search(pattern, text)
    assert match, f"{pattern!r} not in {text[:500]!r}"
    return float(match.group(1))


def deploy_log(page) -> list[str]:
    """The deploy log's lines and any warning or error the page shows: what a failed deploy step reports."""
    text = page.inner_text("body").splitlines()
    return [t for t in text if any(k in t for k in ("⚠", "Error", "deploy", "staged", "Staged", "robot", "started"))]


def press_start(page, timeout_ms: float = 30_000) -> None:
    """Press Start in the question a deploy asks; if none comes, fail saying what the page said instead."""
    from playwright.sync_api import Error

    try:
        page.get_by_role("button", name="Start", exact=True).click(timeout=timeout_ms)
    except Error as exc:
        page.screenshot(path=str(ARTIFACTS / "no-start.png"))
        raise AssertionError(f"no Start was asked; the page said {deploy_log(page)[-25:]}") from exc


def deploy_and_start(page, modules: int, start_timeout_ms: float = 60_000) -> None:
    """Deploy the edited gait from the Deploy tab, press Start in the question that follows, and wait until every
    module is confirmed running — as a user does it."""
    from playwright.sync_api import expect

    page.get_by_role("tab", name="Deploy").click()
    page.get_by_role("button", name="Deploy", exact=True).click()
    press_start(page, start_timeout_ms)
    expect(page.get_by_text(f"{modules} modules confirmed running", exact=False).first).to_be_visible(timeout=60_000)


def once_more(act: Callable[[], None], check: Callable[[], None], say: Callable[[], str]) -> None:
    """``act``, then ``check``; should the check fail (an AssertionError), say why (``say()``), then ``act`` and
    ``check`` once more. Under a fresh clone's load a click or a key was now and then lost on its way to the page;
    a user tries again, and so do the tests that use this — once, saying so, never more."""
    act()
    try:
        check()
    except AssertionError:
        print(say())
        act()
        check()


def click_until_shown(page, button, shown, timeout_ms: float = 30_000) -> None:
    """Click ``button`` until ``shown`` is visible (at most twice). Under CI's load a click was once lost: the
    layout moved between Playwright's stability check and the mouse events (the page rewrites the rows above as
    the robot reports), and nothing reached the server; a user clicks again, and so does this (saying so)."""
    from playwright.sync_api import expect

    def say() -> str:
        return f"click_until_shown: nothing came of the first click; clicking again ({deploy_log(page)[-3:]})"

    once_more(button.click, lambda: expect(shown).to_be_visible(timeout=timeout_ms / 2), say)


def choose(page, label: str, name: str, timeout_ms: float = 20_000) -> None:
    """Pick option ``name`` of the select labelled ``label`` and wait until the select shows it. Under a fresh
    clone's suite a click on an option was lost while the page re-drew the select's options (List files answered
    just then): the list stayed open over the buttons below and the next click hit it. A user picks again; so does
    this, once, saying so."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout
    from playwright.sync_api import expect

    select = page.get_by_label(label, exact=True)
    option = page.get_by_role("option", name=name, exact=True)

    def chosen() -> None:
        if not option.is_visible():
            select.click()
        try:
            option.click(timeout=timeout_ms / 2)
        except PlaywrightTimeout as exc:  # the list closed (re-drawn) between the two clicks: the option never showed
            # (test_plots_time_base's "Live plot 2" after a Clear, once under load: 30 s, then a failure; stop 49)
            raise AssertionError(f"option {name!r} not shown: {exc.message.splitlines()[0]}") from exc
        expect(select).to_have_value(name, timeout=timeout_ms / 2)

    try:
        chosen()
    except AssertionError as exc:
        print(f"choose: {label!r} does not show {name!r} after a click on it ({exc}); choosing again")
        chosen()


def fresh_screenshot(find: Callable[[], Any], timeout: float = 30.0) -> bytes:
    """A screenshot of the element ``find()`` locates, found anew at each try: the page re-creates some elements
    between a test finding one and shooting it (a plot drawn anew with new series; under a fresh clone's suite, the
    canvas of an empty plot was detached mid-screenshot in 2 of 4 runs)."""
    from playwright.sync_api import Error as PlaywrightError

    deadline = time.monotonic() + timeout
    while True:
        try:
            element = find()
            element.scroll_into_view_if_needed(timeout=3_000)
            return element.screenshot(timeout=3_000)
        except PlaywrightError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)
