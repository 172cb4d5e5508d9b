"""Issue 29's review: the Replay tab's plot had no export (only the Monitor's live plots had). By clicks in
Chromium: Export CSV and Export MCAP of the replay plot download the recorded samples it shows — each series' own
times and the file's values, exactly, from its window up to the replay time — and with no recording open, Export is
refused with a line."""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

from mcap.reader import make_reader

from ..helpers import ARTIFACTS
from .browser import choose, marks, number, open_page, page_until
from .test_replay_page import _slider_box, simulated_recording

pytestmark = marks(__name__)


def test_the_replay_plot_exports_the_recorded_samples_it_shows(start_studio, tmp_path, chromium):
    from playwright.sync_api import expect

    from web.recording import open_recording

    simulated_recording(tmp_path / "run.mcap", seconds=3.0)  # every module's joint.angle at 20 Hz, each at its time
    url, _, log = start_studio("--recordings", str(tmp_path))
    target = 1.5

    def replay_time(page) -> float:
        return number(page.get_by_text(re.compile(r"t = [\d.]+ s of")).first.inner_text(), r"t = ([\d.]+) s of")

    browser, page = open_page(chromium, url)
    page.get_by_role("tab", name="Replay").click()
    page.get_by_role("button", name="Export CSV", exact=True).click()  # nothing open: refused, said
    expect(page.get_by_text("no recording open: open one, then export its plot").first).to_be_visible(timeout=15_000)
    page.get_by_role("button", name="List files").click()
    choose(page, "Recording", "run.mcap")
    page.get_by_role("button", name="Open", exact=True).click()
    expect(page.get_by_text(re.compile(r"run\.mcap: 2\.98 s")).first).to_be_visible(timeout=30_000)
    box = _slider_box(page, "Replay time (s)")
    for _ in range(3):  # a loaded page can lose the typed number before Enter commits it: type it again
        box.click()
        box.press("Control+a")
        box.press_sequentially(f"{target:g}")
        box.press("Enter")
        if page_until(lambda: replay_time(page) == target, 15, 0.2):
            break
    assert replay_time(page) == target
    with page.expect_download() as csv_download:
        page.get_by_role("button", name="Export CSV", exact=True).click()
    with page.expect_download() as mcap_download:
        page.get_by_role("button", name="Export MCAP", exact=True).click()
    page.screenshot(path=str(ARTIFACTS / "replay-exported.png"))
    rows = list(csv.reader(Path(csv_download.value.path()).read_text().splitlines()))
    exported = Path(mcap_download.value.path()).read_bytes()  # the browser's downloads go with it
    assert (csv_download.value.suggested_filename, mcap_download.value.suggested_filename) == (
        "replay-plot.csv",
        "replay-plot.mcap",
    )
    browser.close()
    recording = open_recording(tmp_path / "run.mcap")
    recorded = {f"{node} {obj}": [(t, v) for t, v in zip(s.times, s.values, strict=True) if t <= target]
                for (node, obj), s in recording.series.items()}  # fmt: skip
    labels = [f"m{m} joint.angle" for m in range(1, 9)]
    assert rows[0] == ["t (s)", *labels], rows[0]
    assert [float(r[0]) for r in rows[1:]] == sorted(t for label in labels for t, _ in recorded[label])
    for k, label in enumerate(labels, start=1):
        written = [(float(r[0]), float(r[k])) for r in rows[1:] if r[k] != ""]
        assert written == recorded[label] and len(written) > 10, label  # its own samples, exactly, nothing else
    got: dict[str, list[tuple[float, float]]] = {}
    for schema, channel, message in make_reader(io.BytesIO(exported)).iter_messages():
        assert schema is not None and schema.name == "asm.PlotSample"
        sample = json.loads(message.data)
        got.setdefault(channel.topic, []).append((sample["t"], sample["value"]))
    assert got == {f"/m{m}/joint.angle": recorded[f"m{m} joint.angle"] for m in range(1, 9)}
    assert not any("Traceback" in line for line in log), "".join(log[-40:])
