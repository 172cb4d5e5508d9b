"""The Monitor tab: the roster, an attribute browser whose input fits each type, and which live plot an attribute
joins — every read and write through the page's robot link (web/link.py), never into a module object."""

from __future__ import annotations

import json
import logging
import threading
import time
from typing import TYPE_CHECKING, Any

from asm_module.names import module_name

from .confirm import plain
from .inputs import ValueInput
from .layout_store import VERSION, LayoutStore, check_version, read_layout
from .monitor import (
    PLOT_SECONDS,
    WINDOWS,
    LivePlot,
    SeriesPlot,
    StudioClock,
    describe,
    format_value,
    plot_file,
)
from .recording import utf8_text

if TYPE_CHECKING:
    from gaits.model import Gait

    from .page import Page

log = logging.getLogger("asm_studio.monitor")
LIST_RETRY = 2.0
"""Seconds between the page's own tries to list the chosen node's objects while none are listed (and to restore
the last layout while the robot does not answer)."""
RESTORE_TRIES = 15
LIVE_PLOTS = {"Live plot 1": "Live 1: module attributes (from the robot)",
              "Live plot 2": "Live 2: module attributes (from the robot)"}  # fmt: skip


def check_layout(layout: Any) -> None:
    """What a layout of this page is, or ValueError saying what it lacks: a JSON object of a version this studio
    reads, plots among LIVE_PLOTS, each plotted attribute node/attribute, a window of WINDOWS."""
    if not isinstance(layout, dict):
        raise ValueError("not a JSON object")
    check_version(layout)
    plots, window = layout.get("plots"), layout.get("window", PLOT_SECONDS)
    if not isinstance(plots, dict) or set(plots) - set(LIVE_PLOTS) or window not in WINDOWS:
        raise ValueError(f"a layout has plots named among {sorted(LIVE_PLOTS)} and a window of one of "
                         f"{list(WINDOWS)} s")  # fmt: skip
    if any(not isinstance(keys, list) or any(len(str(k).split("/", 1)) != 2 for k in keys) for keys in plots.values()):
        raise ValueError("each plot is a list of node/attribute names")


class MonitorPanel:
    """The Monitor tab of ``page``; the live plots it feeds are drawn in the page's plots panel."""

    def __init__(self, page: Page, plots_tab: Any) -> None:
        self.page = page
        gui = page.gui
        self.clock = StudioClock()
        """The live plots' one time base (the studio's, not a robot's: a restarted robot starts again at 0)."""
        self.plots = [LivePlot(page.robot.lookup, self.clock) for _ in LIVE_PLOTS]
        self.roster_md = gui.add_markdown("")
        forget = gui.add_button("Forget lost nodes", hint="drop the nodes shown LOST from this list and the plots (a "
                                "module renumbered by another tool, a board unplugged on purpose)")  # fmt: skip
        forget.on_click(page.safe(lambda _: self.forget_lost()))
        with gui.add_folder("Attribute browser"):
            self.browse_module = gui.add_dropdown("Node", ["-"])
            self.browse_object = gui.add_dropdown("Object", ["-"])
            self.browse_module.on_update(page.safe(lambda _: None if page.syncing else self.list_objects()))
            self.browse_object.on_update(page.safe(lambda _: None if page.syncing else self._choose()))
            self.browse_value = gui.add_markdown("")
            self.value_folder = gui.add_folder("Value")
            actions = gui.add_button_group("Browse", ["List", "Get", "Set", "Plot"])
            actions.on_click(page.safe(self._on_browse))
        self.plot_into = gui.add_dropdown("Plot into", list(LIVE_PLOTS), hint="which live plot Plot adds to")
        self.window = gui.add_dropdown("Window (s)", [f"{w:g}" for w in WINDOWS], initial_value=f"{PLOT_SECONDS:g}")
        self.window.on_update(page.safe(lambda e: [setattr(p, "window", float(e.target.value)) for p in self.plots]))
        self.freeze = gui.add_checkbox("Pause the live plots", initial_value=False,
                                       hint="hold the plots still to read them; the samples keep arriving")  # fmt: skip
        export = gui.add_button_group("Export CSV", list(LIVE_PLOTS), hint="download what the plot shows")
        export.on_click(page.safe(lambda e: self._export(e, "csv")))
        export_mcap = gui.add_button_group("Export MCAP", list(LIVE_PLOTS), hint="the same, for Foxglove")
        export_mcap.on_click(page.safe(lambda e: self._export(e, "mcap")))
        gui.add_button("Save layout (.json)").on_click(page.safe(lambda e: e.client.send_file_download(
            "asm-layout.json", json.dumps(self.layout(), indent=2).encode(), save_immediately=True)))  # fmt: skip
        load = gui.add_upload_button("Load layout (.json)", mime_type=".json")
        load.on_upload(page.safe(self._on_load))
        self.layout_line = gui.add_markdown("")
        """Why the layout is not kept in its file (the file is not a layout, or cannot be written): said by the
        layout buttons for as long as it lasts (a toast goes, and no browser may be open when the studio starts)."""
        clear = gui.add_button_group("Clear", list(LIVE_PLOTS))
        clear.on_click(page.safe(lambda e: self.plots[list(LIVE_PLOTS).index(e.target.value)].unwatch_all()))
        # several plots at once, one under the other
        self.lives = [SeriesPlot(gui, plots_tab, title=title, y_label="value", aspect=3.0)
                      for title in LIVE_PLOTS.values()]  # fmt: skip
        self._value_input: ValueInput | None = None
        self._browsing = threading.RLock()  # the user's choices (viser's pool) and the refresh's own listing
        self._listing = threading.Lock()
        """Held by the refresh's own listing (one at a time)."""
        self._listed_at = -LIST_RETRY
        self._restored_at = -LIST_RETRY
        self.store = LayoutStore(page.layout_file, check=check_layout)
        self._restoring: dict[str, Any] | None = self.store.load()
        """The layout the studio showed when it last ran, plotted again once the robot answers (None: done)."""
        self._restore_tries = 0
        self._said_store: str | None = None
        self._say_store()
        page.on("relinked", self.relink)
        page.on("modules_removed", self.forget)
        page.on("deployed", self.watch_angles)
        page.on("pick", lambda module_id: self.select(f"m{module_id}"))

    @property
    def plot(self) -> LivePlot:
        """The first live plot (a deploy watches the modules' angles in it)."""
        return self.plots[0]

    def layout(self) -> dict[str, Any]:
        """Which attributes each live plot shows, and the window: what Save layout writes."""
        return {"version": VERSION, "window": self.plots[0].window,
                "plots": {name: [f"{m}/{a}" for m, a in sorted(plot.series)]
                          for name, plot in zip(LIVE_PLOTS, self.plots, strict=True)}}  # fmt: skip

    def _on_load(self, event: Any) -> None:
        """Load layout: the uploaded file, named in what is said of it (a refusal changes nothing)."""
        uploaded = event.target.value
        name = str(uploaded.name)
        try:
            self.apply_layout(read_layout(uploaded.content, name, check_layout), name)
        except ValueError as exc:  # said on the page: the file's name is the user's text
            raise ValueError(plain(utf8_text(str(exc)))) from None

    def apply_layout(self, layout: Any, source: str = "the layout") -> None:
        """Plot what a saved layout names (ValueError naming ``source``, nothing changed, for one that is not)."""
        try:
            check_layout(layout)
        except ValueError as exc:
            raise ValueError(f"{source} is not a layout: {exc}") from None
        window = layout.get("window", PLOT_SECONDS)
        wanted = {name: [str(k).split("/", 1) for k in keys] for name, keys in layout["plots"].items()}
        for name, keys in wanted.items():  # every attribute found and plottable first: a refusal changes nothing
            for module, attribute in keys:  # (the plots were emptied, half refilled and the half saved)
                try:
                    self.plots[list(LIVE_PLOTS).index(name)].resolve(module, attribute)
                except Exception as exc:  # a lookup's error, a module not there, text: said, nothing changed
                    raise ValueError(f"{source}: {module}/{attribute} cannot be plotted ({exc}); nothing was "
                                     "changed") from None  # fmt: skip
        for name, keys in wanted.items():
            plot = self.plots[list(LIVE_PLOTS).index(name)]
            plot.unwatch_all()
            for module, attribute in keys:
                plot.watch(module, attribute)
        for plot in self.plots:
            plot.window = float(window)
        with self.page.programmatic():
            self.window.value = f"{float(window):g}"
        self.page.notify("Layout", f"{plain(utf8_text(source))} loaded: {sum(len(k) for k in wanted.values())} "
                         "plotted attributes")  # fmt: skip

    def _keep_layout(self) -> None:
        """Keep the layout in the store whenever it changes; first restore the last one (off the refresh thread,
        a try every LIST_RETRY s while the robot's modules do not answer yet, RESTORE_TRIES at most)."""
        if self._restoring is None:
            self.store.save(self.layout())
            self._say_store()
            return
        now = time.monotonic()
        if self._listing.locked() or now - self._restored_at < LIST_RETRY or not self.page.robot.roster.alive():
            return
        self._restored_at = now
        threading.Thread(target=self._restore, name="studio-restore-layout", daemon=True).start()

    def _say_store(self) -> None:
        """The store's trouble (a file there that is not a layout, or one that cannot be written) by the layout
        buttons and as a notice, once; the line goes when the trouble does."""
        refused = self.store.refused
        if refused == self._said_store:
            return
        self._said_store = refused
        self.layout_line.content = "" if refused is None else f"⚠ **Layout**: {plain(utf8_text(refused))}"
        if refused is not None:
            self.page.notify("Layout", plain(utf8_text(refused)), error=True)

    def _restore(self) -> None:
        if self._restoring is None or not self._listing.acquire(blocking=False):
            return
        try:
            self.apply_layout(self._restoring, str(self.store.path))
            self.page.notify("Layout", f"the last one restored (from {plain(utf8_text(str(self.store.path)))})")
            self._restoring = None
        except Exception as exc:  # the modules not up yet, or a layout no longer valid: said at the last try
            self._restore_tries += 1
            if self._restore_tries >= RESTORE_TRIES:
                self._restoring = None
                self.store.spare(self.layout())  # the file keeps the layout not restored (it was written over)
                where = plain(utf8_text(str(self.store.path)))
                self.page.notify("Layout", f"the last one ({where}) was not restored: {plain(utf8_text(str(exc)))}",
                                 error=True)  # fmt: skip
        finally:
            self._listing.release()

    def _export(self, event: Any, kind: str) -> None:
        """Download what a live plot shows now (its window) as CSV or MCAP, to the tab that asked: each series'
        samples as received, never the drawing's interpolated or held values."""
        index = list(LIVE_PLOTS).index(event.target.value)
        labels, samples = self.plots[index].samples()
        if not labels:
            raise ValueError(f"{event.target.value} plots nothing yet: Plot an attribute into it first")
        content = plot_file(kind, labels, samples)
        event.client.send_file_download(f"live-plot-{index + 1}.{kind}", content, save_immediately=True)

    def watch_angles(self, gait: Gait) -> None:
        """A gait was deployed: plot its first modules' joint.angle."""
        for assignment in gait.modules[:4]:
            self.plot.watch(module_name(assignment.id), "joint.angle")

    def forget_lost(self) -> list[str]:
        """Every node shown LOST leaves the roster and the plots (the robot can tell a node gone on purpose from one
        lost only when the page made it go: another tool's renumbering looks like a loss); the names forgotten."""
        lost = self.page.robot.roster.lost()
        if lost:
            self.page.robot.forget(lost)
            self.page.emit("modules_removed", lost)
        return lost

    def forget(self, modules: list[str]) -> None:
        """Modules gone for good (the robot was rebuilt smaller): no longer plotted."""
        for plot in self.plots:
            plot.forget(modules)

    def relink(self) -> None:
        """The page now shows another robot: the plots follow its modules, the browser starts afresh."""
        for plot in self.plots:
            plot.unwatch_all()
            plot.lookup = self.page.robot.lookup
        if self._value_input is not None:
            self._value_input.remove()
            self._value_input = None
        with self.page.programmatic():
            self.browse_module.options = ["-"]
            self.browse_object.options = ["-"]
        self.browse_value.content = ""

    def _on_browse(self, event: Any) -> None:
        action = event.target.value
        if action == "List" or self._value_input is None:
            self.list_objects()
            return
        value = self._value_input
        if action == "Get":
            self.browse_value.content = (
                f"`{value.obj.name}` ({describe(value.obj)}) = **{format_value(value.refresh())}**"
            )
        elif action == "Set":
            where = f"{self.browse_module.value}/{value.obj.name}"
            try:
                written = value.write()
            except Exception as exc:  # refused in the page or by the module, or no answer: said under "Set"
                self.browse_value.content = f"⚠ `{value.obj.name}` not set: {exc}"
                self.page.notify("Set", f"{where}: {exc}", error=True)
                return
            self.browse_value.content = f"`{value.obj.name}` set to **{format_value(written)}**"
            # the refusal of an earlier Set is over: the status line says so (it stayed, even after a reload)
            self.page.resolved("Set", f"{where} set to {format_value(written)}")
        else:
            self.plots[list(LIVE_PLOTS).index(self.plot_into.value)].watch(self.browse_module.value, value.obj.name)
            self.page.emit("plotted")

    def list_objects(self) -> None:
        """List the chosen node's objects and choose the first."""
        with self._browsing:
            self._list_objects()

    def _list_by_itself(self, names: list[str]) -> None:
        """While the chosen node's objects are not listed, list them without a click on List: off the refresh
        thread, one try at a time, every LIST_RETRY seconds. Listing once, when the roster first named a node, left
        "-" for good whenever that try failed (a robot still starting, a node answering late)."""
        now = time.monotonic()
        if (not names or self.browse_module.value not in names or list(self.browse_object.options) != ["-"]
                or self._listing.locked() or now - self._listed_at < LIST_RETRY):  # fmt: skip
            return
        self._listed_at = now
        threading.Thread(target=self._list_quietly, name="studio-list-objects", daemon=True).start()

    def _list_quietly(self) -> None:
        if not self._listing.acquire(blocking=False):
            return
        try:
            self.list_objects()
        except Exception as exc:  # not answering yet, or gone: tried again LIST_RETRY s on; List says why
            log.debug("listing the objects of %s failed: %s", self.browse_module.value, exc)
        finally:
            self._listing.release()

    def _list_objects(self) -> None:
        if self.browse_module.value == "-":
            return
        objects = self.page.robot.list_objects(self.browse_module.value, timeout=2.0)
        with self.page.programmatic():
            self.browse_object.options = [o.name for o in objects] or ["-"]
        self.browse_value.content = "  \n".join(f"`{o.name}` {describe(o)}" for o in objects)
        if objects:
            self._choose_now()

    def _choose(self) -> None:
        """Show an input that fits the chosen object's type, holding its current value."""
        with self._browsing:
            self._choose_now()

    def _choose_now(self) -> None:
        if self._value_input is not None:
            self._value_input.remove()
            self._value_input = None
        if self.browse_object.value == "-":
            return
        obj = self.page.robot.lookup(self.browse_module.value, self.browse_object.value, timeout=2.0)
        with self.value_folder:
            self._value_input = ValueInput(self.page.gui, obj)

    def select(self, module: str) -> None:
        """A module picked elsewhere (the 3D view): browse it."""
        if module in self.browse_module.options:
            self.browse_module.value = module

    def refresh(self) -> None:
        """The roster, the browser's node list and the live plots, now (the page's 20 Hz refresh)."""
        roster = self.page.robot.roster
        rows = roster.rows()
        names = [n for n, _, _ in rows]
        if names and list(self.browse_module.options) != names:
            with self.page.programmatic():
                self.browse_module.options = names
        self._list_by_itself(names)
        others = sorted(roster.tools)
        watching = f"  \nAlso attached: {', '.join(others)}" if others else ""
        self.roster_md.content = "**Nodes**" + watching + "  \n" + "  \n".join(
            f"{'🟢' if alive else '🔴'} `{name}` {'live' if alive else 'LOST'} · last heard {age:.1f} s ago"
            f"{' · ' + roster.gait(name) if roster.gait(name) else ''}"
            for name, alive, age in rows
        )  # fmt: skip
        self._keep_layout()
        now = self.clock()  # one now for every plot: their windows end at the same instant
        for plot, live in zip(self.plots, self.lives, strict=True):
            labels, data = plot.data(now)
            if self.freeze.value:
                continue
            live.show(labels, data, now, plot.window)  # cleared: its lines go too (they stayed after Clear)

    def close(self) -> None:
        for plot in self.plots:
            plot.close()
