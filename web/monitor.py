"""Live monitoring through the dashboard's own ASM node: who is there, what their attributes hold, how they move.

Everything here goes through lookups, gets/sets and subscriptions of ``node``; nothing reaches into a module object.
Publications arrive on transport threads and only append to bounded buffers; the refresh thread formats them.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from asm_py import Node
from asm_py.keys import TOOL
from asm_py.remote import RemoteAttribute, RemoteObject

PLOT_SECONDS = 10.0
"""The live plot's default window; the page offers WINDOWS."""
WINDOWS = (10.0, 30.0, 60.0, 300.0)
PLOT_POINTS = 8000
"""Per series: five minutes at the modules' 25 publications a second."""


FORGET_GRACE = 5.0
"""Seconds after a node is forgotten during which news of it alive is taken as late."""


class Roster:
    """Nodes seen by discovery: alive or lost, and when they were last heard."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._lock = threading.Lock()
        self.entries: dict[str, dict[str, Any]] = {}
        self._forgotten: dict[str, float] = {}
        """Nodes dropped on purpose, with when: their loss is never shown, and news of them alive is taken only
        after FORGET_GRACE (discovery's news lags: a board lent an ID to be wiggled was heard alive after the
        wiggle's answer, then shown LOST)."""
        self._gait_objects: dict[str, tuple[Any, ...]] = {}
        self.tools: set[str] = set()
        """The other tools of the robot now (other studios, scripts), by name."""
        for name in node.discover():
            self._changed(name, True)
        self._unlisten = node.on_discovery(self._changed)

    def _changed(self, name: str, alive: bool) -> None:
        if name == self.node.transport.address:
            return
        if name.startswith(TOOL):  # another tool watching the robot (a studio, a script): listed apart
            with self._lock:
                (self.tools.add if alive else self.tools.discard)(name[len(TOOL) :])
            return
        with self._lock:
            if name in self._forgotten:
                if not alive or time.monotonic() - self._forgotten[name] < FORGET_GRACE:
                    return  # its loss, or news of it from before it went, reported late
                del self._forgotten[name]
            self.entries[name] = {"alive": alive, "since": time.monotonic()}

    def poll_gaits(self, timeout: float = 0.3, stop: threading.Event | None = None) -> None:
        """Ask each live module whether its gait runs and in which state (a STATUS and a PEEK each); ``stop`` ends
        the round early (the page is closing)."""
        for name in self.alive():
            if stop is not None and stop.is_set():
                return
            try:
                if name not in self._gait_objects:  # looked up once: a lookup by name is a few frames each way
                    self._gait_objects[name] = tuple(self.node.lookup(name, o, timeout=timeout)
                                                     for o in ("gait.service", "gait.state", "estop"))  # fmt: skip
                service, state, estop = self._gait_objects[name]
                running, index = bool(service.running), state.peek()
                latched = bool(estop.peek())
            except Exception:  # not a module (a bridge, a tool) or gone: no gait column, look it up again next time
                self._gait_objects.pop(name, None)
                continue
            with self._lock:
                if name in self.entries:
                    self.entries[name]["gait"] = (f"gait {'running' if running else 'stopped'} · state {index}"
                                                  + (" · **E-STOP latched**" if latched else ""))  # fmt: skip
                    self.entries[name]["heard"] = time.monotonic()  # it answered: heard now

    def forget(self, names: list[str]) -> None:
        """Drop nodes that were closed on purpose (the studio removed them), so they do not show as lost."""
        with self._lock:
            for name in names:
                self.entries.pop(name, None)
                self._forgotten[name] = time.monotonic()
                self._gait_objects.pop(name, None)

    def gait(self, name: str) -> str:
        with self._lock:
            return self.entries.get(name, {}).get("gait", "")

    def rows(self) -> list[tuple[str, bool, float | None]]:
        """(name, alive, seconds since last heard or since the change) sorted by name (m2 before m10)."""
        heard = getattr(self.node.transport, "last_heard", None)
        now = time.monotonic()
        with self._lock:
            items = sorted(self.entries.items(), key=lambda kv: (len(kv[0]), kv[0]))
        out = []
        for name, entry in items:
            last = heard(name) if heard is not None else None  # a CAN transport hears every frame
            last = last if last is not None else entry.get("heard", entry["since"])  # else: its last answer
            out.append((name, entry["alive"], now - last))
        return out

    def alive(self) -> list[str]:
        return [name for name, alive, _ in self.rows() if alive]

    def lost(self) -> list[str]:
        """The nodes shown LOST: heard once, not now."""
        return [name for name, alive, _ in self.rows() if not alive]

    def close(self) -> None:
        self._unlisten()


Lookup = Callable[..., Any]
"""``lookup(node, name, timeout=…)``: a client object (RobotLink.lookup, Node.lookup)."""


class StudioClock:
    """Seconds since the studio's monitor started: the one time base of every live plot.

    Each plot used to count from its own start, so two plots (or one re-targeted) ran on different scales; a robot
    restart resets the robot's own time, so that is no base either. Injectable (``now``) so a test can run a
    studio for days in a moment."""

    def __init__(self, now: Callable[[], float] = time.monotonic) -> None:
        self._now = now
        self.t0 = now()

    def __call__(self) -> float:
        return self._now() - self.t0


Labelled = list[tuple[str, list[tuple[float, float]]]]
"""A plot's series by label, each its (time, value) samples."""
PLOTTABLE = ("bool", "int", "float")
"""The codec kinds whose values a plot draws (a bool as 0 or 1)."""


class LivePlot:
    """Bounded time series of remote attributes, filled by their publications (looked up with ``lookup``, which
    the page swaps for the new robot's), timed by ``clock`` (shared by the page's plots)."""

    def __init__(self, lookup: Lookup, clock: Callable[[], float] | None = None) -> None:
        self.lookup = lookup
        self.clock = clock if clock is not None else StudioClock()
        self._lock = threading.Lock()
        self.series: dict[tuple[str, str], deque[tuple[float, float]]] = {}
        self._unsubscribe: dict[tuple[str, str], Callable[[], None]] = {}
        self.received = 0
        self.window = PLOT_SECONDS
        """Seconds shown, up to the newest sample."""

    def resolve(self, module: str, attribute: str, timeout: float = 2.0) -> Any:
        """The remote attribute ``module/attribute`` if a plot can show it: a lookup error, or ValueError for one
        whose values are not numbers (text, records: it showed "(no samples yet)" for good)."""
        remote = self.lookup(module, attribute, timeout=timeout)
        codec = getattr(remote, "codec", None)
        info = codec.describe() if codec is not None else {}
        if info.get("kind") not in PLOTTABLE:
            raise ValueError(f"{module}/{attribute} holds {info.get('spec', 'no value')}: not a number, nothing to "
                             "plot (the Monitor's value box shows it)")  # fmt: skip
        return remote

    def watch(self, module: str, attribute: str, timeout: float = 2.0) -> None:
        key = (module, attribute)
        if key in self._unsubscribe:
            return
        remote = self.resolve(module, attribute, timeout)
        buffer: deque[tuple[float, float]] = deque(maxlen=PLOT_POINTS)
        with self._lock:
            self.series[key] = buffer

        def arrived(value: Any) -> None:
            buffer.append((self.clock(), float(value)))
            self.received += 1

        self._unsubscribe[key] = remote.on_change(arrived)

    def forget(self, modules: list[str]) -> None:
        """Stop plotting every attribute of ``modules``."""
        for key in [k for k in self._unsubscribe if k[0] in modules]:
            self._unsubscribe.pop(key)()
            with self._lock:
                self.series.pop(key, None)

    def unwatch_all(self) -> None:
        for remove in self._unsubscribe.values():
            remove()
        self._unsubscribe.clear()
        with self._lock:
            self.series.clear()

    def data(self, now: float | None = None) -> tuple[list[str], tuple[np.ndarray, ...]]:
        """Labels and uPlot data: a shared time axis (every sample's time on the clock, the last ``window`` seconds
        up to ``now``), one array per series.

        Publications of different attributes arrive at different times, so each series is interpolated linearly
        between its own samples onto the shared axis, and held at its first and last value outside them. A series
        with no sample yet is all NaN: it has no value, and SeriesPlot draws no line for it (a line at 0 said it had
        one); a series' own values are never NaN (uPlot takes only null as a gap, and one NaN leaves its whole scale,
        and every line on it, undrawn)."""
        now, items, recent = self._window(now)
        items_last = {label: float(np.nan_to_num(points[-1][1])) for label, points in items if points}
        times = np.unique(np.array([t for _, points in recent for t, _ in points], dtype=float))
        if not len(times):  # nothing recent: one point at now, inside the shown window
            times = np.full(1, now)
        columns = []
        for label, points in recent:
            if not points:  # nothing recent: flat at its last value, or no value at all (none yet)
                columns.append(np.full(len(times), items_last.get(label, np.nan)))
                continue
            t, v = np.array(points, dtype=float).T
            columns.append(np.interp(times, t, np.nan_to_num(v)))
        return [label for label, _ in items], (times, *columns)

    def samples(self, now: float | None = None) -> tuple[list[str], list[PlotSamples]]:
        """Labels and each series' samples in the window (the last ``window`` seconds up to ``now``, as ``data``), as
        received: its own times on the clock and its values, nothing interpolated or held — what the exports write
        (``data`` is the drawing). A series with no sample in the window has none."""
        _, _, recent = self._window(now)
        return [label for label, _ in recent], [([t for t, _ in kept], [v for _, v in kept]) for _, kept in recent]

    def _window(self, now: float | None) -> tuple[float, Labelled, Labelled]:
        """``now`` (the clock's, if None), every series' samples, labelled, and those in the window (the last
        ``window`` seconds up to ``now``): what both the drawing (:meth:`data`) and the exports (:meth:`samples`)
        start from."""
        with self._lock:
            items = [(f"{m} {a}", list(buf)) for (m, a), buf in sorted(self.series.items())]
        now = self.clock() if now is None else now
        horizon = now - self.window
        # up to now: a sample that arrived since waits for the next refresh (past now it would be off the plot)
        return now, items, [(label, [(t, v) for t, v in points if horizon <= t <= now]) for label, points in items]

    def close(self) -> None:
        self.unwatch_all()


PlotSamples = tuple[Sequence[float], Sequence[float | int]]
"""One series of a plot as published or recorded: its sample times (s) and their values, in time order."""


def _exact(value: float | int) -> float | int:
    """A sample's value as exported: an int stays an int (a bool: 0 or 1), any other number is a float."""
    return int(value) if isinstance(value, bool | int | np.integer) else float(value)


def _cell(value: float | int) -> str:
    value = _exact(value)
    return str(value) if isinstance(value, int) else repr(value)  # repr: the float exactly ("nan", "inf" as such)


def plot_csv(labels: list[str], samples: Sequence[PlotSamples]) -> str:
    """A plot's samples (``LivePlot.samples``, ``replay.plot_samples``: each series' own) as CSV, as PlotJuggler and
    pandas read it: a ``t (s)`` column, then one column per series; a row per distinct sample time, in time order,
    and a cell left empty where that series has no sample at that time — nothing interpolated, nothing held before
    a series' first sample or after its last. Times and values are written exactly (a float's repr round-trips);
    a series with two samples at one time gives that time two rows."""
    import csv
    import io

    rows: dict[tuple[float, int], list[str]] = {}
    for k, (times, values) in enumerate(samples):
        seen: dict[float, int] = {}
        for t, value in zip(times, values, strict=True):
            t = float(t)
            repeat = seen[t] = seen.get(t, -1) + 1
            rows.setdefault((t, repeat), [""] * len(labels))[k] = _cell(value)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["t (s)", *labels])
    for (t, _), row in sorted(rows.items()):
        writer.writerow([repr(t), *row])
    return out.getvalue()


def plot_file(kind: str, labels: list[str], samples: Sequence[PlotSamples]) -> bytes:
    """A plot's samples as the file a page's Export button downloads: ``kind`` "csv" (:func:`plot_csv`) or "mcap"
    (:func:`plot_mcap`)."""
    return plot_csv(labels, samples).encode() if kind == "csv" else plot_mcap(labels, samples)


PLOT_SAMPLE_SCHEMA = {
    "title": "asm.PlotSample",
    "description": "A sample a studio plot showed, as published or recorded: its series (node and attribute) at t "
                   "seconds of the plot's clock; value null when it was not a finite number",
    "type": "object",
    "properties": {"node": {"type": "string"}, "object": {"type": "string"}, "t": {"type": "number"},
                   "value": {"type": ["number", "null"]}},
    "required": ["node", "object", "t", "value"],
}  # fmt: skip


def plot_mcap(labels: list[str], samples: Sequence[PlotSamples]) -> bytes:
    """A plot's samples (as ``plot_csv`` takes them) as MCAP, for Foxglove or PlotJuggler: one channel per series
    (``/m1/joint.angle``, as the recordings name them) holding exactly that series' samples, a JSON message each,
    its ``t`` on the plot's clock and its log time the nanoseconds since the plot's first sample (MCAP's times are
    unsigned; a live plot's clock runs up to now); written in time order, each channel's sequence counting its
    samples from 0. A value that is not a finite number (JSON has none) is null."""
    import io

    from mcap.writer import Writer

    out = io.BytesIO()
    writer = Writer(out)
    writer.start(profile="", library="asm-studio plot export")
    schema = writer.register_schema("asm.PlotSample", "jsonschema", json.dumps(PLOT_SAMPLE_SCHEMA).encode())
    messages: list[tuple[float, int, int, float | int]] = []
    channels: list[tuple[int, str, str]] = []
    for k, (label, (times, values)) in enumerate(zip(labels, samples, strict=True)):
        node, _, attribute = label.partition(" ")
        channels.append((writer.register_channel(f"/{node}/{attribute}", "json", schema), node, attribute))
        messages += [(float(t), k, seq, value) for seq, (t, value) in enumerate(zip(times, values, strict=True))]
    messages.sort(key=lambda m: m[:3])
    start = messages[0][0] if messages else 0.0
    for t, k, seq, value in messages:
        channel, node, attribute = channels[k]
        value = _exact(value)
        sample = {"node": node, "object": attribute, "t": t, "value": value if math.isfinite(value) else None}
        stamp = round((t - start) * 1e9)
        writer.add_message(channel, stamp, json.dumps(sample).encode(), stamp, seq)
    writer.finish()
    return out.getvalue()


class SeriesPlot:
    """A live plot against seconds before now, whose set of series can change (it gains a series per watched
    attribute).

    Its x scale is fixed at [-window, 0] and the data moves through it. With an automatic x scale, viser's uPlot
    component carries each plot's range from one update to the next relative to the ends of that plot's own data
    (its client's UplotComponent.tsx): two plots showed different ranges (one from its first sample, one from the
    other's), and a range that stopped following its data — reported: an axis at 34 s against samples at 853 s —
    stayed until a reload. A fixed range has nothing to carry over, and every live plot shows the same window
    ending at the same now.

    A new set of series (or window) makes a new uPlot in the same place, holding its data from the start: the page
    applies a plot's ``series`` and ``data`` as two updates, and a plot that had five series with two arrays in
    between kept a broken x scale (millions of seconds, no line) for as long as it lived."""

    def __init__(self, gui: Any, container: Any, *, title: str, y_label: str, aspect: float) -> None:
        self._gui = gui
        self._container = container
        self._title, self._y_label, self._aspect = title, y_label, aspect
        self.labels: list[str] = []
        self.silent: tuple[bool, ...] = (True,)
        """Per series: no value to draw (no sample yet, or nothing plotted)."""
        self.window = PLOT_SECONDS
        with container:
            self.handle = gui.add_uplot(data=self._empty(), series=self._series(["-"], self.silent),
                                        **self._options())  # fmt: skip
        self._order = self.handle.order

    def _options(self) -> dict[str, Any]:
        return {"title": self._title, "aspect": self._aspect, **live_axes(self._y_label, self.window)}

    def _empty(self) -> tuple[np.ndarray, ...]:
        return (np.array([-self.window, 0.0]), np.zeros(2))

    @staticmethod
    def _series(labels: list[str], silent: tuple[bool, ...]) -> tuple[dict[str, Any], ...]:
        """uPlot's series: a silent one is hidden, with no stroke (uPlot draws no line without one, even if a click
        on its legend shows it) and no points, so it neither draws nor takes part in the y scale."""
        return ({"label": "t"}, *({"label": f"{label} (no samples yet)" if label != "-" else label, "show": False,
                                   "points": {"show": False}} if quiet else {"label": label, "stroke": stroke(k)}
                                  for k, (label, quiet) in enumerate(zip(labels, silent, strict=True))))  # fmt: skip

    def show(self, labels: list[str], data: tuple[np.ndarray, ...], now: float, window: float) -> None:
        """Show ``data`` (times on the plots' clock) as seconds before ``now``, the last ``window`` of them;
        ``labels`` empty: nothing plotted. A series all NaN has no value (no sample yet): no line is drawn for it,
        and the page is sent zeros in its place (uPlot takes no NaN)."""
        if labels:
            columns = [np.asarray(column, dtype=float) for column in data[1:]]
            silent = tuple(not np.isfinite(column).any() for column in columns)
            shown = (np.asarray(data[0], dtype=float) - now, *(drawable(column) for column in columns))
        else:  # nothing plotted: one hidden series, no line (a line at 0 was drawn)
            silent, shown = (True,), (np.array([-window, 0.0]), np.zeros(2))
        if labels == self.labels and silent == self.silent and window == self.window:
            self.handle.data = shown
            return
        old = self.handle
        self.window = window
        with self._container:
            self.handle = self._gui.add_uplot(data=shown, series=self._series(labels or ["-"], silent),
                                              order=self._order, **self._options())  # fmt: skip
        old.remove()
        self.labels, self.silent = labels, silent


def drawable(column: np.ndarray) -> np.ndarray:
    """``column`` with every value that is not finite (±inf, NaN: a float attribute may publish them, a recording
    holds them) replaced by the last finite one before it (the first finite one at the start): one infinite value
    sent as 1.8e308 left uPlot's scale, and every line of the plot, undrawn. All not finite: zeros (the series is
    silent, not drawn)."""
    finite = np.isfinite(column)
    if finite.all():
        return column
    if not finite.any():
        return np.zeros_like(column)
    last = np.maximum.accumulate(np.where(finite, np.arange(len(column)), 0))
    filled = column[last]
    first = int(np.argmax(finite))
    filled[:first] = column[first]
    return filled


PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
           "#17becf")  # fmt: skip


def stroke(index: int) -> str:
    """The colour of a plot's ``index``-th series (uPlot draws no line without one)."""
    return PALETTE[index % len(PALETTE)]


def seconds_axes(y_label: str) -> dict[str, Any]:
    """uPlot options for a plot against time in seconds: uPlot's default x scale takes numbers as UNIX dates
    (and labelled 0..10 s as "1/1/70 12:00am"); the y axis carries its unit."""
    return {"scales": {"x": {"time": False}}, "axes": ({"label": "time (s)"}, {"label": y_label})}


def live_axes(y_label: str, window: float) -> dict[str, Any]:
    """uPlot options for a live plot: seconds before now on a fixed x range (see SeriesPlot), its y unit."""
    return {"scales": {"x": {"time": False, "range": (-float(window), 0.0)}},
            "axes": ({"label": "seconds before now"}, {"label": y_label})}  # fmt: skip


def empty_plot(count: int) -> tuple[np.ndarray, ...]:
    """uPlot data for a plot with ``count`` arrays (time first) and nothing to show yet."""
    return (np.array([0.0, 1.0]), *(np.zeros(2) for _ in range(count - 1)))


def describe(obj: RemoteObject) -> str:
    """One line about a remote object: its kind and type."""
    info = obj.info
    codec = getattr(info, "codec", None)
    return f"{info.kind.name.lower()} {codec.spec if codec is not None else ''}".strip()


def parse_value(obj: RemoteAttribute, text: str) -> Any:
    """A value typed in the page for ``obj``'s codec: numbers, booleans, arrays as JSON, text and bytes (hex)."""
    kind = obj.codec.describe().get("kind")
    text = text.strip()
    if kind == "bool":
        if text.lower() in ("1", "true", "yes", "on"):
            return True
        if text.lower() in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"{text!r} is not a boolean (true/false)")
    if kind == "int":
        return int(text, 0)
    if kind == "float":
        return float(text)
    if kind == "bytes":
        return bytes.fromhex(text)
    if kind == "str":
        return text
    return json.loads(text)


def format_value(value: Any) -> str:
    if isinstance(value, bytes | bytearray):
        return value.hex(" ") if len(value) <= 48 else value[:48].hex(" ") + f" … ({len(value)} bytes)"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, tuple | list):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    return str(value)
