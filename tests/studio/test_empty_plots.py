"""A plot with nothing to show draws no line (issue 29's review: an empty live plot drew a flat line at 0, as if an
attribute read 0). What the page is sent is read from a stand-in for viser's GUI: the uPlots made, their series and
data; a series draws a line when it is shown and has a stroke (uPlot draws none without one)."""

from __future__ import annotations

import contextlib
from collections import deque
from typing import Any

import numpy as np

from web.monitor import LivePlot, SeriesPlot, StudioClock
from web.replay import plot_data


class _Uplot:
    def __init__(self, data: tuple[np.ndarray, ...], series: tuple[dict[str, Any], ...], order: float) -> None:
        self.data, self.series, self.order = data, series, order
        self.removed = False

    def remove(self) -> None:
        self.removed = True


class _Gui:
    """viser's GUI as SeriesPlot uses it: uPlots made in a container."""

    def __init__(self) -> None:
        self.made: list[_Uplot] = []

    def add_uplot(self, data: tuple[np.ndarray, ...], series: tuple[dict[str, Any], ...], order: float | None = None,
                  **_options: Any) -> _Uplot:  # fmt: skip
        self.made.append(_Uplot(data, series, len(self.made) if order is None else order))
        return self.made[-1]


def drawn(plot: SeriesPlot) -> dict[str, list[float]]:
    """The lines the page draws: each shown series with a stroke, and its values."""
    handle = plot.handle
    assert not handle.removed and len(handle.series) == len(handle.data)
    assert all(np.isfinite(column).all() for column in handle.data)  # uPlot takes no NaN
    return {s["label"]: [float(v) for v in column] for s, column in zip(handle.series, handle.data, strict=True)
            if s is not handle.series[0] and s.get("show", True) and s.get("stroke")}  # fmt: skip


def _no_lookup(*_: object, **__: object) -> object:
    raise AssertionError("no lookup: the series are filled by hand")


def test_a_live_plot_draws_no_line_until_there_are_samples():
    plot = SeriesPlot(_Gui(), contextlib.nullcontext(), title="Live 1", y_label="value", aspect=3.0)
    assert drawn(plot) == {}  # nothing plotted yet: it drew a line at 0
    wall = [100.0]
    live = LivePlot(lookup=_no_lookup, clock=StudioClock(lambda: wall[0]))
    now = live.clock()
    plot.show(*live.data(now), now, live.window)
    assert drawn(plot) == {}
    live.series[("m1", "joint.angle")] = deque()  # plotted, no sample yet: a point at 0 was drawn for it
    plot.show(*live.data(now), now, live.window)
    assert drawn(plot) == {} and "m1 joint.angle (no samples yet)" in [s["label"] for s in plot.handle.series]
    live.series[("m1", "joint.angle")].append((now, 5.0))
    live.series[("m2", "joint.angle")] = deque()  # a second attribute, silent so far: no line at 0 beside the first
    plot.show(*live.data(now), now, live.window)
    assert drawn(plot) == {"m1 joint.angle": [5.0]}
    live.series[("m2", "joint.angle")].append((now, -2.0))
    wall[0] += 30.0  # both out of the window: held at their last values, as before
    now = live.clock()
    plot.show(*live.data(now), now, live.window)
    assert drawn(plot) == {"m1 joint.angle": [5.0], "m2 joint.angle": [-2.0]}
    live.unwatch_all()  # Clear
    plot.show(*live.data(now), now, live.window)
    assert drawn(plot) == {}


def test_the_replay_plot_draws_no_line_before_the_first_recorded_value():
    from web.recording import Recording, Series

    recording = Recording("run.mcap")
    recording.series[("m1", "joint.angle")] = Series([1.0, 2.0], [10.0, 20.0])
    recording.series[("m2", "joint.angle")] = Series([1.5], [7.0])
    plot = SeriesPlot(_Gui(), contextlib.nullcontext(), title="Replay", y_label="value", aspect=3.0)
    keys = [("m1", "joint.angle"), ("m2", "joint.angle")]
    both = {"m1 joint.angle": [10.0, 15.0, 20.0], "m2 joint.angle": [7.0, 7.0, 7.0]}
    for t, lines in ((0.5, {}), (1.0, {"m1 joint.angle": [10.0]}), (2.0, both)):  # m2 from 1.5 s on
        plot.show(*plot_data(recording, keys, t, 30.0), t, 30.0)
        assert drawn(plot) == lines, t


def test_an_infinite_value_does_not_blank_the_plot():
    """Issue 29's third review: one /m1/joint.angle of Infinity in a recording (a float attribute may publish it)
    blanked the replay plot of every module: it was sent as 1.8e308, and uPlot's scale drew nothing. A value that
    is not finite is drawn as the last finite one before it; the other series are untouched."""
    from web.recording import Recording, Series

    recording = Recording("run.mcap")
    recording.series[("m1", "joint.angle")] = Series([1.0, 2.0, 3.0, 4.0], [10.0, float("inf"), -float("inf"), 40.0])
    recording.series[("m2", "joint.angle")] = Series([1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, 4.0])
    plot = SeriesPlot(_Gui(), contextlib.nullcontext(), title="Replay", y_label="value", aspect=3.0)
    keys = [("m1", "joint.angle"), ("m2", "joint.angle")]
    plot.show(*plot_data(recording, keys, 4.0, 30.0), 4.0, 30.0)
    lines = drawn(plot)
    assert lines["m2 joint.angle"] == [1.0, 2.0, 3.0, 4.0]
    assert max(abs(v) for v in lines["m1 joint.angle"]) <= 40.0 and lines["m1 joint.angle"][-1] == 40.0, lines
