"""The dashboard: one viser page to edit a gait, preview it in MuJoCo, deploy it to modules and watch them.

Layout: an always-visible E-STOP button and status line, then tabs — Gait (library/upload, automaton state editor,
module phases and directions, robot, undo/redo, download, the table view and the expanded table plot), Preview
(play/pause, speed, timeline, step, reset, metrics, commanded vs measured angle), Deploy (progress, verify, start,
stop), Monitor (roster, attribute browser, live plot).

Every callback either takes the document's lock or queues a request to the preview loop, and is wrapped so that an
exception becomes a notification in the page, never a dead server.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import viser

from gaits.deploy import deploy, module_name, start_all, stop_all
from gaits.model import GaitError, load
from gaits.table import expand

from .document import GaitDocument
from .monitor import LivePlot, Roster, describe, format_value, parse_value
from .preview import PreviewLoop, SceneView

if TYPE_CHECKING:
    from server.studio import Studio

log = logging.getLogger("asm_studio.web")
LIBRARY = Path(__file__).resolve().parent.parent / "gaits" / "library"
FRAME_PERIOD = 1 / 60


class Dashboard:
    """The viser app of a Studio; see the module docstring."""

    def __init__(self, studio: Studio, *, host: str = "127.0.0.1", port: int = 8080) -> None:
        self.studio = studio
        self.node = studio.node
        self.server = viser.ViserServer(host=host, port=port, label="ASM Studio", verbose=False)
        self.port = self.server.get_port()
        self.doc = GaitDocument(studio.gait)
        self.loop = PreviewLoop(studio.gait)
        self.view = SceneView(self.server, self.loop)
        self.roster = Roster(self.node)  # type: ignore[arg-type]
        self.plot = LivePlot(self.node)  # type: ignore[arg-type]
        self._stop = threading.Event()
        self._syncing = False
        self._rebuild_lock = threading.RLock()
        self._build()
        self.server.on_client_connect(self._frame_camera)
        self._threads = [threading.Thread(target=self._render, name="studio-render", daemon=True),
                         threading.Thread(target=self._refresh, name="studio-refresh", daemon=True)]  # fmt: skip
        for thread in self._threads:
            thread.start()

    # -- helpers --------------------------------------------------------------------------------------------------

    def _safe(self, fn: Callable[..., Any]) -> Callable[[Any], None]:
        """A callback whose failure is shown as a notification instead of escaping into viser's thread pool."""

        @functools.wraps(fn)
        def wrapped(event: Any) -> None:
            try:
                fn(event)
            except Exception as exc:
                log.info("action failed: %s", exc)
                self.notify("Error", str(exc), error=True)

        return wrapped

    def notify(self, title: str, body: str, *, error: bool = False) -> None:
        self.status.content = f"**{title}**: {body}"
        for client in self.server.get_clients().values():
            client.add_notification(title, body, color="red" if error else "blue", auto_close_seconds=6.0)

    def _frame_camera(self, client: Any) -> None:
        """Look at the robot from close enough to see its modules move."""
        size = self.doc.gait().robot.modules * self.doc.gait().robot.module_size
        client.camera.position = (0.4 * size + 0.3, -0.9 * size - 0.4, 0.4 * size + 0.3)
        client.camera.look_at = (0.0, 0.0, 0.05)

    # -- layout ---------------------------------------------------------------------------------------------------

    def _build(self) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large")
        self.estop = gui.add_button("E-STOP", color="red", hint="stop every module's gait and hold its joint")
        self.estop.on_click(self._safe(self._on_estop))
        self.status = gui.add_markdown("Ready.")
        tabs = gui.add_tab_group()
        with tabs.add_tab("Gait"):
            self._build_editor()
        with tabs.add_tab("Preview"):
            self._build_preview()
        with tabs.add_tab("Deploy"):
            self._build_deploy()
        with tabs.add_tab("Monitor"):
            self._build_monitor()
        self._refresh_editor()

    def _build_editor(self) -> None:
        gui = self.server.gui
        names = sorted(p.stem for p in LIBRARY.glob("*.toml"))
        self.library = gui.add_dropdown("Library", names, initial_value=self.studio.gait.name
                                        if self.studio.gait.name in names else names[0])  # fmt: skip
        self.open_button = gui.add_button("Open from library")
        self.open_button.on_click(self._safe(lambda _: self._open(load(LIBRARY / f"{self.library.value}.toml"))))
        self.upload = gui.add_upload_button("Upload gait file", mime_type=".toml")
        self.upload.on_upload(self._safe(self._on_upload))
        with gui.add_folder("State"):
            self.automaton = gui.add_dropdown("Automaton", ["-"])
            self.state_index = gui.add_slider("State", min=1, max=2, step=1, initial_value=1)
            self.angle = gui.add_number("Angle (deg)", initial_value=0.0, step=0.5)
            self.duration = gui.add_number("Duration (s)", initial_value=0.1, step=0.005, min=0.0)
            self.interp = gui.add_dropdown("Interpolation", ["linear", "step"])
            self.state_problem = gui.add_markdown("")
            row = gui.add_button_group("Edit states", ["Insert after", "Remove"])
        with gui.add_folder("Module"):
            self.module_index = gui.add_slider("Module", min=1, max=2, step=1, initial_value=1)
            self.phase = gui.add_number("Phase", initial_value=0.0, min=0.0, max=0.999999, step=0.01)
            self.direction = gui.add_dropdown("Direction", ["1", "-1"])
            self.module_automaton = gui.add_dropdown("Runs", ["-"])
            self.module_problem = gui.add_markdown("")
        with gui.add_folder("Robot", expand_by_default=False):
            self.friction = gui.add_number("Friction", initial_value=1.0, min=0.01, max=10.0, step=0.05)
            self.module_size = gui.add_number("Module size (m)", initial_value=0.05, min=0.01, max=1.0, step=0.005)
        history = gui.add_button_group("History", ["Undo", "Redo"])
        self.download = gui.add_button("Download .toml")
        self.problems = gui.add_markdown("")
        self.table_html = gui.add_html("")
        self.expanded = gui.add_uplot(data=_zeros(2), series=({"label": "t"}, {"label": "m1"}),
                                      title="Expanded table: commanded angle per module", aspect=1.6)  # fmt: skip

        def field(setter: Callable[[Any], None]) -> Callable[[Any], None]:
            def callback(event: Any) -> None:
                if not self._syncing:
                    setter(event.target.value)
                    self._after_edit()

            return self._safe(callback)

        def state_field(name: str, convert: Callable[[Any], Any]) -> Callable[[Any], None]:
            return field(lambda v: self.doc.set_state(self.automaton.value, int(self.state_index.value) - 1, name,
                                                      convert(v)))  # fmt: skip

        self.angle.on_update(state_field("angle", float))
        self.duration.on_update(state_field("duration", float))
        self.interp.on_update(state_field("interpolation", str))
        self.phase.on_update(field(lambda v: self.doc.set_module(int(self.module_index.value), "phase", float(v))))
        self.direction.on_update(field(lambda v: self.doc.set_module(int(self.module_index.value), "direction",
                                                                      int(v))))  # fmt: skip
        self.module_automaton.on_update(field(lambda v: self.doc.set_module(int(self.module_index.value),
                                                                             "automaton", v)))  # fmt: skip
        self.friction.on_update(field(lambda v: self.doc.set_robot("friction", float(v))))
        self.module_size.on_update(field(lambda v: self.doc.set_robot("module_size", float(v))))
        for control in (self.automaton, self.state_index, self.module_index):
            control.on_update(self._safe(lambda _: None if self._syncing else self._refresh_editor()))

        def edit_states(event: Any) -> None:
            index = int(self.state_index.value) - 1
            if event.target.value == "Insert after":
                self.doc.add_state(self.automaton.value, index)
            else:
                self.doc.remove_state(self.automaton.value, index)
            self._after_edit()

        row.on_click(self._safe(edit_states))

        def undo_redo(event: Any) -> None:
            moved = self.doc.undo() if event.target.value == "Undo" else self.doc.redo()
            if not moved:
                self.notify("History", f"nothing to {event.target.value.lower()}")
            self._after_edit()

        history.on_click(self._safe(undo_redo))
        self.download.on_click(self._safe(lambda e: e.client.send_file_download(
            f"{self.doc.gait().name}.toml", self.doc.text().encode())))  # fmt: skip

    def _build_preview(self) -> None:
        gui = self.server.gui
        self.play = gui.add_button_group("Playback", ["Play", "Pause", "Reset"])
        self.play.on_click(self._safe(self._on_play))
        self.speed = gui.add_slider("Speed", min=0.1, max=4.0, step=0.1, initial_value=1.0)
        self.speed.on_update(self._safe(lambda e: self.loop.request("speed", e.target.value)))
        self.timeline = gui.add_slider("Timeline (frame)", min=0, max=1, step=1, initial_value=0)
        self.timeline.on_update(self._safe(self._on_seek))
        steps = gui.add_button_group("Step", ["◀ back", "forward ▶"])
        steps.on_click(self._safe(lambda e: self.loop.request("step", -1 if "back" in e.target.value else 1)))
        self.metrics = gui.add_markdown("")
        self.plot_module = gui.add_slider("Plot module", min=1, max=max(2, self.doc.gait().robot.modules), step=1,
                                          initial_value=1)  # fmt: skip
        self.angles = gui.add_uplot(data=_zeros(3),
                                    series=({"label": "t"}, {"label": "commanded", "stroke": "orange"},
                                            {"label": "measured", "stroke": "steelblue"}),
                                    title="Joint angle (deg)", aspect=2.0)  # fmt: skip

    def _build_deploy(self) -> None:
        gui = self.server.gui
        target = "the simulated modules" if self.studio.simulated else "the modules on the REAL CAN bus"
        gui.add_markdown(f"Deploy the edited gait to {target}: validate, transfer, verify each checksum, then start "
                         "all modules with one broadcast.")  # fmt: skip
        self.deploy_button = gui.add_button("Deploy")
        self.deploy_button.on_click(self._safe(self._on_deploy))
        self.progress = gui.add_progress_bar(0.0)
        self.deploy_log = gui.add_markdown("")
        self.run_buttons = gui.add_button_group("Modules", ["Start all", "Stop all"])
        self.run_buttons.on_click(self._safe(self._on_run))

    def _build_monitor(self) -> None:
        gui = self.server.gui
        self.roster_md = gui.add_markdown("")
        with gui.add_folder("Attribute browser"):
            self.browse_module = gui.add_dropdown("Node", ["-"])
            self.browse_object = gui.add_dropdown("Object", ["-"])
            self.browse_value = gui.add_markdown("")
            self.browse_input = gui.add_text("New value", initial_value="")
            actions = gui.add_button_group("Browse", ["List", "Get", "Set", "Plot"])
            actions.on_click(self._safe(self._on_browse))
        self.live = gui.add_uplot(data=_zeros(2), series=({"label": "t"}, {"label": "-"}),
                                  title="Live attributes", aspect=2.0)  # fmt: skip
        self._live_labels: list[str] = ["-"]

    # -- editor ---------------------------------------------------------------------------------------------------

    def _open(self, gait: Any) -> None:
        self.doc.replace(gait)
        self._after_edit()
        self.notify("Opened", f"{gait.name}: {gait.robot.modules}-module {gait.robot.shape}")

    def _on_upload(self, event: Any) -> None:
        file = event.target.value
        try:
            self.doc.load_text(file.content.decode("utf-8"), source=file.name)
        except GaitError as exc:
            self.notify("Invalid gait file", "; ".join(str(p) for p in exc.problems[:5]), error=True)
            return
        self._after_edit()
        self.notify("Opened", file.name)

    def _after_edit(self) -> None:
        self._refresh_editor()
        if self.doc.problems:
            self.notify("Invalid", str(self.doc.problems[0]), error=True)
            return
        self.loop.request("load", self.doc.gait())  # an edit re-previews at once

    @contextlib.contextmanager
    def _programmatic(self) -> Iterator[None]:
        """Controls set by the server (not the user) inside this block: their update callbacks do nothing.

        viser calls a control's callbacks synchronously when the server sets its value; the flag tells them apart,
        and the lock keeps the editor's resync and the 20 Hz refresh from clearing each other's flag."""
        with self._rebuild_lock:
            self._syncing = True
            try:
                yield
            finally:
                self._syncing = False

    def _refresh_editor(self, table: bool = True) -> None:
        with self._programmatic():
            self._sync_controls(table)

    def _sync_controls(self, table: bool) -> None:
        data = self.doc.data()
        automata = list(data["automata"])
        if list(self.automaton.options) != automata:
            self.automaton.options = automata
            self.module_automaton.options = automata
        if self.automaton.value not in automata:
            self.automaton.value = automata[0]
        states = data["automata"][self.automaton.value]["states"]
        self.state_index.max = max(2, len(states))
        index = min(int(self.state_index.value), len(states)) - 1
        state = states[index]
        self.angle.value = float(state.get("angle", 0.0))
        self.duration.value = float(state.get("duration") or 0.0)
        self.interp.value = state.get("interpolation", "linear")
        path = f"automata.{self.automaton.value}.states[{index}]"
        self.state_problem.content = "".join(f"⚠ {p.message}  \n" for p in self.doc.problem_at(path))
        modules = data["modules"]
        self.module_index.max = max(2, len(modules))
        m_index = min(int(self.module_index.value), len(modules)) - 1
        module = modules[m_index]
        self.phase.value = float(module.get("phase", 0.0))
        self.direction.value = str(module.get("direction", 1))
        if module.get("automaton") in automata:
            self.module_automaton.value = module["automaton"]
        self.module_problem.content = "".join(f"⚠ {p.message}  \n" for p in self.doc.problem_at(f"modules[{m_index}]"))
        self.friction.value = float(data.get("ground", {}).get("friction", 1.0))
        self.module_size.value = float(data["robot"].get("module_size", 0.05))
        self.problems.content = ("**Problems**  \n" + "".join(f"- {p}\n" for p in self.doc.problems)
                                 if self.doc.problems else f"✓ valid ({data['name']})")  # fmt: skip
        if table:
            self.table_html.content = _states_table(data, self.automaton.value, index)
            if not self.doc.problems:
                times, rows = expand(self.doc.gait(), samples=32)
                self.expanded.data = (np.asarray(times), *(np.asarray(r) for r in rows))
                self.expanded.series = ({"label": "t"}, *({"label": f"m{k + 1}"} for k in range(len(rows))))

    # -- preview, deploy, monitor ---------------------------------------------------------------------------------

    def _on_play(self, event: Any) -> None:
        kind = event.target.value
        self.loop.request("reset" if kind == "Reset" else "play", kind == "Play")

    def _on_seek(self, event: Any) -> None:
        if not self._syncing:  # a user's drag scrubs (and pauses); the refresh moving the slider does not
            self.loop.request("seek", int(event.target.value))

    def _on_estop(self, _: Any) -> None:
        self.node.estop("studio E-STOP")  # type: ignore[union-attr]
        self.notify("E-STOP", "sent to every module: gaits stopped, joints holding", error=True)

    def _on_deploy(self, event: Any) -> None:
        gait = self.doc.gait()  # GaitError (shown) if the edited gait is invalid
        if not self.studio.simulated:
            self._confirm_real(event, gait)
            return
        self._deploy(gait)

    def _confirm_real(self, event: Any, gait: Any) -> None:
        with event.client.gui.add_modal("Deploy to the real robot?") as modal:
            event.client.gui.add_markdown(f"{gait.name} will be written to {gait.robot.modules} modules on the bus.")
            go = event.client.gui.add_button("Yes, deploy", color="red")
            cancel = event.client.gui.add_button("Cancel")

            @go.on_click
            def _(_: Any) -> None:
                modal.close()
                self._safe(lambda __: self._deploy(gait))(None)

            cancel.on_click(lambda _: modal.close())

    def _deploy(self, gait: Any) -> None:
        lines: list[str] = []

        def progress(done: int, total: int, message: str) -> None:
            self.progress.value = 100.0 * done / total
            lines.append(message)
            self.deploy_log.content = "  \n".join(lines[-8:])

        self.progress.value = 0.0
        deploy(self.node, gait, progress=progress)  # type: ignore[arg-type]
        start_all(self.node)  # type: ignore[arg-type]
        self.notify("Deployed", f"{gait.name} verified on {gait.robot.modules} modules and started")
        for assignment in gait.modules[:4]:
            self.plot.watch(module_name(assignment.id), "joint.angle")

    def _on_run(self, event: Any) -> None:
        if event.target.value == "Start all":
            start_all(self.node)  # type: ignore[arg-type]
        else:
            stop_all(self.node)  # type: ignore[arg-type]
        self.notify("Modules", event.target.value.lower())

    def _on_browse(self, event: Any) -> None:
        action, name = event.target.value, self.browse_module.value
        if action == "List" or self.browse_object.value == "-":
            objects = self.node.list_objects(name, timeout=2.0)  # type: ignore[union-attr]
            self.browse_object.options = [o.name for o in objects]
            self.browse_value.content = "  \n".join(f"`{o.name}` {describe(o)}" for o in objects)
            return
        obj = self.node.lookup(name, self.browse_object.value, timeout=2.0)  # type: ignore[union-attr]
        if action == "Get":
            self.browse_value.content = f"`{obj.name}` ({describe(obj)}) = **{format_value(obj.peek())}**"
        elif action == "Set":
            obj.set(parse_value(obj, self.browse_input.value), wait=True)
            self.browse_value.content = f"`{obj.name}` set to **{format_value(obj.peek())}**"
        else:
            self.plot.watch(name, obj.name)

    # -- threads --------------------------------------------------------------------------------------------------

    def _render(self) -> None:
        while not self._stop.wait(FRAME_PERIOD):
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
        self.metrics.content = (f"t = {m.seconds:.2f} s · distance **{m.distance:.3f} m** "
                                f"({m.body_lengths:.2f} BL) · speed **{m.speed:.3f} m/s** · heading {m.heading:.0f}° · "
                                f"peak torque {m.peak_torque:.2f} N·m{warning}")  # fmt: skip
        with self._programmatic():
            self.timeline.max = max(1, frames - 1)
            if loop.cursor is None:
                self.timeline.value = max(0, frames - 1)
        t, goal, angle = loop.series(int(self.plot_module.value) - 1)
        self.angles.data = (t, goal, angle)
        rows = self.roster.rows()
        names = [n for n, _, _ in rows]
        if names and list(self.browse_module.options) != names:
            self.browse_module.options = names
        self.roster_md.content = "**Nodes**  \n" + "  \n".join(
            f"{'🟢' if alive else '🔴'} `{name}` {'live' if alive else 'LOST'} · last heard {age:.1f} s ago"
            f"{' · ' + self.roster.gait(name) if self.roster.gait(name) else ''}"
            for name, alive, age in rows
        )  # fmt: skip
        labels, data = self.plot.data()
        if labels:
            if labels != self._live_labels:
                self.live.series = ({"label": "t"}, *({"label": label} for label in labels))
                self._live_labels = labels
            self.live.data = data

    def close(self) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=5)
        self.plot.close()
        self.roster.close()
        self.loop.close()
        self.server.stop()


def _states_table(data: dict[str, Any], selected: str, index: int) -> str:
    """The automata as an HTML table (states across, one row per automaton; the selected cell highlighted)."""
    rows = []
    for name, automaton in data["automata"].items():
        cells = []
        for k, state in enumerate(automaton["states"]):
            mark = ' style="background:#ffe8a8"' if name == selected and k == index else ""
            duration = state.get("duration")
            cells.append(
                f"<td{mark}>{state.get('angle', 0):.1f}°<br><small>{duration if duration else '…'}s</small></td>"
            )
        rows.append(f"<tr><th>{name}</th>{''.join(cells)}</tr>")
    return ('<div style="overflow-x:auto;font-size:0.75em"><table border="1" cellpadding="2" '
            f'style="border-collapse:collapse">{"".join(rows)}</table></div>')  # fmt: skip


def _zeros(count: int) -> tuple[np.ndarray, ...]:
    return (np.array([0.0, 1.0]), *(np.zeros(2) for _ in range(count - 1)))
