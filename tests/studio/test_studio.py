"""The studio's parts without a browser: the edited document (validation, undo/redo) and the preview loop."""

from __future__ import annotations

import itertools
import time

import pytest

from gaits.model import GaitError, dumps, load
from tests.helpers import wait_until
from web.document import GaitDocument
from web.monitor import format_value
from web.preview import PreviewLoop

pytestmark = pytest.mark.timeout(60)
CATERPILLAR = "gaits/library/caterpillar.toml"


def test_an_invalid_edit_is_kept_with_its_problem_and_undo_restores():
    doc = GaitDocument(load(CATERPILLAR))
    doc.set_state("wave", 2, "angle", 120.0)  # beyond the ±90° limits
    assert [p.path for p in doc.problems] == ["automata.wave.states[2].angle"]
    assert doc.problem_at("automata.wave.states[2]")
    with pytest.raises(GaitError):
        doc.gait()
    assert doc.undo() and not doc.problems
    assert doc.gait().automata["wave"].states[2].angle == pytest.approx(46.194)
    assert doc.redo() and doc.problems
    assert not doc.redo()


def test_edits_reach_the_gait_and_the_file():
    doc = GaitDocument(load(CATERPILLAR))
    doc.set_module(3, "phase", 0.5)
    doc.set_module(3, "direction", -1)
    doc.set_robot("friction", 0.6)
    doc.add_state("wave", 0)
    gait = doc.gait()
    assert gait.assignment(3).phase == 0.5 and gait.assignment(3).direction == -1
    assert gait.ground.friction == 0.6
    assert len(gait.automata["wave"].states) == 17
    assert "friction = 0.6" in doc.text()
    with pytest.raises(GaitError):
        doc.load_text("name = 'x'\n[robot]\nshape = 'blob'\n")
    assert doc.gait() == gait  # a bad upload changes nothing
    with pytest.raises(GaitError, match=r"line 2: .*not UTF-8"):
        doc.load_text(b"name = 'x'\ndescription = '\xff'\n")  # uploaded bytes that are not UTF-8
    assert doc.gait() == gait
    doc.load_text(dumps(load("gaits/library/inchworm.toml")))
    assert doc.gait().name == "inchworm" and doc.undo() and doc.gait().name == "caterpillar"


def test_preview_loop_plays_steps_scrubs_and_reloads():
    loop = PreviewLoop(load(CATERPILLAR))
    try:
        loop.request("speed", 4.0)
        deadline = time.monotonic() + 20
        while len(loop.frames) < 30 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(loop.frames) >= 30
        loop.request("seek", 5)
        time.sleep(0.2)
        assert not loop.playing and loop.shown() is loop.frames[5]
        loop.request("step", -1)
        time.sleep(0.2)
        assert loop.shown() is loop.frames[4]
        # the metrics and the angle plot follow the timeline with the pose: they are those of frame 4
        assert loop.metrics().seconds == loop.frames[4].time < loop.frames[-1].time
        t, goal, _ = loop.series(0)
        assert t[-1] == loop.frames[4].time and goal[-1] == loop.frames[4].goals[0]
        loop.request("step", 1)  # step works while scrubbed
        time.sleep(0.2)
        assert loop.shown() is loop.frames[5] and loop.metrics().seconds == loop.frames[5].time
        loop.request("load", load("gaits/library/rolling_loop.toml"))
        loop.request("play", True)
        deadline = time.monotonic() + 20
        while (loop.generation < 1 or not loop.frames) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert loop.sim.gait.name == "rolling_loop" and len(loop.frames[-1].goals) == 12
    finally:
        loop.close()


def test_values_are_formatted_for_the_page():
    assert format_value(b"\x01\x02") == "01 02"
    assert format_value((1.0, 2.5)) == "[1, 2.5]"


def test_the_robot_grows_shrinks_and_changes_shape_from_the_document():
    doc = GaitDocument(load(CATERPILLAR))
    doc.set_robot("modules", 12)
    gait = doc.gait()
    assert gait.robot.modules == 12 and [m.id for m in gait.modules] == list(range(1, 13))
    # the new modules continue the travelling wave: the same phase step as modules 7 → 8
    step = (gait.assignment(8).phase - gait.assignment(7).phase) % 1.0
    for k in range(9, 13):
        assert (gait.assignment(k).phase - gait.assignment(k - 1).phase) % 1.0 == pytest.approx(step, abs=1e-5)
    doc.set_module(3, "phase", 0.25)
    doc.set_module(11, "direction", -1)
    doc.set_robot("modules", 1)  # typing "12" over "1" passes through one module
    assert [m.id for m in doc.gait().modules] == [1]
    doc.set_robot("modules", 12)
    assert doc.gait().assignment(3).phase == 0.25 and doc.gait().assignment(11).direction == -1
    doc.set_robot("shape", "legged")
    assert doc.gait().robot.legs == 4  # 12 modules: four legs of three
    doc.set_robot("modules", 10)
    assert [p.path for p in doc.problems] == ["robot.legs"]  # 10 modules do not split into 4 legs
    doc.set_robot("legs", 2)
    assert not doc.problems
    doc.set_robot("shape", "loop")
    assert "legs" not in doc.data()["robot"] and doc.gait().robot.shape == "loop"
    with pytest.raises(ValueError):
        doc.set_robot("modules", 0)
    assert doc.undo() and doc.gait().robot.shape == "legged"


def test_a_grid_row_is_one_undoable_edit():
    doc = GaitDocument(load(CATERPILLAR))
    doc.update_state("wave", 4, {"angle": 10.0, "duration": 0.07})
    state = doc.gait().automata["wave"].states[4]
    assert (state.angle, state.duration) == (10.0, 0.07)
    assert not doc.problems
    assert doc.undo() and doc.gait().automata["wave"].states[4].angle == pytest.approx(46.194)
    with pytest.raises(ValueError):
        doc.update_state("wave", 0, {"until": "contact"})


@pytest.mark.parametrize("index", [-1, -16, 16, 99])
def test_an_edit_of_a_state_the_gait_does_not_have_is_refused_by_name_and_changes_nothing(index: int) -> None:
    """A state index from the page that the gait has no state for: -1 edited the last state (Python's indexing),
    16 said only "list index out of range" (a state clicked in a view of states since removed)."""
    doc = GaitDocument(load(CATERPILLAR))
    before = doc.data()
    edits = (lambda: doc.set_state("wave", index, "angle", 5.0),
             lambda: doc.update_state("wave", index, {"duration": 0.2}),
             lambda: doc.set_event("wave", index, None), lambda: doc.set_emit("wave", index, 3),
             lambda: doc.add_state("wave", index), lambda: doc.remove_state("wave", index))  # fmt: skip
    for edit in edits:
        with pytest.raises(ValueError, match=rf"wave has no state S{index + 1}$"):
            edit()
    with pytest.raises(ValueError, match="nope has no state S1"):
        doc.set_state("nope", 0, "angle", 5.0)
    assert doc.data() == before and not doc.undo()


def _no_lookup(*_: object, **__: object) -> object:
    """A plot's lookup in tests that fill its series by hand: never called."""
    raise AssertionError("no lookup: the series are filled by hand")


def test_live_series_are_continuous_on_a_shared_time_axis():
    from collections import deque

    from web.monitor import LivePlot

    plot = LivePlot(lookup=_no_lookup)  # filled by hand: no subscriptions
    now = plot.clock()
    plot.series[("m1", "joint.angle")] = deque([(now - 1.0, 0.0), (now - 0.5, 10.0), (now, 20.0)])
    plot.series[("m2", "joint.angle")] = deque([(now - 0.75, 5.0), (now - 0.25, 7.0)])
    labels, (t, a, b) = plot.data()
    assert labels == ["m1 joint.angle", "m2 joint.angle"]
    assert list(t) == sorted(t) and len(t) == 5
    assert list(a) == pytest.approx([0.0, 5.0, 10.0, 15.0, 20.0])  # m1 between its own samples
    assert list(b) == pytest.approx([5.0, 5.0, 6.0, 7.0, 7.0])  # held outside m2's samples, no NaN (uPlot)


def test_every_live_plot_runs_on_one_studio_clock_for_as_long_as_the_studio_runs():
    """Two plots share the page's clock (not each its own start, nor a robot's time): after a day of running, a
    series added to the second plot a moment ago sits in the same window, ending at the same now, as the first's."""
    from collections import deque

    from web.monitor import LivePlot, StudioClock

    wall = [1000.0]
    clock = StudioClock(lambda: wall[0])
    first, second = LivePlot(lookup=_no_lookup, clock=clock), LivePlot(lookup=_no_lookup, clock=clock)
    first.series[("m1", "joint.angle")] = deque([(clock(), 1.0)])
    wall[0] += 86_400.0  # a day later
    first.series[("m1", "joint.angle")].append((clock(), 2.0))
    second.series[("m7", "joint.angle")] = deque([(clock() - 0.5, 3.0), (clock(), 4.0)])
    now = clock()
    assert now == 86_400.0
    (_, (t1, a)), (_, (t2, b)) = first.data(now), second.data(now)
    assert list(t1) == [now] and list(a) == [2.0]  # the sample a day old is out of the window
    assert list(t2) == [now - 0.5, now] and list(b) == [3.0, 4.0]
    assert list(first.data(now + 60.0)[1][0]) == [now + 60.0]  # nothing recent: one point at now, in the window


def test_undo_takes_back_a_typed_value_not_a_keystroke():
    """Typing 45 sends "4" then "45": one undo step gives back the value before, never "4"."""
    now = [0.0]
    doc = GaitDocument(load(CATERPILLAR), clock=lambda: now[0])
    before = doc.gait().automata["wave"].states[0].angle
    doc.set_state("wave", 0, "angle", 4.0)
    now[0] += 0.2
    doc.set_state("wave", 0, "angle", 45.0)
    assert doc.gait().automata["wave"].states[0].angle == 45.0
    assert doc.undo() and doc.gait().automata["wave"].states[0].angle == before
    assert not doc.undo()  # one step, not two
    assert doc.redo() and doc.gait().automata["wave"].states[0].angle == 45.0
    # a pause ends the step; so does an edit of another field
    now[0] += 5.0
    doc.set_state("wave", 0, "angle", 30.0)
    now[0] += 0.1
    doc.set_module(1, "phase", 0.5)
    now[0] += 0.1
    doc.set_state("wave", 0, "angle", 31.0)
    assert doc.undo() and doc.gait().automata["wave"].states[0].angle == 30.0
    assert doc.undo() and doc.gait().assignment(1).phase == 0.0
    assert doc.undo() and doc.gait().automata["wave"].states[0].angle == 45.0


def test_a_refused_value_is_never_an_undo_step_of_its_own():
    """A duration of -0.1 is refused (the document invalid, the problem at its field); typing a valid one later
    replaces it in its undo step: Undo gives back the value before the refused one."""
    now = [0.0]
    doc = GaitDocument(load(CATERPILLAR), clock=lambda: now[0])
    before = doc.gait().automata["wave"].states[0].duration
    doc.set_state("wave", 0, "duration", -0.1)
    assert doc.problems and doc.data()["automata"]["wave"]["states"][0]["duration"] == -0.1  # kept, not clamped
    now[0] += 30.0  # long after: not the typing window that joins keystrokes
    doc.set_state("wave", 0, "duration", 0.07)
    assert not doc.problems
    assert doc.undo() and doc.gait().automata["wave"].states[0].duration == before
    assert not doc.undo()
    # valid values typed far apart stay steps of their own
    now[0] += 30.0
    doc.set_state("wave", 0, "duration", 0.05)
    now[0] += 30.0
    doc.set_state("wave", 0, "duration", 0.06)
    assert doc.undo() and doc.gait().automata["wave"].states[0].duration == 0.05


def test_play_from_a_scrubbed_point_replays_from_there_then_simulates_on():
    """Pause, go back to frame 10, Play: the frames from 10 on are shown in turn (not a jump to the newest), and
    once they are played the simulation goes on from the newest frame."""
    loop = PreviewLoop(load(CATERPILLAR))
    try:
        loop.request("speed", 4.0)
        assert wait_until(lambda: len(loop.frames) >= 120, timeout=30)
        loop.request("seek", 10)
        assert wait_until(lambda: loop.cursor == 10, timeout=5)
        newest = loop.frames[-1].time
        loop.request("speed", 1.0)
        loop.request("play", True)
        assert wait_until(lambda: loop.cursor is not None and loop.cursor > 15, timeout=5)
        shown = loop.shown()
        assert shown is not None and shown.time < newest  # replaying what was recorded, not at the newest frame
        assert wait_until(lambda: loop.cursor is None, timeout=30)  # played through: the simulation goes on
        assert wait_until(lambda: loop.frames[-1].time > newest + 0.5, timeout=30)
    finally:
        loop.close()


def test_a_held_preview_waits_where_it_is_and_goes_on_from_there():
    """Nobody watching the page holds the preview: its time stands still (no frames, no CPU), requests are still
    taken, and released it goes on from where it was, never catching up the time it was held."""
    loop = PreviewLoop(load(CATERPILLAR))
    try:
        assert wait_until(lambda: len(loop.frames) >= 10, timeout=30)
        loop.hold(True)
        time.sleep(0.3)  # a step under way when the hold came is finished
        held_at, count = loop.frames[-1].time, len(loop.frames)
        time.sleep(1.0)
        assert (loop.frames[-1].time, len(loop.frames)) == (held_at, count)
        assert loop.playing  # a hold is not the user's Pause
        loop.request("speed", 2.0)  # still taken while held
        assert wait_until(lambda: loop.speed == 2.0, timeout=5)
        loop.hold(False)
        assert wait_until(lambda: loop.frames[-1].time > held_at + 0.2, timeout=10)
        # on from where it was: frames follow one another on the 1/60 s grid, with no jump over the held second
        times = [f.time for f in loop.frames if f.time >= held_at]
        assert max(b - a for a, b in itertools.pairwise(times)) < 0.02
    finally:
        loop.close()


def _two_series_plot():
    """A live plot filled by hand (no subscriptions): gait.state, integer states published from 5 s into the
    window, and joint.angle from the start at other times; one sample of each is older than the window."""
    from collections import deque

    from web.monitor import LivePlot

    plot = LivePlot(lookup=_no_lookup)
    now = plot.clock()
    states = [(now - 30.0, 9.0), *((now - 5.0 + k * 0.7, float(k % 4 * 5)) for k in range(7))]
    angles = [(now - 30.0, 1.0), *((now - 9.0 + k * 0.4, (k - 10) / 3) for k in range(22))]
    plot.series[("m1", "gait.state")] = deque(states)
    plot.series[("m1", "joint.angle")] = deque(angles)
    plot.series[("m2", "joint.goal")] = deque()  # watched, no sample yet
    return plot, now, {"m1 gait.state": states[1:], "m1 joint.angle": angles[1:], "m2 joint.goal": []}


def test_a_live_plot_exported_as_csv_holds_each_series_samples_as_received():
    # Issue 29's review: the export wrote the drawing's grid — gait.state interpolated to 14.92, held at its first
    # value before its first sample; each series' own samples are written, a cell empty where it has none.
    import csv

    from web.monitor import plot_csv

    plot, now, published = _two_series_plot()
    labels, samples = plot.samples(now)
    rows = list(csv.reader(plot_csv(labels, samples).splitlines()))
    assert rows[0] == ["t (s)", "m1 gait.state", "m1 joint.angle", "m2 joint.goal"]
    times = [float(row[0]) for row in rows[1:]]
    assert times == sorted({t for points in published.values() for t, _ in points})  # a row per sample time
    for k, label in enumerate(rows[0][1:], start=1):
        written = [(float(row[0]), float(row[k])) for row in rows[1:] if row[k] != ""]
        assert written == published[label], label  # exactly what was published, at its times, nothing else
    first_state = published["m1 gait.state"][0][0]
    assert all(row[1] == "" for row in rows[1:] if float(row[0]) < first_state)  # nothing held before it
    assert all(float(row[1]).is_integer() for row in rows[1:] if row[1])  # no state between states


def test_a_live_plot_exported_as_mcap_holds_each_series_samples_as_received():
    import io
    import json

    from mcap.reader import make_reader

    from web.monitor import plot_mcap

    plot, now, published = _two_series_plot()
    labels, samples = plot.samples(now)
    reader = make_reader(io.BytesIO(plot_mcap(labels, samples)))
    start = min(t for points in published.values() for t, _ in points)
    got: dict[str, list[tuple[float, float]]] = {}
    for schema, channel, message in reader.iter_messages():
        assert schema is not None and schema.name == "asm.PlotSample" and channel.message_encoding == "json"
        sample = json.loads(message.data)
        assert message.log_time == round((sample["t"] - start) * 1e9)
        assert message.sequence == len(got.get(channel.topic, []))
        got.setdefault(channel.topic, []).append((sample["t"], sample["value"]))
    assert got == {"/m1/gait.state": published["m1 gait.state"], "/m1/joint.angle": published["m1 joint.angle"]}


def test_the_replay_plot_exported_holds_the_recorded_samples_exactly():
    # Issue 29's review: the Replay tab's plot had no export; it writes the file's values (an int stays an int)
    # of what the plot shows: its window up to the replay time.
    import csv
    import io
    import json

    from mcap.reader import make_reader

    from web.monitor import plot_csv, plot_mcap
    from web.recording import Recording, Series
    from web.replay import plot_samples
    from web.replay_panel import PLOT_WINDOW

    recording = Recording("run.mcap")
    recording.series[("m1", "gait.state")] = Series([10.0, 40.5, 41.25, 42.0, 50.0], [0, 3, 1, 2, 3])  # a list
    recording.series[("m2", "joint.angle")] = Series([5.0, 40.1, 41.0, 41.7, 45.0], [0.5, 1.0, -2.25, 1 / 3, 9.0])
    recording.series[("m2", "note")] = Series([41.0], ["text"])  # not a number: not plotted, not exported
    keys = [("m1", "gait.state"), ("m2", "joint.angle"), ("m2", "note")]
    labels, samples = plot_samples(recording, keys, 42.0, PLOT_WINDOW)  # the window: (12 s, 42 s]
    assert labels == ["m1 gait.state", "m2 joint.angle"]
    rows = list(csv.reader(plot_csv(labels, samples).splitlines()))
    assert rows == [["t (s)", *labels], ["40.1", "", "1.0"], ["40.5", "3", ""], ["41.0", "", "-2.25"],
                    ["41.25", "1", ""], ["41.7", "", repr(1 / 3)], ["42.0", "2", ""]]  # fmt: skip
    got: dict[str, list[tuple[float, object]]] = {}
    for _, channel, message in make_reader(io.BytesIO(plot_mcap(labels, samples))).iter_messages():
        sample = json.loads(message.data)
        got.setdefault(channel.topic, []).append((sample["t"], sample["value"]))
    assert got == {"/m1/gait.state": [(40.5, 3), (41.25, 1), (42.0, 2)],
                   "/m2/joint.angle": [(40.1, 1.0), (41.0, -2.25), (41.7, 1 / 3)]}  # fmt: skip
    assert all(type(v) is int for _, v in got["/m1/gait.state"])  # the file's ints, not floats


def test_the_trail_keeps_where_the_robot_went_and_points_the_way_it_goes():
    from types import SimpleNamespace

    import numpy as np

    from web.trail import SAMPLE_EVERY, Trail

    drawn: dict[str, np.ndarray] = {}
    scene = SimpleNamespace(add_line_segments=lambda name, points, *_a, **_k: drawn.__setitem__(name, points))
    trail = Trail(scene)
    angle = np.radians(30.0)
    for k in range(SAMPLE_EVERY * 20):  # travelling at 30° from x
        trail.add(np.array([np.cos(angle), np.sin(angle), 0.0]) * k * 0.01, np.zeros(3), seconds=k / 60)
    assert len(trail.points) == 20
    heading = trail.heading()
    assert heading is not None and np.degrees(np.arctan2(heading[1], heading[0])) == pytest.approx(30.0, abs=1e-6)
    assert drawn["/trail"].shape == (19, 2, 3) and drawn["/travel_arrow"].shape == (3, 2, 3)
    tip = drawn["/travel_arrow"][0, 1, :2] - drawn["/travel_arrow"][0, 0, :2]
    assert np.degrees(np.arctan2(tip[1], tip[0])) == pytest.approx(30.0, abs=1e-3)  # the arrow points the way
    trail.add(np.zeros(3), np.zeros(3), seconds=0.5)  # scrubbed back: a new trail from there
    assert len(trail.points) == 1
