"""Live monitoring through the dashboard's own ASM node: who is there, what their attributes hold, how they move.

Everything here goes through lookups, gets/sets and subscriptions of ``node``; nothing reaches into a module object.
Publications arrive on transport threads and only append to bounded buffers; the refresh thread formats them.
"""

from __future__ import annotations

import json
import threading
import time
from collections import deque
from collections.abc import Callable
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


class Roster:
    """Nodes seen by discovery: alive or lost, and when they were last heard."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self._lock = threading.Lock()
        self.entries: dict[str, dict[str, Any]] = {}
        self._forgotten: set[str] = set()
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
                if not alive:
                    return  # its loss, reported late
                self._forgotten.discard(name)
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
                self._forgotten.add(name)
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

    def close(self) -> None:
        self._unlisten()


Lookup = Callable[..., Any]
"""``lookup(node, name, timeout=…)``: a client object (RobotLink.lookup, Node.lookup)."""


class LivePlot:
    """Bounded time series of remote attributes, filled by their publications (looked up with ``lookup``, which
    the page swaps for the new robot's)."""

    def __init__(self, lookup: Lookup) -> None:
        self.lookup = lookup
        self._lock = threading.Lock()
        self.series: dict[tuple[str, str], deque[tuple[float, float]]] = {}
        self._unsubscribe: dict[tuple[str, str], Callable[[], None]] = {}
        self.t0 = time.monotonic()
        self.received = 0
        self.window = PLOT_SECONDS
        """Seconds shown, up to the newest sample."""

    def watch(self, module: str, attribute: str, timeout: float = 2.0) -> None:
        key = (module, attribute)
        if key in self._unsubscribe:
            return
        remote = self.lookup(module, attribute, timeout=timeout)
        buffer: deque[tuple[float, float]] = deque(maxlen=PLOT_POINTS)
        with self._lock:
            self.series[key] = buffer

        def arrived(value: Any) -> None:
            buffer.append((time.monotonic() - self.t0, float(value)))
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

    def data(self) -> tuple[list[str], tuple[np.ndarray, ...]]:
        """Labels and uPlot data: a shared time axis (every sample's time), one array per series.

        Publications of different attributes arrive at different times, so each series is interpolated linearly
        between its own samples onto the shared axis, and held at its first and last value outside them. No NaN:
        uPlot takes only null as a gap, and one NaN leaves its whole scale (and every line on it) undrawn."""
        with self._lock:
            items = [(f"{m} {a}", list(buf)) for (m, a), buf in sorted(self.series.items())]
        horizon = time.monotonic() - self.t0 - self.window
        recent = [(label, [(t, v) for t, v in points if t >= horizon]) for label, points in items]
        items_last = {label: float(np.nan_to_num(points[-1][1])) for label, points in items if points}
        times = np.unique(np.array([t for _, points in recent for t, _ in points], dtype=float))
        if not items or not len(times):
            return [label for label, _ in items], (np.zeros(1), *(np.zeros(1) for _ in items))
        columns = []
        for label, points in recent:
            if not points:  # nothing recent: flat at its last value, or zero
                last = items_last.get(label, 0.0)
                columns.append(np.full(len(times), last))
                continue
            t, v = np.array(points, dtype=float).T
            columns.append(np.interp(times, t, np.nan_to_num(v)))
        return [label for label, _ in items], (times, *columns)

    def close(self) -> None:
        self.unwatch_all()


def plot_csv(labels: list[str], data: tuple[np.ndarray, ...]) -> str:
    """What a plot shows (``LivePlot.data``'s labels and arrays) as CSV: seconds, then one column per series."""
    import csv
    import io

    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["t (s)", *labels])
    times, *columns = data
    for k, t in enumerate(times):
        writer.writerow([f"{t:.6f}", *(repr(float(c[k])) for c in columns)])
    return out.getvalue()


class SeriesPlot:
    """A plot against seconds whose set of series can change (a live plot gains a series per watched attribute).

    A new set of series makes a new uPlot in the same place, holding its data from the start: the page applies a
    plot's ``series`` and ``data`` as two updates, and a plot that had five series with two arrays in between kept
    a broken x scale (millions of seconds, no line) for as long as it lived."""

    def __init__(self, gui: Any, container: Any, *, title: str, y_label: str, aspect: float) -> None:
        self._gui = gui
        self._container = container
        self._options = {"title": title, "aspect": aspect, **seconds_axes(y_label)}
        self.labels: list[str] = ["-"]
        with container:
            self.handle = gui.add_uplot(data=empty_plot(2), series=self._series(self.labels), **self._options)
        self._order = self.handle.order

    @staticmethod
    def _series(labels: list[str]) -> tuple[dict[str, Any], ...]:
        return ({"label": "t"}, *({"label": label, "stroke": stroke(k)} for k, label in enumerate(labels)))

    def show(self, labels: list[str], data: tuple[np.ndarray, ...]) -> None:
        if labels == self.labels:
            self.handle.data = data
            return
        old = self.handle
        with self._container:
            self.handle = self._gui.add_uplot(data=data, series=self._series(labels), order=self._order,
                                              **self._options)  # fmt: skip
        old.remove()
        self.labels = labels


PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
           "#17becf")  # fmt: skip


def stroke(index: int) -> str:
    """The colour of a plot's ``index``-th series (uPlot draws no line without one)."""
    return PALETTE[index % len(PALETTE)]


def seconds_axes(y_label: str) -> dict[str, Any]:
    """uPlot options for a plot against time in seconds: uPlot's default x scale takes numbers as UNIX dates
    (and labelled 0..10 s as "1/1/70 12:00am"); the y axis carries its unit."""
    return {"scales": {"x": {"time": False}}, "axes": ({"label": "time (s)"}, {"label": y_label})}


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
