"""Replaying a recording in the studio (issue 29), by clicks in Chromium: open a recording of the recordings folder,
play it, pause, scrub; the robot is drawn in the 3D view and moves, the replay plot has a line, the events and the
modules' values are listed; Leave replay returns to the live robot. A file that is not a recording is refused on
the page with one line, and the studio lives on.

The recording is written the way the recorder writes one (its file writer and its message encoders) from the
caterpillar simulated here: the real thing is recorded and replayed in tests/server/test_replay_equality.py.
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

from ..helpers import ARTIFACTS
from .browser import choose, marks, number, open_page, page_until, pixels, plot

pytestmark = marks(__name__)


def violet(png: bytes) -> int:
    """Pixels of the replayed robot: violet (web/scene_view.py: SceneView._build), shaded by the lights — apart from the
    green trail, the magenta heading arrow, the grey grid, the tan preview and the blue live robot."""
    import io

    import numpy as np
    from PIL import Image

    image = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=int)
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    return int(((b - g > 30) & (r - g > 15) & (b - r > 15)).sum())  # the arrow: r >= b; the live robot: g > r


VIEW = {"x": 0, "y": 150, "width": 900, "height": 330}
"""The 3D view clear of the toasts above and the plots panel over its lower left."""


def simulated_recording(path: Path, seconds: float = 8.0) -> None:
    """The caterpillar simulated for ``seconds``, written as asm-record writes a run: poses at 60 Hz, every
    module's joint.angle at 20 Hz, a deploy's group message at 1 s and an e-stop at 5 s."""
    from asm_module.feed import PoseFrame
    from gaits.mjcf import build_mjcf
    from gaits.model import LIBRARY, load
    from gaits.sim import Simulation
    from server import foxglove_msgs as fx
    from server.mcap_files import Attachment, McapFiles, RecordingInfo
    from server.record import ATTRIBUTE, ESTOP, GROUP, TRANSFORMS

    gait = load(LIBRARY / "caterpillar.toml")
    mjcf = build_mjcf(gait.robot, name=gait.name)
    sim = Simulation(gait)
    sim.start()
    info = RecordingInfo({"robot": "robot", "modules": "8", "recorder": "test"},
                         [Attachment("robot.mjcf", "application/xml", mjcf.encode())])  # fmt: skip
    files = McapFiles(path, info)
    bodies = fx.bodies(mjcf)
    start = time.time_ns()
    for k in range(int(seconds * 60)):
        sim.advance(1 / 60)
        ns = start + k * 16_666_667
        frame = PoseFrame(k + 1, k / 60, sim.data.xpos[1:].copy(), sim.data.xquat[1:].copy())
        files.write(fx.TOPIC_TRANSFORMS, TRANSFORMS, fx.frame_transforms(frame, bodies, ns).encode(), ns, seq=k + 1)
        if k % 3 == 0:
            for m in range(1, 9):
                view = {"node": f"m{m}", "object": "joint.angle", "seq": k, "t": k / 60, "value": sim.angle(m)}
                files.write(f"/m{m}/joint.angle", ATTRIBUTE, json.dumps(view).encode(), ns + m)
        if k == 60:
            group = {"group": "all", "source": "studio", "kind": 1, "method": 1, "class_id": 1, "object_id": 1,
                     "data": ""}  # fmt: skip
            files.write(fx.TOPIC_GROUP, GROUP, json.dumps(group).encode(), ns + 10)
        if k == 300:
            estop = {"scope": "robot", "source": "studio", "reason": "test"}
            files.write(fx.TOPIC_ESTOP, ESTOP, json.dumps(estop).encode(), ns + 10)
    files.close()


def lines(png: bytes) -> int:
    """Pixels of a plot's lines, in the colours of its first eight series."""
    from web.monitor import PALETTE

    return sum(pixels(png, tuple(int(c[i : i + 2], 16) for i in (1, 3, 5)), 60) for c in PALETTE[:8])  # type: ignore[arg-type]


def _slider_box(page, label: str):
    """The number box beside a viser slider (the slider's own label names the slider)."""
    row = page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::*[.//input[@inputmode]][1]")
    return row.locator("input.mantine-NumberInput-input")


def test_open_a_recording_play_pause_scrub_and_leave(start_studio, tmp_path, chromium):
    from playwright.sync_api import expect

    simulated_recording(tmp_path / "caterpillar-run.mcap")
    (tmp_path / "not-a-recording.mcap").write_text("a text file named .mcap\n")
    whole = (tmp_path / "caterpillar-run.mcap").read_bytes()
    upload = tmp_path / "upload" / "killed.mcap"  # a recorder killed mid-write: no summary, cut mid-chunk
    upload.parent.mkdir()
    upload.write_bytes(whole[: len(whole) // 2])
    url, _, log = start_studio("--recordings", str(tmp_path))

    def replay_time(page) -> float:
        return number(page.get_by_text(re.compile(r"t = [\d.]+ s of")).first.inner_text(), r"t = ([\d.]+) s of")

    browser, page = open_page(chromium, url)
    assert violet(page.screenshot(clip=VIEW)) < 50  # the preview: a tan robot
    page.get_by_role("tab", name="Replay").click()
    page.get_by_role("button", name="List files").click()
    # hostile first: a file that is not MCAP is refused with a line, nothing else changes
    choose(page, "Recording", "not-a-recording.mcap")
    page.get_by_role("button", name="Open", exact=True).click()
    refused = page.get_by_text("Not opened: not-a-recording.mcap is not an MCAP file", exact=False)
    expect(refused.first).to_be_visible(timeout=20_000)
    with page.expect_file_chooser() as chooser:  # uploaded: read tolerantly, up to its last whole chunk
        page.get_by_role("button", name="Upload an MCAP file").click()
    chooser.value.set_files(str(upload))
    expect(page.get_by_text("replayed up to its last whole chunk", exact=False).first).to_be_visible(timeout=30_000)
    expect(page.get_by_text("Showing: Replay of killed.mcap", exact=False).first).to_be_visible(timeout=15_000)
    choose(page, "Recording", "caterpillar-run.mcap")
    page.get_by_role("button", name="Open", exact=True).click()
    expect(page.get_by_text(re.compile(r"caterpillar-run\.mcap: 7\.\d\d s, 480 poses")).first).to_be_visible(
        timeout=30_000
    )
    expect(page.get_by_text("Showing: Replay of caterpillar-run.mcap", exact=False).first).to_be_visible(timeout=15_000)
    expect(page.get_by_text("group message to all from studio", exact=False).first).to_be_visible()
    expect(page.get_by_text("E-STOP (robot) by studio: test", exact=False).first).to_be_visible()
    marks = page.locator(".mantine-Slider-markLabel")  # the events on the timeline: G at 1 s, E at 5 s
    expect(marks.filter(has_text=re.compile(r"^E$"))).to_have_count(1, timeout=15_000)
    expect(marks.filter(has_text=re.compile(r"^G$"))).to_have_count(1)
    # the robot is drawn (violet), at t = 0, paused
    if not page_until(lambda: violet(page.screenshot(clip=VIEW)) > 500, 60, 0.5):
        page.screenshot(path=str(ARTIFACTS / "replay-no-robot.png"))
        raise AssertionError("no robot drawn")
    assert replay_time(page) == 0.0
    still = page.screenshot(clip=VIEW)
    page.get_by_role("button", name="▶ Play").click()
    assert page_until(lambda: replay_time(page) > 2.0, 30, 0.2), replay_time(page)
    page.get_by_role("button", name="Pause", exact=True).click()
    expect(page.get_by_text("· paused ·", exact=False).first).to_be_visible(timeout=10_000)
    paused = replay_time(page)
    time.sleep(1.0)
    assert replay_time(page) == paused  # paused: time stands
    moved = page.screenshot(clip=VIEW)
    assert violet(moved) > 500
    assert moved != still, "the replayed robot did not move"
    replayed = plot(page, "Replay: recorded values")
    expect(replayed).to_contain_text("m1 joint.angle", timeout=15_000)
    if not page_until(lambda: lines(replayed.locator("canvas").first.screenshot()) > 200, 20, 0.5):
        page.screenshot(path=str(ARTIFACTS / "replay-no-line.png"))
        replayed.screenshot(path=str(ARTIFACTS / "replay-no-line-replayed.png"))
        raise AssertionError("no line in the replay plot")
    expect(page.get_by_text(re.compile(r"m8\s*joint\.angle = ")).first).to_be_visible()  # the values listed
    page.screenshot(path=str(ARTIFACTS / "replay-paused.png"))
    # scrub back half a gait period (1 s): the time, the robot and the plot follow (a whole period back, the
    # crawling robot can be drawn to the pixel as it was: a fresh-clone CI scrubbed from 2.0x s to 1 s)
    target = round(paused - 0.5, 2)
    box = _slider_box(page, "Replay time (s)")
    plot_before = replayed.locator("canvas").first.screenshot()
    for _ in range(3):  # a loaded page can lose the typed number before Enter commits it: type it again
        box.click()
        box.press("Control+a")
        box.press_sequentially(f"{target:g}")
        expect(box).to_have_value(f"{target:g}", timeout=10_000)
        box.press("Enter")
        if page_until(lambda: abs(replay_time(page) - target) < 0.02, 15, 0.2):
            break
    assert abs(replay_time(page) - target) < 0.02, replay_time(page)
    assert page_until(lambda: page.screenshot(clip=VIEW) != moved, 20, 0.5), "the scrub did not move the robot"
    assert page_until(lambda: replayed.locator("canvas").first.screenshot() != plot_before, 20, 0.5)
    # play on from the scrubbed point (not from the end) at 0.25x, then at 4x to the end
    choose(page, "Replay speed", "0.25x")
    expect(page.get_by_text("· 0.25x", exact=False).first).to_be_visible(timeout=10_000)
    page.get_by_role("button", name="▶ Play").click()
    assert page_until(lambda: replay_time(page) > target + 0.05, 20, 0.2), replay_time(page)
    slow = replay_time(page)
    assert slow < target + 3.0, slow  # a quarter of the wall clock's pace, from the scrubbed point
    choose(page, "Replay speed", "4x")
    expect(page.get_by_text("■ ended", exact=False).first).to_be_visible(timeout=30_000)
    assert replay_time(page) > 7.0
    page.screenshot(path=str(ARTIFACTS / "replay-ended.png"))
    page.get_by_role("button", name="Leave replay").click()
    expect(page.get_by_text("Showing: Live", exact=False).first).to_be_visible(timeout=15_000)
    expect(page.get_by_text("No recording open.").first).to_be_visible()
    assert page_until(lambda: violet(page.screenshot(clip=VIEW)) < 50, 30, 0.5)  # no violet robot
    browser.close()
    assert not any("Traceback" in line for line in log), "".join(log[-40:])


def test_asm_studio_replay_opens_a_recording_at_start_and_refuses_a_bad_one(start_studio, tmp_path):
    """``--replay FILE``: the recording is open when the page comes (said in the log); a file that is not MCAP is
    refused in one line and the studio serves on; a file that does not exist is a usage error."""
    from ..processes import run

    simulated_recording(tmp_path / "run.mcap", seconds=2.0)
    _, _, log = start_studio("--replay", str(tmp_path / "run.mcap"))
    assert page_until(lambda: any("replaying run.mcap: 1.98 s, 120 poses" in line for line in log), 60, 0.2), log
    (tmp_path / "bad.mcap").write_bytes(b"PK\x03\x04 a zip file")
    _, _, bad = start_studio("--replay", str(tmp_path / "bad.mcap"))
    assert page_until(lambda: any("not replayed: bad.mcap is not an MCAP file" in line for line in bad), 60, 0.2)
    missing = run("-m", "server.studio", "--replay", str(tmp_path / "none.mcap"), timeout=60)
    assert missing.returncode == 2 and "none.mcap" in missing.stderr, missing
    assert not any("Traceback" in line for line in log + bad)
