"""The Replay tab's edges found by issue 29's review, in the studio of this process (no browser): a replay time
outside the recording refused and said (it was moved to the start or the end without a word), and a recording with
no robot model clearing the 3D view and saying why (the robot shown before stayed drawn)."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from ..helpers import wait_until
from .test_replay import write_recording

pytestmark = pytest.mark.timeout(120)


def test_a_replay_time_outside_the_recording_is_refused_and_said(studio, tmp_path: Path):
    app = studio.app
    panel = app.replay
    path = tmp_path / "run.mcap"
    write_recording(path)  # 120 frames: 0 to 1.98 s
    panel.open_path(path)
    assert wait_until(lambda: panel.source is not None and "120 poses" in panel.line.content, 20)
    source = panel.source
    assert source is not None
    try:
        panel.timeline.value = 1.0  # a user's scrub, inside the recording
        assert wait_until(lambda: source.time() == 1.0, 20)
        for typed in (-5.0, 46.0):
            panel.timeline.value = typed  # typed into the slider's box, as the page would send it
            said = re.sub(r"\\(.)", r"\1", app.page.status.content)
            assert f"replay time {typed:g} s refused: run.mcap runs from 0 to 1.98 s" in said, said
            with pytest.raises(ValueError, match=r"runs from 0 to 1\.98 s"):
                panel._on_seek(SimpleNamespace(target=SimpleNamespace(value=typed)))
            time_now = source.time()
            assert time_now == 1.0, time_now  # not moved to the start or the end
            panel.refresh()
            assert panel.timeline.value == 1.0  # the slider back where the replay is
        panel.timeline.value = panel.timeline.max  # the end mark: the recording's end, to the hundredth
        assert wait_until(lambda: source.time() == min(panel.timeline.max, source.clock.duration), 20)
    finally:
        panel.leave()


def test_a_recording_without_a_model_clears_the_3d_view_and_says_so(studio, tmp_path: Path):
    app = studio.app
    panel, view = app.replay, app.view
    write_recording(tmp_path / "with-model.mcap")
    write_recording(tmp_path / "no-model.mcap", mjcf=None)
    panel.open_path(tmp_path / "with-model.mcap")
    assert wait_until(lambda: panel.source is not None and view._drawn is panel.source.recording.frames[0], 20)
    assert view._batches  # the recording's robot drawn
    try:
        panel.open_path(tmp_path / "no-model.mcap")
        assert wait_until(lambda: panel.source is not None and panel.source.recording.name == "no-model.mcap", 20)
        # the robot, its module labels and its trail go, in one clear on the render thread: waited for as one (a
        # fresh-clone run saw the batches gone and the trail not yet, read between two lines of that clear)
        cleared = lambda: not view._batches and not view._labels and view.trail._line is None  # noqa: E731
        assert wait_until(lambda: cleared() and "no robot model" in view._label.text, 20), "the one before is drawn"
        assert "no-model.mcap" in view._label.text
        app.bar.tick()
        assert "Nothing drawn" in app.bar.source_md.content and "no robot model" in app.bar.source_md.content
        assert "no robot model" in panel.line.content
    finally:
        panel.leave()
    assert wait_until(lambda: view._batches != [], 20)  # the live robot drawn again


def test_a_damaged_chunk_is_said_on_the_replay_tab(studio, tmp_path: Path):
    from mcap.reader import make_reader

    panel = studio.app.replay
    path = tmp_path / "damaged.mcap"
    write_recording(path)
    with path.open("rb") as stream:
        bad = make_reader(stream).get_summary().chunk_indexes[2]  # type: ignore[union-attr]
    data = bytearray(path.read_bytes())
    middle = bad.chunk_start_offset + bad.chunk_length // 2
    data[middle : middle + 64] = bytes(64)
    path.write_bytes(bytes(data))
    panel.open_path(path)
    try:
        assert wait_until(lambda: panel.source is not None and "poses" in panel.line.content, 20)
        said = re.sub(r"\\(.)", r"\1", panel.line.content)
        assert "⚠ 1 damaged chunk skipped: the file is corrupt" in said and "did not finish" not in said, said
    finally:
        panel.leave()


def test_leaving_a_replay_lets_its_recording_go(studio, tmp_path: Path):
    # Issue 29's second review: a 204 MB recording took the studio from 148 MB to 2.3 GB, which stayed after Leave
    # replay (the 3D scene still held it) and grew to 3.2 GB when it was opened again.
    import gc
    import weakref

    panel = studio.app.replay
    path = tmp_path / "run.mcap"
    write_recording(path)
    panel.open_path(path)
    assert wait_until(lambda: panel.source is not None and "120 poses" in panel.line.content, 20)
    assert panel.source is not None
    gone = weakref.ref(panel.source.recording)
    panel.leave()
    # held before: by the 3D scene's replay, and by the opening thread's last local while it waited
    assert wait_until(lambda: gc.collect() >= 0 and gone() is None, 20), "the recording is still held"


def test_a_replay_opened_over_another_says_it_replaces_it_in_every_tab(studio, tmp_path: Path):
    # Issue 29's second review: tab B's replay took over tab A's without a word (one replay per studio).
    panel = studio.app.replay
    first, second = tmp_path / "first.mcap", tmp_path / "second.mcap"
    write_recording(first)
    write_recording(second, frames=60)
    panel.open_path(first)
    assert wait_until(lambda: panel.source is not None and "120 poses" in panel.line.content, 20)
    panel.open_path(second)
    try:
        assert wait_until(lambda: panel.source is not None and "60 poses" in panel.line.content, 20)

        def said() -> str:  # the status is written after the panel's line (a fresh clone's run read it between)
            return re.sub(r"\\(.)", r"\1", studio.app.page.status.content)

        assert wait_until(lambda: "second.mcap opened" in said(), 20), said()
        assert "it replaces first.mcap: a studio has one replay, every tab" in said()
    finally:
        panel.leave()


def test_a_jump_in_a_recordings_log_times_is_said(studio, tmp_path: Path):
    # Issue 29's second review: one message with a far-future log time made a replay 1,000,000,001.67 s long,
    # its slider running to 1e9, without a word.
    import json

    from server.record import ATTRIBUTE

    from .test_replay import START

    panel = studio.app.replay
    path = tmp_path / "jump.mcap"
    files = write_recording(path, finish=False)
    late = {"node": "m1", "object": "joint.angle", "value": 1.0}
    files.write("/m1/joint.angle", ATTRIBUTE, json.dumps(late).encode(), START + 10**18)
    files.close()
    panel.open_path(path)
    try:
        assert wait_until(lambda: panel.source is not None and "poses" in panel.line.content, 20)
        said = re.sub(r"\\(.)", r"\1", panel.line.content)
        assert "⚠ its log times jump by 999,999,998 s at 1.98 s" in said, said
    finally:
        panel.leave()
