"""The dashboard: one viser page to edit a gait, preview it in MuJoCo, deploy it to modules and watch them.

Layout: the side panel (docked right) has an always-visible E-STOP button and status line, then tabs — Gait
(web/editor.py), Preview (play/pause, speed, timeline, step, reset, metrics), Deploy (web/deploy_panel.py), Drive
(web/drive.py), Monitor (roster, attribute browser, which live plot to add to). A second panel over the 3D view's
lower left shows the plots (the preview's angles and two live plots at once) and the gait control table.

Every callback either takes the document's lock or queues a request to the preview loop, and is wrapped so that an
exception becomes a notification in the page, never a dead server.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, Protocol

from asm_py.node import Node
from gaits.deploy import release_all
from gaits.model import Gait

from .deploy_panel import DeployPanel
from .document import GaitDocument
from .drive import DrivePanel
from .editor import GaitEditor
from .guard import AccessGuard, guarded_server
from .inputs import ValueInput
from .live import KinematicTwin, LiveFeed
from .monitor import (
    PLOT_SECONDS,
    WINDOWS,
    LivePlot,
    Roster,
    SeriesPlot,
    describe,
    empty_plot,
    format_value,
    seconds_axes,
)
from .preview import PreviewLoop, SceneView

log = logging.getLogger("asm_studio.web")
TOAST_SECONDS = 6.0
PANEL_WIDTH, PANEL_HEIGHT = 560, 330
"""The table-and-plots panel, floating over the 3D view's lower left (it fits a 1366×768 screen beside the side
panel)."""
LIVE_PLOTS = {"Live plot 1": "Live 1: module attributes (from the robot)",
              "Live plot 2": "Live 2: module attributes (from the robot)"}  # fmt: skip
MIN_DRAW_INTERVAL = 1 / 100


class Backend(Protocol):
    """What the page needs of the backend that builds it (server.studio.Studio is one): the page imports nothing
    of server/, so the two never import each other."""

    node: Node
    """The page's own ASM node, on Zenoh: everything it does to modules goes through it."""
    gait: Gait
    """The gait opened at start."""
    gait_text: str | None
    """The text of its file (a download keeps its comments)."""
    simulated: bool
    """The robot is simulated (it publishes poses); else a real bus."""
    robot_name: str
    """The robot's name in its Zenoh keys."""
    c_modules: str | None
    """The simulated modules that run the C runtime ("odd", "even", "all", "1,3,5"), in the robot and the preview."""

    def ensure_robot(self, gait: Gait) -> str | None:
        """Make a simulated robot the one ``gait`` describes; a message when it was rebuilt."""


class Dashboard:
    """The viser app of a Backend; see the module docstring."""

    def __init__(self, studio: Backend, *, host: str = "127.0.0.1", port: int = 8080, token: str | None = None) -> None:
        self.studio = studio
        self.node = studio.node
        self.guard = AccessGuard(host, token)
        self.server = guarded_server(self.guard, host=host, port=port, label="ASM Studio", verbose=False)
        self.port = self.server.get_port()
        self.doc = GaitDocument(studio.gait, text=studio.gait_text)
        self.loop = PreviewLoop(studio.gait, c_modules=studio.c_modules)
        self.feed = LiveFeed(studio.node.transport.session, studio.robot_name)  # type: ignore[attr-defined]
        self.view = SceneView(self.server, self.loop, self.feed)
        self.view.on_pick = self.pick_module
        self.twin: KinematicTwin | None = None
        self.roster = Roster(self.node)  # type: ignore[arg-type]
        self.plots = [LivePlot(self.node) for _ in LIVE_PLOTS]  # type: ignore[arg-type]
        self.plot = self.plots[0]
        """The first live plot (a deploy watches the modules' angles in it)."""
        self._stop = threading.Event()
        self._programmatic = threading.local()
        self._last_toast: tuple[tuple[str, str], float] | None = None
        self.toasts = 0
        """Toasts sent (a repeat within TOAST_SECONDS is not)."""
        self._value_input: ValueInput | None = None
        self._rebuild_lock = threading.RLock()
        self._build()
        self.server.on_client_connect(self._frame_camera)
        self._threads = [threading.Thread(target=self._render, name="studio-render", daemon=True),
                         threading.Thread(target=self._refresh, name="studio-refresh", daemon=True)]  # fmt: skip
        for thread in self._threads:
            thread.start()

    # -- helpers --------------------------------------------------------------------------------------------------

    def safe(self, fn: Callable[..., Any]) -> Callable[[Any], None]:
        """A callback whose failure is shown as a notification instead of escaping into viser's thread pool."""

        @functools.wraps(fn)
        def wrapped(event: Any) -> None:
            try:
                fn(event)
            except Exception as exc:
                log.info("action failed: %s", exc)
                self.notify("Error", str(exc), error=True)

        return wrapped

    def pick_module(self, module_id: int) -> None:
        """A module clicked in the 3D view: select it in the editor, the preview's plot and the attribute browser."""
        modules = self.doc.data()["modules"]
        index = next((k for k, m in enumerate(sorted(modules, key=lambda m: m["id"])) if m["id"] == module_id), None)
        if index is not None:
            self.editor.module_index.value = index + 1  # its callback resyncs the editor (and the control table)
        if module_id <= self.plot_module.max:
            self.plot_module.value = module_id
        if f"m{module_id}" in self.browse_module.options:
            self.browse_module.value = f"m{module_id}"
        self.status.content = f"Selected module {module_id}"

    def notify(self, title: str, body: str, *, error: bool = False) -> None:
        """Say it in the status line, and as a toast unless the same toast went out less than TOAST_SECONDS ago
        (typing into a field with a problem used to pile up one toast per keystroke)."""
        self.status.content = f"**{title}**: {body}"
        now = time.monotonic()
        last = self._last_toast
        if last is not None and last[0] == (title, body) and now - last[1] < TOAST_SECONDS:
            return
        self._last_toast = ((title, body), now)
        self.toasts += 1
        for client in self.server.get_clients().values():
            client.add_notification(title, body, color="red" if error else "blue", auto_close_seconds=TOAST_SECONDS)

    def resolved(self, title: str, now: str) -> None:
        """The problem the status line reports under ``title`` is gone: say ``now`` instead (one status, current)."""
        if self.status.content.startswith(f"**{title}**"):
            self.status.content = now
            self._last_toast = None

    def _frame_camera(self, client: Any) -> None:
        """Look at the robot from close enough to see its modules move."""
        robot = self.doc.data()["robot"]
        size = float(robot.get("modules", 8)) * float(robot.get("module_size", 0.05))
        client.camera.position = (0.4 * size + 0.3, -0.9 * size - 0.4, 0.4 * size + 0.3)
        client.camera.look_at = (0.0, 0.0, 0.05)

    # -- layout ---------------------------------------------------------------------------------------------------

    def _build(self) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large")
        self.estop = gui.add_button("E-STOP", color="red", hint="stop every module's gait and hold its joint")
        self.estop.on_click(self.safe(self._on_estop))
        self.release = gui.add_button("Release e-stop", color="green", hint="let every module move again (asks first)")
        self.release.on_click(self.safe(self._on_release))
        self.status = gui.add_markdown("Ready.")
        hint = "the edited gait in the preview simulation, or the robot itself"
        self.source = gui.add_button_group("View", ["Preview", "Live"], hint=hint)
        self.source.on_click(self.safe(lambda e: self.show(e.target.value.lower())))
        self.source_md = gui.add_markdown("Showing: **Preview** (the edited gait, simulated here)")
        self._build_panel()
        tabs = gui.add_tab_group()
        with tabs.add_tab("Gait"):
            self.editor = GaitEditor(self, initial=self.studio.gait.name)
        with tabs.add_tab("Preview"):
            self._build_preview()
        with tabs.add_tab("Deploy"):
            self.deployer = DeployPanel(self)
        with tabs.add_tab("Drive"):
            self.drive = DrivePanel(self)
        with tabs.add_tab("Monitor"):
            self._build_monitor()
        self._build_keys()
        self.editor.sync()

    def _build_panel(self) -> None:
        """A second panel over the 3D view's lower left: the gait control table and the plots, where there is room
        (the side panel keeps the controls). It can be moved, docked or minimized like any viser panel."""
        gui = self.server.gui
        gui.main_panel.dock_right()
        self.panel = gui.add_panel()
        self.plots_tab = self.panel.add_tab("Plots")  # first: what the page shows at once
        self.table_tab = self.expanded_tab = self.panel.add_tab("Control table")
        self.panel.float(x=12, y=-12, width=PANEL_WIDTH, height=PANEL_HEIGHT)

    def _build_keys(self) -> None:
        """Keyboard shortcuts, as viser's command-palette hotkeys (a key typed into a field stays the field's)."""
        keys = (
            ("Play / pause the preview", "space", None, lambda: self.loop.request("play", not self.loop.playing)),
            ("Step the preview back", "arrowleft", "shift", lambda: self.loop.request("step", -1)),
            ("Step the preview forward", "arrowright", "shift", lambda: self.loop.request("step", 1)),
            ("Undo the last edit", "Z", "cmd/ctrl", lambda: self.editor.history("Undo")),
            ("Redo", "Z", "cmd/ctrl+shift", lambda: self.editor.history("Redo")),
        )

        def add(label: str, key: str, action: Any, modifier: str | None = None) -> None:
            command = self.server.gui.add_command(label, hotkey=key, modifier=modifier)  # type: ignore[arg-type]
            command.on_trigger(self.safe(lambda _: action()))

        for label, key, modifier, action in keys:
            add(label, key, action, modifier)
        self.drive.bind_keys(add)  # the arrow keys drive

    def _build_preview(self) -> None:
        gui = self.server.gui
        self.play = gui.add_button_group("Playback", ["Play", "Pause", "Reset"])
        self.play.on_click(self.safe(self._on_play))
        self.speed = gui.add_slider("Speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
        self.speed.on_update(self.safe(lambda e: self.loop.request("speed", e.target.value)))
        self.timeline = gui.add_slider("Preview timeline (frame)", min=0, max=1, step=1, initial_value=0)
        self.timeline.on_update(self.safe(self._on_seek))
        steps = gui.add_button_group("Step", ["◀ back", "forward ▶"])
        steps.on_click(self.safe(lambda e: self.loop.request("step", -1 if "back" in e.target.value else 1)))
        rich = gui.add_checkbox("Shadows and reflections", initial_value=False,
                                hint="nicer, but slow in a browser without a GPU")  # fmt: skip
        rich.on_update(self.safe(lambda e: self.view.set_rich(bool(e.target.value))))
        follow = gui.add_checkbox("Follow the robot", initial_value=True,
                                  hint="keep the robot in the middle; the ground moves under it")  # fmt: skip
        follow.on_update(self.safe(lambda e: setattr(self.view, "follow", bool(e.target.value))))
        labels = gui.add_checkbox("Module labels", initial_value=True, hint="each module's name at its joint")
        labels.on_update(self.safe(lambda e: self.view.set_labels(bool(e.target.value))))
        self.metrics = gui.add_markdown("")
        self.plot_module = gui.add_slider("Plot module", min=1, max=max(2, self.doc.gait().robot.modules), step=1,
                                          initial_value=1)  # fmt: skip
        with self.plots_tab:
            self.angles = gui.add_uplot(data=empty_plot(3),
                                        series=({"label": "t"}, {"label": "commanded", "stroke": "orange"},
                                                {"label": "measured", "stroke": "steelblue"}),
                                        title="Preview: joint angle (deg)", aspect=3.0,
                                        **seconds_axes("degrees"))  # fmt: skip

    def _build_monitor(self) -> None:
        gui = self.server.gui
        self.roster_md = gui.add_markdown("")
        with gui.add_folder("Attribute browser"):
            self.browse_module = gui.add_dropdown("Node", ["-"])
            self.browse_object = gui.add_dropdown("Object", ["-"])
            self.browse_object.on_update(self.safe(lambda _: None if self.syncing else self._choose()))
            self.browse_value = gui.add_markdown("")
            self.value_folder = gui.add_folder("Value")
            actions = gui.add_button_group("Browse", ["List", "Get", "Set", "Plot"])
            actions.on_click(self.safe(self._on_browse))
        self.plot_into = gui.add_dropdown("Plot into", list(LIVE_PLOTS), hint="which live plot Plot adds to")
        self.window = gui.add_dropdown("Window (s)", [f"{w:g}" for w in WINDOWS], initial_value=f"{PLOT_SECONDS:g}")
        self.window.on_update(self.safe(lambda e: [setattr(p, "window", float(e.target.value)) for p in self.plots]))
        self.freeze = gui.add_checkbox("Pause the live plots", initial_value=False,
                                       hint="hold the plots still to read them; the samples keep arriving")  # fmt: skip
        clear = gui.add_button_group("Clear", list(LIVE_PLOTS))
        clear.on_click(self.safe(lambda e: self.plots[list(LIVE_PLOTS).index(e.target.value)].unwatch_all()))
        # several plots at once, one under the other
        self.lives = [SeriesPlot(gui, self.plots_tab, title=title, y_label="value", aspect=3.0)
                      for title in LIVE_PLOTS.values()]  # fmt: skip

    @contextlib.contextmanager
    def programmatic(self) -> Iterator[None]:
        """Controls set by the server (not the user) inside this block: their update callbacks do nothing.

        viser calls a control's callbacks synchronously, in the thread that sets its value: the flag is that
        thread's alone. (It was one flag for the process: a user's edit arriving on viser's thread pool while the
        20 Hz refresh was setting the timeline was taken for the server's own and silently dropped.) The lock
        keeps the editor's resync and the refresh from interleaving."""
        with self._rebuild_lock:
            outer = self.syncing
            self._programmatic.active = True
            try:
                yield
            finally:
                self._programmatic.active = outer

    @property
    def syncing(self) -> bool:
        """True in a thread that is setting controls itself (see :meth:`programmatic`)."""
        return getattr(self._programmatic, "active", False)

    # -- preview, deploy, monitor ---------------------------------------------------------------------------------

    def _on_play(self, event: Any) -> None:
        kind = event.target.value
        self.loop.request("reset" if kind == "Reset" else "play", kind == "Play")

    def _on_seek(self, event: Any) -> None:
        if not self.syncing:  # a user's drag scrubs (and pauses); the refresh moving the slider does not
            self.loop.request("seek", int(event.target.value))

    def show(self, source: str) -> None:
        """Show the "preview" or the "live" robot in the 3D view (and say which, under the buttons).

        A real robot sends no poses: its Live view is a kinematic twin of the edited gait's robot, posed from the
        modules' joint.angle publications (made once, on the first look)."""
        if source == "live" and not self.studio.simulated and self.twin is None:
            self.twin = KinematicTwin(self.doc.gait())
            self.twin.follow(self.feed, self.node)
        self.view.set_source(source)
        # the preview simulation pauses while the live robot is shown (its CPU is the live view's), and plays again
        self.loop.request("play", source == "preview")
        self._show_source()

    def _show_estop(self) -> None:
        latched = self.feed.status.estop if self.feed.status is not None else None
        label = f"E-STOP — LATCHED on {len(latched)} modules" if latched else "E-STOP"
        if self.estop.label != label:
            self.estop.label = label

    def _show_source(self) -> None:
        if self.view.source == "live":
            kind = "simulated" if self.studio.simulated else "real: no poses, angles only"
            shown = f"Showing: **Live** (the robot, {kind})"
        else:
            shown = "Showing: **Preview** (the edited gait, simulated here)"
        content = shown + self._live_line()
        if self.source_md.content != content:
            self.source_md.content = content
        self._show_estop()

    def _on_estop(self, _: Any) -> None:
        self.node.estop("studio E-STOP")  # type: ignore[union-attr]
        self.notify("E-STOP", "sent to every module: gaits stopped, joints holding", error=True)

    def modules(self) -> list[str]:
        """The module nodes the roster sees alive (m1, m2, …)."""
        return [n for n in self.roster.alive() if n.startswith("m") and n[1:].isdigit()]

    def confirm(self, event: Any, title: str, lines: list[str], yes: str, color: str, action: Any) -> None:
        """Ask the user who clicked first: a dialog with ``lines``, a ``yes`` button running ``action``, and Cancel."""
        gui = event.client.gui
        with gui.add_modal(title) as modal:
            for line in lines:
                gui.add_markdown(line)
            go = gui.add_button(yes, color=color)
            cancel = gui.add_button("Cancel")

            @go.on_click
            def _(_: Any) -> None:
                modal.close()
                self.safe(lambda __: action())(None)

            cancel.on_click(lambda _: modal.close())

    def _on_release(self, event: Any) -> None:
        modules = self.modules()
        lines = [f"Every module ({len(modules)}) may move again: joints stay where they hold and nothing starts until "
                 "you start or deploy a gait."]  # fmt: skip
        self.confirm(event, "Release the emergency stop?", lines, "Yes, release", "green",
                      lambda: self._release(modules))  # fmt: skip

    def _release(self, modules: list[str]) -> None:
        released = release_all(self.node, modules)  # type: ignore[arg-type]
        self.notify("E-STOP released", f"released on {len(released)} of {len(modules)} modules")

    def _on_browse(self, event: Any) -> None:
        action = event.target.value
        if action == "List" or self._value_input is None:
            self._list()
            return
        value = self._value_input
        if action == "Get":
            self.browse_value.content = (
                f"`{value.obj.name}` ({describe(value.obj)}) = **{format_value(value.refresh())}**"
            )
        elif action == "Set":
            try:
                written = value.write()
            except (ValueError, TypeError) as exc:  # refused in the page: nothing was sent to the module
                self.browse_value.content = f"⚠ `{value.obj.name}` not set: {exc}"
                raise
            self.browse_value.content = f"`{value.obj.name}` set to **{format_value(written)}**"
        else:
            self.plots[list(LIVE_PLOTS).index(self.plot_into.value)].watch(self.browse_module.value, value.obj.name)
            self.panel.expand()

    def _list(self) -> None:
        """List the chosen node's objects and choose the first."""
        objects = self.node.list_objects(self.browse_module.value, timeout=2.0)  # type: ignore[union-attr]
        with self.programmatic():
            self.browse_object.options = [o.name for o in objects] or ["-"]
        self.browse_value.content = "  \n".join(f"`{o.name}` {describe(o)}" for o in objects)
        if objects:
            self._choose()

    def _choose(self) -> None:
        """Show an input that fits the chosen object's type, holding its current value."""
        if self._value_input is not None:
            self._value_input.remove()
            self._value_input = None
        obj = self.node.lookup(self.browse_module.value, self.browse_object.value, timeout=2.0)  # type: ignore[union-attr]
        with self.value_folder:
            self._value_input = ValueInput(self.server.gui, obj)

    # -- threads --------------------------------------------------------------------------------------------------

    def _render(self) -> None:
        """Draw each frame the preview records, as it is recorded: at speed 1 the loop records 60 frames a second
        and each is drawn once (a fixed 60 Hz clock beating against the loop's would skip some and repeat others);
        faster playback is drawn at most every MIN_DRAW_INTERVAL."""
        last = 0.0
        while not self._stop.is_set():
            if not self.view.wait_changed(timeout=0.1):
                continue
            pause = last + MIN_DRAW_INTERVAL - time.monotonic()
            if pause > 0 and self._stop.wait(pause):
                return
            last = time.monotonic()
            try:
                self.view.draw()
            except Exception:
                log.exception("drawing the preview failed")

    def _refresh(self) -> None:
        ticks = 0
        while not self._stop.wait(0.05):  # 20 Hz
            ticks += 1
            try:
                self._refresh_once()
                if ticks % 20 == 0:  # once a second: every module's gait status, by asking it
                    self.roster.poll_gaits()
            except Exception:
                log.exception("refreshing the dashboard failed")

    def _refresh_once(self) -> None:
        loop = self.loop
        m = loop.metrics()
        frames = len(loop.frames)
        warning = f"  \n⚠ {loop.error}" if loop.error else ""
        self.metrics.content = (f"Preview: t = {m.seconds:.2f} s · distance **{m.distance:.3f} m** "
                                f"({m.body_lengths:.2f} BL) · speed **{m.speed:.3f} m/s** · heading {m.heading:.0f}° · "
                                f"peak torque {m.peak_torque:.2f} N·m{warning}")  # fmt: skip
        self._show_source()
        with self.programmatic():
            self.drive.sync(loop.sim.gait)
            modules = max(2, loop.sim.gait.robot.modules)
            if self.plot_module.max != modules:
                self.plot_module.max = modules
            self.timeline.max = max(1, frames - 1)
            if loop.cursor is None:
                self.timeline.value = max(0, frames - 1)
        t, goal, angle = loop.series(int(self.plot_module.value) - 1)
        self.angles.data = (t, goal, angle)
        shown = loop.shown()
        with contextlib.suppress(ValueError):  # a gait with no single period has no cursor
            self.editor.draw_control_table(cursor=None if shown is None else shown.time / loop.sim.gait.period)
        rows = self.roster.rows()
        names = [n for n, _, _ in rows]
        if names and list(self.browse_module.options) != names:
            self.browse_module.options = names
        self.roster_md.content = "**Nodes**  \n" + "  \n".join(
            f"{'🟢' if alive else '🔴'} `{name}` {'live' if alive else 'LOST'} · last heard {age:.1f} s ago"
            f"{' · ' + self.roster.gait(name) if self.roster.gait(name) else ''}"
            for name, alive, age in rows
        )  # fmt: skip
        for plot, live in zip(self.plots, self.lives, strict=True):
            labels, data = plot.data()
            if labels and not self.freeze.value:
                live.show(labels, data)

    def _live_line(self) -> str:
        status = self.feed.status
        if status is None:
            return "  \nLive: no status from the robot yet"
        moved, speed = self.feed.speed()
        rtf = "" if status.real_time_factor is None else f" · real-time factor {status.real_time_factor:.2f}"
        latched = f" · **E-STOP latched** on {len(status.estop)} modules" if status.estop else ""
        behind = " · ⚠ the simulation cannot keep up with real time" if status.behind else ""
        return (f"  \nLive: {status.mode} robot, {status.modules} modules{rtf} · moved {moved:.3f} m in the last "
                f"10 s ({speed:.3f} m/s){latched}{behind}")  # fmt: skip

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5)
        for plot in self.plots:
            plot.close()
        self.roster.close()
        self.feed.close()
        self.loop.close()
        self.server.stop()
