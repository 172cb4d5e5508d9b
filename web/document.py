"""The gait being edited: its data, every edit as one undoable step, and its validation after each edit.

The document keeps the plain data of a gait file (gaits.model.to_dict's shape), not a Gait: an edit may make it
invalid — a user types an angle beyond the limits — and the editor must show that problem where it occurs rather
than refuse the keystroke. :attr:`problems` lists what is wrong now; :meth:`gait` returns the validated gait, and
only a valid document reaches the preview or the modules.
"""

from __future__ import annotations

import copy
import math
import re
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gaits.model import FORWARD, MAX_MODULES, Gait, GaitError, Problem, from_dict, loads, to_dict
from gaits.roundtrip import save

HISTORY = 200
EVENT_FIELDS = ("tolerance", "threshold", "neighbour", "state", "on_timeout", "signal")
"""The fields that go with a state's event (``until``)."""
TYPING = 1.0
"""Seconds between two edits of one field that still count as typing one value (one undo step)."""

Snapshot = tuple[dict[str, Any], str | None, Path | None]
"""One undo step: the gait's data, the file text it was opened from and that file's path (a robot file it names
lies beside it)."""


class GaitDocument:
    """An editable gait with undo/redo; thread-safe (viser runs GUI callbacks on a thread pool)."""

    def __init__(self, gait: Gait, *, text: str | None = None, path: Path | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:  # fmt: skip
        self._lock = threading.Lock()
        self._clock = clock
        self._last_edit: tuple[Any, float] | None = None
        """(what was edited, when): the next edit of the same field within TYPING seconds joins its undo step."""
        self._data: dict[str, Any] = to_dict(gait)
        self._source: str | None = text
        """The TOML text the gait was opened from: saving keeps its comments and layout (gaits.roundtrip)."""
        self._path = path
        """The file it was opened from: a robot file the gait names (``[robot] file``) is read beside it."""
        self._undo: list[Snapshot] = []
        self._redo: list[Snapshot] = []
        self._valid: Gait | None = gait
        self.problems: list[Problem] = []
        self.version = 0
        self.layout = 0
        """Changes whenever a state's index may have changed (a state inserted or removed, another gait opened, an
        undo or redo of one of those). An edit addressed by index may name the layout it was made in; made in
        another, it is refused: the page applies an edit a moment after it arrived, and another tab's Remove in
        between moved every state after it (an angle typed for S5 landed on the old S6)."""
        self._spare: dict[int, dict[str, Any]] = {}
        """Assignments of modules removed by shrinking the robot, given back if it grows again: a module count
        typed as 1 then 12 passes through one module on the way."""

    # -- reading ------------------------------------------------------------------------------------------------

    def data(self) -> dict[str, Any]:
        with self._lock:
            return copy.deepcopy(self._data)

    def gait(self) -> Gait:
        """The document as a validated gait; GaitError if it has problems."""
        with self._lock:
            if self._valid is None:
                raise GaitError("edited gait", list(self.problems))
            return self._valid

    def text(self, *, inline: bool = False) -> str:
        """The document as a TOML gait file (the last valid state if it has problems now), keeping the comments
        and layout of the file it was opened from; a gait with no file gets its units in comments. ``inline``: a
        robot file it names written in (a file that stands alone, as a recording keeps it)."""
        gait = self.gait()
        with self._lock:
            source = self._source
        return save(to_dict(gait, inline=inline), source)

    @property
    def path(self) -> Path | None:
        """The file the gait was opened from (None: it has none); a robot file it names lies beside it."""
        with self._lock:
            return self._path

    def sized_by_robot_file(self) -> str | None:
        """Where the module size is set when the gait's robot file sets its default type's length (the gait's
        ``module_size`` must then equal it: the page cannot edit another file), e.g. ``robot.types.t.length in
        robot.toml``; None when the gait's own module size may be edited."""
        with self._lock:
            gait = self._valid
        if gait is None or gait.robot.file is None or gait.robot.module.length is None:
            return None
        where = f"robot.types.{gait.robot.type}" if gait.robot.type else "robot.module"
        return f"{where}.length in {gait.robot.file}"

    def problem_at(self, prefix: str) -> list[Problem]:
        return [p for p in self.problems if p.path == prefix or p.path.startswith(prefix + ".")]

    # -- editing ------------------------------------------------------------------------------------------------

    def replace(self, gait: Gait, *, text: str | None = None, path: Path | None = None) -> None:
        """Open another gait (undoable); ``text``: the file it comes from, whose comments a save keeps, ``path``
        where that file is."""
        self._spare.clear()
        self._apply(lambda data: data.clear() or data.update(to_dict(gait)), opened=(text, path))

    def load_text(self, text: str | bytes, source: str = "upload", path: Path | None = None) -> None:
        """Open a TOML file's text or bytes (read from ``path``, if from a file); GaitError (nothing changes) if
        it is not a valid gait."""
        gait = loads(text, source=source, path=path)
        self.replace(gait, text=text.decode("utf-8-sig") if isinstance(text, bytes) else text, path=path)

    def upload(self, content: bytes, name: str) -> Path | None:
        """Open an uploaded file's bytes. An upload has no folder of its own: it is read as if it lay beside the gait
        open now (when that one has a file), so a gait downloaded from the page that names its robot file opens
        again with it; the folder it was read in is returned (None: none, and a robot file it names is refused)."""
        current = self.path
        beside = current.parent / (Path(name).name or "upload.toml") if current is not None else None
        self.load_text(content, source=name[:100], path=beside)
        return beside.parent if beside is not None else None

    def set_state(self, automaton: str, index: int, field: str, value: Any, *, layout: int | None = None) -> None:
        """Set ``angle``, ``duration`` or ``interpolation`` of one state of an automaton."""
        self.update_state(automaton, index, {field: value}, layout=layout)

    def update_state(self, automaton: str, index: int, changes: dict[str, Any], *, layout: int | None = None) -> None:
        """Set several fields of one state as one undoable step (a grid row sends angle and duration together)."""
        wrong = set(changes) - {"angle", "duration", "interpolation"}
        if wrong:
            raise ValueError(f"a state has no editable field {sorted(wrong)[0]!r}")

        def edit(data: dict[str, Any]) -> None:
            _state(data, automaton, index).update(changes)

        self._apply(edit, field=("state", automaton, index, tuple(sorted(changes))), layout=layout)

    def add_state(self, automaton: str, index: int, *, layout: int | None = None) -> None:
        """Duplicate state ``index`` right after it."""
        self._apply(lambda d: d["automata"][automaton]["states"].insert(
            index + 1, dict(_state(d, automaton, index))), layout=layout, reshapes=True)  # fmt: skip

    def remove_state(self, automaton: str, index: int, *, layout: int | None = None) -> None:
        def edit(data: dict[str, Any]) -> None:
            _state(data, automaton, index)  # there (two alike states are two states: pop, not remove)
            data["automata"][automaton]["states"].pop(index)

        self._apply(edit, layout=layout, reshapes=True)

    def set_module(self, module_id: int, field: str, value: Any, gait: str = FORWARD) -> None:
        """Set ``phase``, ``direction`` or ``automaton`` of one module's assignment in one gait of the program."""
        if field not in ("phase", "direction", "automaton"):
            raise ValueError(f"a module assignment has no editable field {field!r}")

        def edit(data: dict[str, Any]) -> None:
            module = next((m for m in assignments(data, gait) if m["id"] == module_id), None)
            if module is None:  # the robot shrank while this edit was on its way
                raise ValueError(f"the gait has no module {module_id} (any more)")
            module[field] = value

        self._apply(edit, field=("module", gait, module_id, field))

    def set_event(self, automaton: str, index: int, until: str | None, *, layout: int | None = None,
                  **fields: Any) -> None:  # fmt: skip
        """What ends one state: its duration alone (``until`` None) or an event with its fields (``tolerance``,
        ``threshold``, ``neighbour``, ``state``, ``on_timeout``), as one undo step. Fields of other events go, since
        the loader refuses them (a tolerance on a contact state)."""
        wrong = set(fields) - set(EVENT_FIELDS)
        if wrong:
            raise ValueError(f"a state's event has no field {sorted(wrong)[0]!r}")

        def edit(data: dict[str, Any]) -> None:
            state = _state(data, automaton, index)
            for key in ("until", *EVENT_FIELDS):
                state.pop(key, None)
            if until is not None:
                state["until"] = until
                state.update({k: v for k, v in fields.items() if v is not None})

        self._apply(edit, field=("event", automaton, index), layout=layout)

    def set_emit(self, automaton: str, index: int, signal: int, *, layout: int | None = None) -> None:
        """The broadcast signal a state sends on entry (0: none); a value outside 1..255 is kept for the loader to
        refuse at the field, not altered."""

        def edit(data: dict[str, Any]) -> None:
            state = _state(data, automaton, index)
            if signal:
                state["emit"] = signal
            else:
                state.pop("emit", None)

        self._apply(edit, field=("emit", automaton, index), layout=layout)

    def set_one_shot(self, automaton: str, one_shot: bool) -> None:
        """Make an automaton one-shot (it ends after its last state) or periodic."""

        def edit(data: dict[str, Any]) -> None:
            if one_shot:
                data["automata"][automaton]["one_shot"] = True
            else:
                data["automata"][automaton].pop("one_shot", None)

        self._apply(edit)

    def add_program_gait(self, name: str) -> None:
        """A new gait of the program, a copy of ``forward``'s assignments, to edit module by module."""
        if not re.fullmatch(r"[A-Za-z0-9_-]{1,64}", name) or name == FORWARD:
            raise ValueError(f"a gait is named with 1-64 letters, digits, _ or -, other than {FORWARD!r}: {name!r}")
        if name in self._data.get("gaits", {}):
            raise ValueError(f"the program already has a gait {name!r}")
        self._apply(lambda d: d.setdefault("gaits", {}).__setitem__(name, {"modules": copy.deepcopy(d["modules"])}))

    def remove_program_gait(self, name: str) -> None:
        """Remove a gait of the program, and the sequence steps that ran it."""

        def edit(data: dict[str, Any]) -> None:
            data.get("gaits", {}).pop(name)
            if not data.get("gaits"):
                data.pop("gaits", None)
            steps = [s for s in data.get("program", {}).get("sequence", []) if s.get("gait") != name]
            _set_sequence(data, steps)

        self._apply(edit)

    def set_sequence(self, steps: list[tuple[str, int | None]]) -> None:
        """The program's own order: (gait, cycles or None for the last) steps; none removes the sequence."""
        self._apply(lambda d: _set_sequence(d, [{"gait": g, **({"cycles": c} if c is not None else {})}
                                                 for g, c in steps]), field=("sequence",))  # fmt: skip

    def set_robot(self, field: str, value: Any) -> None:
        """Edit the robot: ``modules`` (the assignments follow), ``shape``, ``axes``, ``legs``, ``module_size``;
        the ground's ``friction``."""
        if field == "friction":
            self._apply(lambda d: d.setdefault("ground", {}).__setitem__("friction", value), field=("robot", field))
        elif field == "modules":
            if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= MAX_MODULES:
                raise ValueError(f"a robot has 1 to {MAX_MODULES} modules, not {value!r}: nothing changed")
            self._apply(lambda d: _resize(d, value, self._spare), field=("robot", field))
        elif field == "shape":
            self._apply(lambda d: _reshape(d, value), field=("robot", field))
        elif field == "module_size":
            fixed = self.sized_by_robot_file()
            if fixed is not None:
                raise ValueError(f"the module size is the robot file's ({fixed}): edit it there; nothing changed")
            self._apply(lambda d: _resize_module(d, value), field=("robot", field))
        elif field in ("axes", "legs"):
            self._apply(lambda d: d["robot"].__setitem__(field, value), field=("robot", field))
        else:
            raise ValueError(f"the robot has no editable field {field!r}")

    def set_meta(self, field: str, value: str) -> None:
        """Rename the gait (``name``) or describe it (``description``); the download is named after it."""
        if field not in ("name", "description"):
            raise ValueError(f"a gait has no text field {field!r}")
        if not isinstance(value, str):
            raise ValueError(f"the {field} must be text")
        self._apply(lambda d: d.__setitem__(field, value), field=("meta", field))

    def spread_phases(self) -> None:
        """Phases evenly over the modules in ID order, module k at -k/n of a cycle: one wave along the body."""

        def edit(data: dict[str, Any]) -> None:
            modules = sorted(data["modules"], key=lambda m: m["id"])
            for k, module in enumerate(modules):
                module["phase"] = round((-k / len(modules)) % 1.0, 6) % 1.0

        self._apply(edit)

    def shift_phases(self, delta: float) -> None:
        """Add ``delta`` cycles to every module's phase (mod 1)."""
        if not isinstance(delta, int | float) or not math.isfinite(delta):
            raise ValueError(f"a phase shift must be a finite number of cycles, not {delta!r}")

        def edit(data: dict[str, Any]) -> None:
            for module in data["modules"]:
                module["phase"] = round((module.get("phase", 0.0) + delta) % 1.0, 6) % 1.0

        self._apply(edit)

    def scale_amplitude(self, factor: float, automaton: str | None = None) -> None:
        """Multiply the angles of one automaton (or all): refused whole, changing nothing, if any would leave the
        joint limits."""
        if not isinstance(factor, int | float) or not math.isfinite(factor):
            raise ValueError(f"a scale factor must be a finite number, not {factor!r}")
        data = self.data()
        low, high = data.get("limits", {}).get("min", -90.0), data.get("limits", {}).get("max", 90.0)
        names = [automaton] if automaton is not None else list(data["automata"])
        for name in names:
            for k, state in enumerate(data["automata"][name]["states"]):
                scaled = state.get("angle", 0.0) * factor
                if not low <= scaled <= high:
                    raise ValueError(f"{name} S{k + 1} would be {scaled:g}°, outside the limits {low:g}..{high:g}°: "
                                     "nothing changed")  # fmt: skip

        def edit(data: dict[str, Any]) -> None:
            for name in names:
                for state in data["automata"][name]["states"]:
                    state["angle"] = round(state.get("angle", 0.0) * factor, 3)

        self._apply(edit)

    def check_state(self, automaton: str, index: int) -> None:
        """ValueError naming it unless the gait has state ``index`` (0-based) of ``automaton``."""
        with self._lock:
            _state(self._data, automaton, index)

    def check_layout(self, layout: int | None) -> None:
        """ValueError unless ``layout`` is None or the present one (see ``layout``)."""
        if layout is not None and layout != self.layout:
            raise StaleEdit(STALE_EDIT)

    def undo(self) -> bool:
        return self._travel(self._undo, self._redo)

    def redo(self) -> bool:
        return self._travel(self._redo, self._undo)

    def _travel(self, source: list[Snapshot], target: list[Snapshot]) -> bool:
        """Go back to the newest state of ``source``, keeping the present on ``target``; False if none."""
        with self._lock:
            if not source:
                return False
            target.append((self._data, self._source, self._path))
            shape = _states_shape(self._data)
            self._data, self._source, self._path = source.pop()
            if _states_shape(self._data) != shape:  # an undone insert or removal, another gait: states moved
                self.layout += 1
            self._last_edit = None
            self._revalidate()
            return True

    def _apply(self, edit: Any, *, field: Any = None, opened: tuple[str | None, Path | None] | None = None,
               layout: int | None = None, reshapes: bool = False) -> None:  # fmt: skip
        """Apply one edit as an undo step. Edits of the same ``field`` less than TYPING seconds apart are one step:
        the page sends a number as it is typed ("4", then "45"), and Undo should give back the value before "45",
        not "4". An edit of the field whose value was refused (the document invalid) joins that step however late,
        so the refused value is never an undo step of its own. Anything else in between (another field, undo, redo)
        ends the step. ``layout``: refused unless it is the present one (see ``layout``); ``reshapes``: it moves
        states' indices."""
        with self._lock:
            self.check_layout(layout)
            now = self._clock()
            # a refused value (the document invalid after it) is replaced by its field's next value: Undo never
            # gives back a value the page refused
            typing = (field is not None and self._last_edit is not None and self._last_edit[0] == field
                      and (now - self._last_edit[1] < TYPING or bool(self.problems))
                      and self._undo and not self._redo)  # fmt: skip
            before: Snapshot = (copy.deepcopy(self._data), self._source, self._path)
            edit(self._data)
            if opened is not None:  # a gait opened in place of this one: its own file's text and path (or none)
                self._source, self._path = opened
            if reshapes or opened is not None:
                self.layout += 1
            if not typing:
                self._undo.append(before)
                del self._undo[:-HISTORY]
            self._last_edit = (field, now) if field is not None else None
            self._redo.clear()
            self._revalidate()

    def _revalidate(self) -> None:
        try:
            self._valid = from_dict(copy.deepcopy(self._data), source="edited gait", path=self._path)
            self.problems = []
        except GaitError as exc:
            self._valid = None
            self.problems = list(exc.problems)
        self.version += 1


STALE_EDIT = (
    "the gait's states changed while this edit was on its way (a state inserted or removed, here or in "
    "another tab, or undo): it was not applied; make it again"
)


class StaleEdit(ValueError):
    """An edit by index made in another layout than the document's (GaitDocument.layout): nothing was changed."""


def _states_shape(data: dict[str, Any]) -> tuple[tuple[str, int], ...]:
    """Each automaton's name and number of states: what an index addresses."""
    return tuple((name, len(automaton["states"])) for name, automaton in data["automata"].items())


def _resize_module(data: dict[str, Any], size: Any) -> None:
    """A new module size; the default type's length (``[robot.module]``'s, or the named type ``robot.type`` names)
    is the same number, so it follows."""
    robot = data["robot"]
    robot["module_size"] = size
    types = robot.get("types")
    named = types.get(robot.get("type")) if isinstance(types, dict) and isinstance(robot.get("type"), str) else None
    for module in (robot.get("module"), named):
        if isinstance(module, dict) and "length" in module:
            module["length"] = size


def _resize(data: dict[str, Any], count: int, spare: dict[Any, dict[str, Any]]) -> None:
    """Give the robot ``count`` modules: in ``modules`` and in every gait of the program, assignments beyond it go
    to ``spare``, new modules continue the pattern.

    A module that was in ``spare`` comes back as it was. Otherwise a new module runs the last module's automaton
    and direction, and its phase continues the last two modules' phase step (a travelling wave keeps its wavelength
    as the chain grows), or repeats the last phase if there is one module."""
    if not isinstance(count, int) or isinstance(count, bool) or count < 1:
        raise ValueError(f"a robot needs 1 or more modules, not {count!r}")
    data["robot"]["modules"] = count
    first = next(iter(data["automata"]), "")
    data["modules"] = _resized(data["modules"], count, spare, FORWARD, first)
    for name, program_gait in data.get("gaits", {}).items():
        if isinstance(program_gait, dict) and isinstance(program_gait.get("modules"), list):
            program_gait["modules"] = _resized(program_gait["modules"], count, spare, name, first)


def _resized(listed: list[Any], count: int, spare: dict[Any, dict[str, Any]], gait: str, first: str) -> list[Any]:
    modules = sorted((m for m in listed if isinstance(m, dict) and isinstance(m.get("id"), int)),
                     key=lambda m: m["id"])  # fmt: skip
    spare.update(((gait, m["id"]), m) for m in modules if m["id"] > count)
    modules = [m for m in modules if m["id"] <= count]
    if not modules:
        modules = [{"id": 1, "automaton": first, "phase": 0.0, "direction": 1}]
    step = (modules[-1]["phase"] - modules[-2]["phase"]) if len(modules) > 1 else 0.0
    while len(modules) < count:
        last = modules[-1]
        if (gait, last["id"] + 1) in spare:
            modules.append(spare.pop((gait, last["id"] + 1)))
            continue
        phase = round((last.get("phase", 0.0) + step) % 1.0, 6) % 1.0
        modules.append({"id": last["id"] + 1, "automaton": last["automaton"], "phase": phase,
                        "direction": last.get("direction", 1)})  # fmt: skip
    return modules[:count]


def assignments(data: dict[str, Any], gait: str) -> list[dict[str, Any]]:
    """The module assignments of program gait ``gait`` in a document's data (``modules`` for FORWARD)."""
    return data["modules"] if gait == FORWARD else data["gaits"][gait]["modules"]


def _set_sequence(data: dict[str, Any], steps: list[dict[str, Any]]) -> None:
    if steps:
        data["program"] = {"sequence": steps}
    else:
        data.pop("program", None)


def _reshape(data: dict[str, Any], shape: str) -> None:
    """Change the robot's shape; a legged robot gets the most legs (up to 4) that share its modules evenly."""
    robot = data["robot"]
    robot["shape"] = shape
    if shape == "legged":
        modules = robot.get("modules", 0)
        if not isinstance(robot.get("legs"), int) or robot["legs"] < 2:
            robot["legs"] = next((n for n in (4, 2, 3) if isinstance(modules, int) and modules % n == 0), 2)
    else:
        robot.pop("legs", None)


def _state(data: dict[str, Any], automaton: str, index: int) -> dict[str, Any]:
    """State ``index`` of ``automaton``; ValueError naming it when the gait has no such state (a state clicked in a
    view of states since removed said only "list index out of range"; a negative index would have edited another)."""
    states = data["automata"].get(automaton, {}).get("states", [])
    if not 0 <= index < len(states):
        raise ValueError(f"{automaton} has no state S{index + 1}")
    return states[index]
