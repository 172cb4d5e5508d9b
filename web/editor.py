"""The Gait tab: open or upload a gait, edit its states, modules and robot, see its problems and its table.

Layout, top to bottom: library/open/upload, undo/redo and download, the problems (or "valid"), the state grid (every
automaton's states as rows of inputs, web/grid.py), the selected state (interpolation, insert/remove), the selected
module (phase, direction, automaton), the robot (module count, shape, axes, legs, size, friction), then an HTML view of
the table and a plot of the expanded module × time table.

Every edit goes through the GaitDocument (one undoable step, validated after it); a valid document is queued to the
preview at once. Controls the server sets are set inside the dashboard's ``programmatic()`` block so their callbacks
do not take them for user edits.
"""

from __future__ import annotations

import html
import re
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from asm_module.names import MODULE_IDS
from gaits.model import AXES, FORWARD, LIBRARY, SHAPES, GaitError
from gaits.table import expand

from .control_table import SAMPLES as CONTROL_SAMPLES
from .control_table import control_table
from .document import StaleEdit, assignments
from .generator import GaitTools
from .grid import StateGrid
from .inputs import number, slider, whole
from .monitor import empty_plot, seconds_axes, stroke
from .page_script import CLICKED_FIELD
from .program_editor import EventControls, ProgramPanel
from .state_timeline import WINDOW_SECONDS, legend, state_timeline

if TYPE_CHECKING:
    from .page import Page


@dataclass(eq=False)
class _Click:
    """A state clicked in the 3D view, not selected yet: by which tab (None: set from the server), after how many
    selection moves, the state (automaton, 0-based index) and the layout its index is of (GaitDocument.layout).
    Compared by identity: two alike clicks are two."""

    client: int | None
    moves: int
    state: tuple[str, int]
    layout: int


def _clicked_state(text: str) -> tuple[str, int]:
    """(automaton, 0-based index) of ``automaton:index:count``, as the page's script writes a clicked state;
    ValueError for anything else (the gait is asked whether it has that state when it is selected)."""
    parts = text.split(":")
    if len(parts) != 3 or not parts[1].isdigit():
        raise ValueError(f"not a state of the gait: {text[:80]!r}")
    return parts[0], int(parts[1])


class GaitEditor:
    """The controls of the Gait tab of ``page``; the control table and the expanded table go into the page's
    floating panel (``table_tab``, ``expanded_tab``). See the module docstring."""

    def __init__(self, page: Page, initial: str, table_tab: Any, expanded_tab: Any) -> None:
        self.page = page
        self.doc = page.doc
        gui = page.gui
        safe = page.safe
        on_edit = self._on_edit  # the page's, the editor resynced when an edit is refused (it shows the document)
        names = sorted(p.stem for p in LIBRARY.glob("*.toml"))
        self.library = gui.add_dropdown("Library", names, initial_value=initial if initial in names else names[0])
        gui.add_button("Open from library").on_click(
            safe(lambda _: self.open_file(LIBRARY / f"{self.library.value}.toml"))
        )
        self.upload = gui.add_upload_button("Upload gait file", mime_type=".toml")
        self.upload.on_upload(safe(self._on_upload))
        self.history_actions = gui.add_button_group("History", ["Undo", "Redo"])
        on_edit(self.history_actions, self.history, click=True)  # in order with the edits that came before it
        self.download = gui.add_button("Download .toml")
        self.download.on_click(safe(page.in_turn(lambda e: e.client.send_file_download(
            f"{self.doc.gait().name}.toml", self.doc.text().encode(), save_immediately=True))))  # fmt: skip
        self.problems = gui.add_markdown("")
        self.tools = GaitTools(gui, self.doc, edited=self.after_edit, safe=safe, syncing=lambda: page.syncing,
                               on_edit=on_edit)  # fmt: skip
        grid_folder = gui.add_folder("States")
        self.grid = StateGrid(page.server, grid_folder, edited=self._on_grid, on_edit=on_edit,
                              layout=lambda: self.doc.layout)  # fmt: skip
        with grid_folder:  # hidden by the page's script, which writes a clicked state into it (web/page_script.py)
            self.clicked = gui.add_text(CLICKED_FIELD, "")
        self._clicks: deque[_Click] = deque()
        """States clicked in the 3D view and not selected yet (a click's callback runs later on viser's pool): see
        :meth:`_selected_as_it_came`."""
        self._moves = 0
        """States selected with the Automaton and State controls by a user, counted on viser's loop as they come."""
        on_edit(self.clicked, self._select_click, context=self._click_came)
        with gui.add_folder("Selected state"):
            self.automaton = gui.add_dropdown("Automaton", ["-"])
            self.state_index = slider(gui, "State", min=1, max=2, initial_value=1)
            self.angle = number(gui, "Angle (deg)", initial_value=0.0, step=0.5)
            # no min/max on the number inputs: the browser would clamp a value out of range (phase 1.5 became
            # 0.999999); the document takes what was typed and the loader's problem shows at the field instead
            self.duration = number(gui, "Duration (s)", initial_value=0.1, step=0.005)
            self.interp = gui.add_dropdown("Interpolation", ["linear", "step"])
            selected = self._selected_as_it_came
            self.events = EventControls(gui, self.doc, edited=self.after_edit, on_edit=on_edit, selected=selected)
            self.state_problem = gui.add_markdown("")
            self.state_actions = gui.add_button_group("Edit states", ["Insert after", "Remove"])
        with gui.add_folder("Module"):
            self.module_index = slider(gui, "Module", min=1, max=2, initial_value=1)
            self.phase = number(gui, "Phase", initial_value=0.0, step=0.01, hint="phase delay in [0, 1)")
            self.direction = gui.add_dropdown("Direction", ["1", "-1"])
            self.module_automaton = gui.add_dropdown("Runs", ["-"])
            self.module_problem = gui.add_markdown("")
        with gui.add_folder("Program", expand_by_default=False):
            self.program = ProgramPanel(gui, self.doc, edited=self.after_edit, safe=safe, syncing=lambda: page.syncing,
                                        on_edit=on_edit)  # fmt: skip
        with gui.add_folder("Robot"):
            self.modules = number(gui, "Modules", initial_value=8, step=1, hint=f"1..{MODULE_IDS[-1]}")
            self.shape = gui.add_dropdown("Shape", SHAPES)
            self.axes = gui.add_dropdown("Axes", AXES)
            self.legs = number(gui, "Legs", initial_value=4, step=1)
            self.module_size = number(
                gui, "Module size (m)", initial_value=0.05, step=0.005, hint="metres along the chain"
            )
            self.friction = number(gui, "Friction", initial_value=1.0, step=0.05, hint="in (0, 10]")
            self.robot_problem = gui.add_markdown("")
        self.table_html = gui.add_html("")
        with table_tab:  # beside the 3D view, in the page's own panel, not in the side panel
            self.table_caption = gui.add_markdown(TABLE_CAPTION)
            self.control = gui.add_image(control_table([], (-90.0, 90.0)), label=None, format="png")
            self.state_legend = gui.add_html("")
        self._table: tuple[list[list[float]], tuple[float, float]] = ([], (-90.0, 90.0))
        self._table_drawn: tuple[Any, ...] | None = None
        with expanded_tab:
            self.expanded = gui.add_uplot(data=empty_plot(2), series=({"label": "t"}, {"label": "m1"}),
                                          title="Expanded table: commanded angle per module", aspect=2.2,
                                          **seconds_axes("degrees"))  # fmt: skip

        def field(control: Any, setter: Callable[..., None], context: Callable[[], Any] | None = None) -> None:
            def apply(value: Any, *where: Any) -> None:
                setter(value, *where)
                self.after_edit()

            # the value as typed, and the state or module selected when it came (a resync of another edit, or a
            # selection made after it, may run in between)
            on_edit(control, apply, context=context)

        def state_field(control: Any, name: str, convert: Callable[[Any], Any]) -> None:
            field(control, lambda v, at: self.doc.set_state(at[0], at[1], name, convert(v), layout=at[2]),
                  context=selected)  # fmt: skip

        def module_field(control: Any, name: str, convert: Callable[[Any], Any]) -> None:
            field(control, lambda v, at: self.doc.set_module(at[0], name, convert(v), at[1]),
                  context=lambda: (int(self.module_index.value), self.program.gait()))  # fmt: skip

        state_field(self.angle, "angle", float)
        state_field(self.duration, "duration", float)
        state_field(self.interp, "interpolation", str)
        module_field(self.phase, "phase", float)
        module_field(self.direction, "direction", int)
        module_field(self.module_automaton, "automaton", str)
        robot_fields = ((self.modules, "modules", lambda v: whole(v, "Modules")), (self.shape, "shape", str),
                        (self.axes, "axes", str), (self.legs, "legs", lambda v: whole(v, "Legs")),
                        (self.module_size, "module_size", float), (self.friction, "friction", float))  # fmt: skip
        for control, name, convert in robot_fields:
            field(control, lambda v, name=name, convert=convert: self.doc.set_robot(name, convert(v)))
        for control in (self.automaton, self.state_index, self.module_index):
            control.on_update(safe(lambda _: None if page.syncing else self.sync()))
        for control in (self.automaton, self.state_index):
            page.on_arrival(control, self._moved)
        on_edit(self.state_actions, self._on_states, click=True, context=selected)  # the state shown at the click
        page.on("pick", self.pick)

    # -- actions --------------------------------------------------------------------------------------------------

    def pick(self, module_id: int) -> None:
        """A module clicked in the 3D view: select it (its callback resyncs the editor and the control table)."""
        modules = sorted(self.doc.data()["modules"], key=lambda m: m["id"])
        index = next((k for k, m in enumerate(modules) if m["id"] == module_id), None)
        if index is not None:
            self.module_index.value = index + 1

    def open_file(self, path: Path) -> None:
        """Open a gait file, keeping its text so that a download keeps its comments."""
        self.doc.load_text(path.read_bytes(), source=path.name, path=path)
        self.after_edit()
        gait = self.doc.gait()
        self.page.notify("Opened", f"{gait.name}: {gait.robot.modules}-module {gait.robot.shape}")

    def open(self, gait: Any) -> None:
        self.doc.replace(gait)
        self.after_edit()
        self.page.notify("Opened", f"{gait.name}: {gait.robot.modules}-module {gait.robot.shape}")

    def _on_upload(self, event: Any) -> None:
        file = event.target.value
        try:
            folder = self.doc.upload(file.content, file.name)  # bytes: the loader reports bad UTF-8 itself
        except GaitError as exc:
            self.page.notify("Invalid gait file", "; ".join(exc.lines()[:5]), error=True)
            return
        self.after_edit()
        robot_file = self.doc.gait().robot.file
        self.page.notify("Opened", file.name + (f", its modules described by {robot_file} in {folder}"
                                                if robot_file and folder else ""))  # fmt: skip

    def _on_edit(self, handle: Any, apply: Callable[..., None], **options: Any) -> Callable[[], None]:
        """``page.on_edit``, and an edit refused because states moved under it resyncs the page: the field or grid
        row kept showing it, so typing it again sent nothing (the page's value had not changed). A value refused for
        itself stays shown, beside its problem."""

        def applied(*args: Any) -> None:
            try:
                apply(*args)
            except StaleEdit:
                self.sync()
                raise

        return self.page.on_edit(handle, applied, **options)

    def history(self, kind: str) -> None:
        """``Undo`` or ``Redo`` one step (the History buttons and Ctrl+Z / Ctrl+Shift+Z)."""
        elsewhere = self.page.undoing_elsewhere()
        moved = self.doc.undo() if kind == "Undo" else self.doc.redo()
        if not moved:
            self.page.notify("History", f"nothing to {kind.lower()}")
        elif elsewhere:
            self.page.notify("History", f"{kind} took back an edit made in another tab")
        self.after_edit()

    def _on_states(self, clicked: str, at: tuple[str, int, int]) -> None:
        automaton, index, layout = at
        if clicked == "Insert after":
            self.doc.add_state(automaton, index, layout=layout)
        else:
            self.doc.remove_state(automaton, index, layout=layout)
        self.after_edit()

    def _on_grid(self, automaton: str, index: int, changes: dict[str, float], layout: int | None) -> None:
        """A grid row changed: apply the change (refused if states moved since: GaitDocument.layout), and select
        that state in the cell editor too."""
        self.doc.update_state(automaton, index, changes, layout=layout)
        self._select(automaton, index)
        self.after_edit()

    def _select(self, automaton: str, index: int) -> None:
        with self.page.programmatic():
            self.automaton.value = automaton
            self.state_index.max = max(2, index + 1, int(self.state_index.max))
            self.state_index.value = index + 1

    def _selected_as_it_came(self) -> tuple[str, int, int]:
        """The state an edit arriving now is of (read on viser's event loop as it arrives, GaitDocument.layout's
        index included: an edit that comes before another's Remove is refused when applied after it, not moved onto
        the next state). The state the controls show, unless this edit's tab clicked a state in the 3D view since
        that is not selected yet: an angle typed right after a click landed on the state selected before it. A
        selection made with the controls after the click wins; another tab's click is not this tab's selection
        (its Remove took the clicked state, not the one its controls showed)."""
        client = self.page.arriving_client()
        for click in reversed(self._clicks):
            if click.client == client and click.moves == self._moves:
                return (*click.state, self.doc.layout)
        return (str(self.automaton.value), int(self.state_index.value) - 1, self.doc.layout)

    def _moved(self, _: Any) -> None:
        self._moves += 1

    def _click_came(self) -> _Click:
        """A click's state, read on viser's event loop as it arrives (checked against the gait when applied)."""
        state = _clicked_state(str(self.clicked.value))
        click = _Click(self.page.arriving_client(), self._moves, state, self.doc.layout)
        self._clicks.append(click)
        return click

    def _select_click(self, _text: str, click: _Click) -> None:
        """Select a clicked state, unless a selection was made with the controls after the click, or its states
        moved since (another tab's Remove: its index is another state's now, so the tab is asked to click again);
        it stays pending until the controls show it, for the edits that arrive meanwhile."""
        try:
            if click.moves == self._moves:
                self.doc.check_layout(click.layout)
                self._select_state(*click.state)
        finally:
            self._clicks.remove(click)

    def select_clicked(self, text: str) -> None:
        """A state clicked in the page (``automaton:index:count`` from the page's script): select it. Anything else
        — not three parts, an automaton or state the gait does not have — is refused, nothing selected."""
        self._select_state(*_clicked_state(text))

    def _select_state(self, automaton: str, index: int) -> None:
        self.doc.check_state(automaton, index)
        self._select(automaton, index)
        self.sync()

    def after_edit(self) -> None:
        self.page.edited(f"{self.doc.data().get('name', 'the gait')} edited")
        self.sync()
        if self.doc.problems:
            self.page.notify("Invalid", page_label(self.doc.problems[0]), error=True)
            return
        self.page.resolved("Invalid", f"Edited: {self.doc.gait().name} is valid again")
        self.page.resolved("Error", f"Edited: {self.doc.gait().name} is valid again")  # a refused edit's line
        self.page.loop.request("load", self.doc.gait())  # an edit re-previews at once

    # -- showing the document -------------------------------------------------------------------------------------

    def sync(self) -> None:
        """Set every control from the document."""
        with self.page.programmatic():
            self._sync_controls()

    def _sync_controls(self) -> None:
        data = self.doc.data()
        self.tools.sync(data)
        automata = list(data["automata"])
        if list(self.automaton.options) != automata:
            self.automaton.options = automata
            self.module_automaton.options = automata
        if self.automaton.value not in automata:
            self.automaton.value = automata[0]
        states = data["automata"][self.automaton.value]["states"]
        self.state_index.max = max(2, len(states))
        index = min(int(self.state_index.value), len(states)) - 1
        if int(self.state_index.value) != index + 1:  # another gait, fewer states: the slider shows one of them
            self.state_index.value = index + 1
        state = states[index]
        self.angle.value = float(state.get("angle", 0.0))
        self.duration.value = float(state.get("duration") or 0.0)
        self.interp.value = state.get("interpolation", "linear")
        self.state_problem.content = _problems(self.doc.problem_at(f"automata.{self.automaton.value}.states[{index}]"))
        self.events.sync(data, self.automaton.value, index)
        self.program.sync(data)
        editing = self.program.gait()
        modules = assignments(data, editing)
        self.module_index.max = max(2, len(modules))
        m_index = min(int(self.module_index.value), len(modules)) - 1
        if int(self.module_index.value) != m_index + 1:
            self.module_index.value = m_index + 1
        module = modules[m_index]
        self.phase.value = float(module.get("phase", 0.0))
        self.direction.value = str(module.get("direction", 1))
        if module.get("automaton") in automata:
            self.module_automaton.value = module["automaton"]
        where = "modules" if editing == FORWARD else f"gaits.{editing}.modules"
        self.module_problem.content = _problems(self.doc.problem_at(f"{where}[{m_index}]"))
        robot = data["robot"]
        self.modules.value = float(robot.get("modules", 1))  # floats: see inputs.number
        self.shape.value = robot.get("shape", "chain")
        self.axes.value = robot.get("axes", "pitch")
        self.legs.value = float(robot.get("legs") or 4)
        self.legs.disabled = robot.get("shape") != "legged"
        self.module_size.value = float(robot.get("module_size", 0.05))
        fixed = self.doc.sized_by_robot_file()
        self.module_size.disabled = fixed is not None  # the robot file's: the page does not edit that file
        self.module_size.hint = f"set by {fixed}" if fixed else "metres along the chain"
        self.friction.value = float(data.get("ground", {}).get("friction", 1.0))
        self.robot_problem.content = _problems(self.doc.problem_at("robot") + self.doc.problem_at("modules"))
        self.problems.content = ("**Problems**  \n" + "".join(f"- {page_label(p)}\n" for p in self.doc.problems)
                                 if self.doc.problems else f"✓ valid ({data['name']})")  # fmt: skip
        self.grid.sync(data, self.automaton.value)
        self.table_html.content = _states_table(data, self.automaton.value, index)
        if not self.doc.problems and not self.doc.gait().timed:  # events decide its timing: no table to expand
            self._table = ([], self.doc.gait().limits)
            self.redraw_later()  # the page's refresh draws its states over time (draw_states)
            with self.page.atomic():
                self.expanded.series = ({"label": "t"}, {"label": "(event-driven: see the preview)"})
                self.expanded.data = empty_plot(2)
        elif not self.doc.problems:
            gait = self.doc.gait()
            times, rows = expand(gait, samples=CONTROL_SAMPLES)  # the plot takes every other sample (32)
            self._table = (rows, gait.limits)
            self.draw_control_table(force=True)
            times, rows = times[::2], [row[::2] for row in rows]
            with self.page.atomic():  # as many series as arrays, whenever the page applies them
                self.expanded.series = ({"label": "t"}, *({"label": f"m{k + 1}", "stroke": stroke(k)}
                                                          for k in range(len(rows))))  # fmt: skip
                self.expanded.data = (np.asarray(times), *(np.asarray(r) for r in rows))

    def selected_module(self) -> int:
        """The 0-based row of the module chosen in the editor's Module slider."""
        return int(self.module_index.value) - 1

    def draw_control_table(self, *, cursor: float | None = None, force: bool = False) -> None:
        """Draw the control table if its cursor column or selection moved (the dashboard's refresh calls this with
        the preview's phase in the period; an edit redraws it at once)."""
        rows, limits = self._table
        column = None if cursor is None else int((cursor % 1.0) * CONTROL_SAMPLES)
        key = (id(rows), column, self.selected_module())
        if not force and key == self._table_drawn:
            return
        self._table_drawn = key
        self._caption(TABLE_CAPTION, "")
        self.control.image = control_table(rows, limits, cursor=cursor, selected=self.selected_module())

    def redraw_later(self) -> None:
        """The next refresh draws the table (or the states over time) even if nothing moved."""
        self._table_drawn = None

    def draw_states(self, times: np.ndarray, states: np.ndarray, ended_at: float | None) -> None:
        """An event-driven or one-shot gait has no period to tabulate: draw instead the states each module of the
        preview was in over its last seconds (``times``, ``states`` as PreviewLoop.state_history gives them), with
        the end of a one-shot program (``ended_at``, when the frames reach it) — redrawn five times a second."""
        ended_at = ended_at if ended_at is not None and len(times) and ended_at <= times[-1] + 1e-9 else None
        newest = round(float(times[-1]) * 5) if len(times) else None
        key = ("states", newest, states.shape, ended_at, self.selected_module())
        if key == self._table_drawn:
            return
        self._table_drawn = key
        count = max((len(a.states) for a in self.page.loop.gait.automata.values()), default=0)
        ended = f" · **■ ended** at t = {ended_at:.2f} s (the black line)" if ended_at is not None else ""
        span = f"t = {times[0]:.1f} … {times[-1]:.1f} s" if len(times) else "no frames yet"
        self._caption(f"States over time (event-driven: no period to tabulate) · modules 1… top to bottom, "
                      f"{WINDOW_SECONDS:g} s across, a tick each second · {span}{ended}",
                      legend([f"S{k + 1}" for k in range(count)]))  # fmt: skip
        self.control.image = state_timeline(times, states, ended_at=ended_at, selected=self.selected_module())

    def _caption(self, caption: str, legend_html: str) -> None:
        if self.table_caption.content != caption:
            self.table_caption.content = caption
        if self.state_legend.content != legend_html:
            self.state_legend.content = legend_html


TABLE_CAPTION = ("Modules 1… top to bottom, one period across; blue −, red + (full at the limits); black: where the "
                 "preview is; framed: the selected module")  # fmt: skip


def page_label(problem: Any) -> str:
    """A problem as the page names things: 1-based states and modules (``wave S4``, ``module 3``), no line of the
    gait's file; one in the robot file the gait names is said to be there, at its line."""
    if problem.file is not None:
        return str(problem)
    path = re.sub(r"automata\.([^.\[]+)\.states\[(\d+)\]", lambda m: f"{m[1]} S{int(m[2]) + 1}", problem.path)
    path = re.sub(r"modules\[(\d+)\]", lambda m: f"module {int(m[1]) + 1}", path)
    path = re.sub(r"(S\d+|module \d+)\.", r"\1 ", path)  # "module 1 phase", "wave S4 angle"
    return f"{path}: {problem.message}"


def _problems(problems: list[Any]) -> str:
    return "".join(f"⚠ {p.message}  \n" for p in problems)


def _states_table(data: dict[str, Any], selected: str, index: int) -> str:
    """The automata as an HTML table (states across, one row per automaton; the selected cell highlighted)."""
    rows = []
    for name, automaton in data["automata"].items():
        cells = []
        for k, state in enumerate(automaton["states"]):
            mark = f' data-asm-state="{html.escape(name)}:{k}" style="cursor:pointer' + (
                ';background:#ffe8a8"' if name == selected and k == index else '"'
            )
            duration = state.get("duration")
            cells.append(
                f"<td{mark}>{state.get('angle', 0):.1f}°<br><small>{duration if duration else '…'}s</small></td>"
            )
        rows.append(f"<tr><th>{name}</th>{''.join(cells)}</tr>")
    return ('<div style="overflow-x:auto;font-size:0.75em"><table border="1" cellpadding="2" '
            f'style="border-collapse:collapse">{"".join(rows)}</table></div>')  # fmt: skip
