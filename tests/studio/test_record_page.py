"""The studio's Record button (issue 29), by clicks in Chromium: record the live robot, stop, and the MCAP file holds
its poses for Foxglove's 3D panel, its attribute values, the metadata naming the robot and the gait embedded; a live
plot exported as CSV."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

from mcap.reader import make_reader

from ..helpers import ARTIFACTS
from .browser import deploy_and_start, marks, open_page, plot

pytestmark = marks(__name__)


def test_record_the_robot_from_the_page_and_read_the_file_back(start_studio, tmp_path, chromium):
    from playwright.sync_api import expect

    url, _, log = start_studio("--recordings", str(tmp_path))
    browser, page = open_page(chromium, url)
    deploy_and_start(page, 8)
    page.get_by_role("tab", name="Monitor").click()
    page.get_by_role("button", name="● Record").click()
    expect(page.get_by_text("Recording: recording robot robot to", exact=False).first).to_be_visible(timeout=20_000)
    page.wait_for_timeout(4_000)
    page.get_by_role("button", name="■ Stop recording").click()
    done = page.get_by_text(re.compile(r"Recording: recorded \d+ messages")).first
    expect(done).to_be_visible(timeout=30_000)
    page.screenshot(path=str(ARTIFACTS / "record-from-page.png"))
    line = done.inner_text()
    # the first live plot shows the deployed modules' joint.angle: its CSV is what it shows
    with page.expect_download() as download:
        page.get_by_role("button", name="Live plot 1").first.click()
    rows = list(csv.reader(Path(download.value.path()).read_text().splitlines()))
    filename = download.value.suggested_filename
    with page.expect_download() as exported:  # and as MCAP, one channel per series (the next group's button)
        page.get_by_role("button", name="Live plot 1").nth(1).click()
    assert exported.value.suggested_filename == "live-plot-1.mcap"
    with Path(exported.value.path()).open("rb") as stream:
        plotted = {channel.topic for _, channel, _ in make_reader(stream).iter_messages()}
    assert "/m1/joint.angle" in plotted, plotted
    # the layout: saved, the plot cleared, loaded again: the same attributes plotted
    with page.expect_download() as saved:
        page.get_by_role("button", name="Save layout (.json)").click()
    layout_file = tmp_path / "layout.json"
    saved.value.save_as(str(layout_file))
    layout = json.loads(layout_file.read_text())
    page.get_by_role("button", name="Live plot 1").nth(2).click()  # Clear (after Export CSV and Export MCAP)
    live1 = plot(page, "Live 1")
    expect(live1).not_to_contain_text("joint.angle", timeout=15_000)
    with page.expect_file_chooser() as chooser:
        page.get_by_role("button", name="Load layout (.json)").click()
    chooser.value.set_files(str(layout_file))
    for key in layout["plots"]["Live plot 1"]:
        expect(live1).to_contain_text(key.replace("/", " "), timeout=15_000)
    page.reload()  # the layout is the studio's: a reload shows it again
    page.get_by_role("tab", name="Plots").click()
    expect(plot(page, "Live 1")).to_contain_text("m1 joint.angle", timeout=60_000)
    page.screenshot(path=str(ARTIFACTS / "layout-loaded.png"))
    browser.close()
    assert layout["plots"]["Live plot 1"][:1] == ["m1/joint.angle"], layout  # the deploy plotted the angles
    assert filename == "live-plot-1.csv"
    assert rows[0][:2] == ["t (s)", "m1 joint.angle"], rows[0]
    times = [float(r[0]) for r in rows[1:]]
    assert len(times) > 30 and times == sorted(times)
    angles = [float(r[1]) for r in rows[1:] if r[1]]  # empty: m1 has no sample at another series' time
    assert len(angles) > 30 and len(angles) < len(times)  # its own samples only, not every series' times
    assert max(angles) - min(angles) > 20 and all(-90 <= a <= 90 for a in angles)  # the wave, within the limits
    path = Path(re.search(r"to (\S+\.mcap)", line).group(1))  # type: ignore[union-attr]
    assert path.parent == tmp_path and path.exists()
    with path.open("rb") as stream:
        reader = make_reader(stream)
        topics: dict[str, int] = {}
        for _, channel, _ in reader.iter_messages():
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
        stream.seek(0)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        stream.seek(0)
        attachments = {a.name for a in reader.iter_attachments()}
    assert topics.get("/robot/transforms", 0) > 60, topics  # 4 s of poses at 60 a second
    assert topics.get("/m1/joint.angle", 0) > 0, sorted(topics)
    assert any(m.get("robot") == "robot" and m.get("recorder") == "asm-studio" for m in metadata.values()), metadata
    assert "caterpillar.toml" in attachments and "robot.mjcf" in attachments, attachments
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
