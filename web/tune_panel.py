"""The Tune tab: choose which of the edited gait's numbers are free and their bounds, the objective and the ground,
then Start; the search runs in worker processes (web/tuner.py) while the tab shows its progress and the best-so-far
curve. The best candidate found so far can be played in the preview at any moment, and "Adopt" makes it the edited
gait (one undo step, its provenance in the file's comments).

Callbacks only take the panel's lock and start or stop a run (a thread and its processes, started, not waited
for); what the run found is read at the page's refresh."""

from __future__ import annotations

import math
import os
import re
import threading
from typing import TYPE_CHECKING, Any

import numpy as np

from gaits.params import Free, check, parse_free
from gaits.terrain import FLAT, parse
from gaits.tune import OBJECTIVES, Setup

from .inputs import number, precise
from .monitor import empty_plot
from .tuner import Snapshot, TuneRun

if TYPE_CHECKING:
    from .page import Page

GENERATOR = {"amplitude": ((20.0, 85.0), "°"), "period": ((0.35, 1.5), "s"), "wavelength": ((3.0, 14.0), "modules")}
"""The generator's parameters offered as free, with their default bounds (bench/tune.py's)."""
GROUNDS = {
    "flat": (FLAT,),
    "rough ground": (parse("rough:seed=1"), parse("rough:seed=2")),
    "slope 5°": (parse("slope:5"),),
    "rough ground and slope (robust)": (parse("rough:seed=1"), parse("rough:seed=2"), parse("slope:5")),
    "the preview's ground": (),
}
"""What a candidate is simulated on: several grounds make the objective their mean (a robust gait)."""


class TunePanel:
    """The Tune tab of ``page``; its curve is drawn in the tab itself."""

    def __init__(self, page: Page) -> None:
        self.page = page
        gui = page.gui
        self._lock = threading.Lock()
        self.run: TuneRun | None = None
        self._shown = (-1, -1)
        gui.add_markdown("Search the edited gait's free numbers for a faster (or cheaper, or turning) gait: every "
                         "candidate runs in MuJoCo, in worker processes.")  # fmt: skip
        self.free: dict[str, Any] = {}
        self.bounds: dict[str, Any] = {}
        for name, (bounds, unit) in GENERATOR.items():
            self.free[name] = gui.add_checkbox(f"Free: {name}", initial_value=False, hint=f"search the {name} ({unit})")
            self.bounds[name] = precise(gui.add_vector2(f"{name} bounds", initial_value=bounds, step=0.01,
                                                        hint=f"lowest and highest {name} ({unit})"))  # fmt: skip
        self.other = gui.add_text("Other free", initial_value="",
                                  hint="NAME=LOW:HIGH, separated by spaces, commas or semicolons: "
                                  "modules[2].phase=0:1, automata.wave.states[0].angle=-30:30")  # fmt: skip
        self.objective = gui.add_dropdown(
            "Objective",
            list(OBJECTIVES),
            initial_value="speed",
            hint="speed (maximised), cost_of_transport (minimised), heading_rate",
        )
        self.ground = gui.add_dropdown("Tune on", list(GROUNDS), initial_value="flat",
                                       hint="several grounds: their mean is the objective (robust)")  # fmt: skip
        self.budget = number(gui, "Budget (simulations)", initial_value=60, min=4, max=100_000, step=1)
        self.seconds = number(gui, "Seconds per candidate", initial_value=3.0, min=0.5, max=60.0, step=0.5)
        self.seed = number(gui, "Seed", initial_value=1, min=0, max=2**31 - 2, step=1)
        cores = os.cpu_count() or 1
        self.workers = number(gui, "Workers (processes)", initial_value=cores, min=1, max=cores, step=1,
                                      hint=f"candidates simulated at once (this machine has {cores} cores): fewer "
                                      "leave a core to the live robot and the page")  # fmt: skip
        self.control = gui.add_button_group("Tuning", ["Start tuning", "Stop tuning"])
        self.control.on_click(page.safe(page.in_turn(self._on_control)))  # from the gait with every edit before
        self.progress = gui.add_progress_bar(0.0)
        self.status = gui.add_markdown("Not tuning.")
        self.curve = gui.add_uplot(data=empty_plot(2),
                                   series=({"label": "simulations"}, {"label": "best so far", "stroke": "#1f77b4"}),
                                   title="Best so far", aspect=2.0, scales={"x": {"time": False}},
                                   axes=({"label": "simulations"}, {"label": "objective"}),
                                   visible=False)  # fmt: skip
        self.by_parameter = gui.add_folder("Objective against each free parameter", expand_by_default=False)
        self.scatters: dict[str, Any] = {}
        """One plot per free parameter of the run: every valid candidate's objective against its value."""
        self.best = gui.add_button_group("Best candidate", ["Preview best", "Adopt"])
        self.best.on_click(page.safe(self._on_best))
        self.best_line = gui.add_markdown("")

    # -- callbacks (viser's thread pool) --------------------------------------------------------------------------

    def frees(self) -> list[Free]:
        """The free parameters chosen now; ValueError naming a bad one."""
        frees = []
        for name, box in self.free.items():
            if box.value:
                low, high = (float(v) for v in self.bounds[name].value)
                frees.append(parse_free(f"{name}={low}:{high}"))
        frees += [parse_free(text) for text in re.split(r"[\s;,]+", str(self.other.value).strip()) if text]
        if not frees:
            raise ValueError("choose at least one free parameter (tick one, or write NAME=LOW:HIGH)")
        return frees

    def setup(self) -> Setup:
        terrains = GROUNDS[str(self.ground.value)] or (self.page.loop.terrain,)
        seconds, low, high = float(self.seconds.value), float(self.seconds.min or 0.0), float(self.seconds.max or 0.0)
        if not low <= seconds <= high:
            raise ValueError(f"Seconds per candidate is {low:g} to {high:g}, not {seconds:g}")
        return Setup(str(self.objective.value), tuple(terrains), seconds=seconds, warmup=1.0)

    def _on_control(self, event: Any) -> None:
        if event.target.value == "Start tuning":
            self.start()
        else:
            self.stop()

    def start(self, *, workers: int | None = None, popsize: int | None = None) -> TuneRun:
        """Start a search from the edited gait (a running one is stopped first); ``workers`` None: the tab's."""
        gait = self.page.doc.gait()
        frees = self.frees()
        check(gait, frees)
        setup = self.setup()
        budget, seed = _whole(self.budget, "Budget", "simulations"), _whole(self.seed, "Seed", "")
        if workers is None:
            workers = _whole(self.workers, "Workers", "processes")
        with self._lock:
            if self.run is not None:
                self.run.stop(timeout=0.0)
            self.run = TuneRun(gait, frees, setup, budget=budget, seed=seed, workers=workers,
                               popsize=popsize)  # fmt: skip
            self._shown = (-1, -1)
            run = self.run
            self._plot_parameters(frees)
        grounds = ", ".join(t.spec for t in setup.terrains)
        self.page.notify("Tuning", f"{len(frees)} free, {setup.objective} on {grounds}, budget {run.budget}, "
                         f"{run.workers} worker(s)")  # fmt: skip
        return run

    def stop(self) -> None:
        """Stop the search, keeping its best so far (its workers end now)."""
        with self._lock:
            run = self.run
        if run is None or not run.running:
            self.page.notify("Tuning", "not tuning")
            return
        run.stop(timeout=0.0)

    def _best(self) -> tuple[TuneRun, Snapshot]:
        with self._lock:
            run = self.run
        snapshot = run.snapshot() if run is not None else None
        if run is None or snapshot is None or snapshot.best is None:
            raise ValueError("no best candidate yet: start tuning and wait for a generation")
        return run, snapshot

    def _on_best(self, event: Any) -> None:
        run, snapshot = self._best()
        assert snapshot.best is not None
        if event.target.value == "Preview best":
            self.page.loop.request("load", snapshot.best)
            self.page.notify("Preview", f"the best candidate so far ({_values(run, snapshot)}); an edit of the gait "
                             "previews the edited gait again")  # fmt: skip
        else:
            self.page.emit("adopt", *run.adoptable())

    def _plot_parameters(self, frees: list[Free]) -> None:
        for handle in self.scatters.values():
            handle.remove()
        self.scatters = {}
        with self.by_parameter:
            for free in frees:
                self.scatters[free.name] = self.page.gui.add_uplot(
                    data=empty_plot(2), title=f"objective against {free.name}", aspect=2.0, visible=False,
                    series=({"label": free.name}, {"label": "objective", "stroke": "rgba(0,0,0,0)",
                                                   "points": {"show": True, "size": 5, "stroke": "#1f77b4",
                                                              "fill": "#1f77b4"}}),
                    scales={"x": {"time": False}}, axes=({"label": free.name}, {"label": "objective"}),
                )  # fmt: skip

    def close(self) -> None:
        """The studio closes: the search and its workers end."""
        with self._lock:
            run, self.run = self.run, None
        if run is not None:
            run.close()

    # -- the page's refresh ---------------------------------------------------------------------------------------

    def refresh(self) -> None:
        with self._lock:
            run = self.run
        if run is None:
            return
        s = run.snapshot()
        if (id(run), s.version) == self._shown:
            return
        self._shown = (id(run), s.version)
        unit = OBJECTIVES[run.setup.objective][1]
        best = f"{s.value:.4g} {unit}".strip() if not math.isnan(s.value) else "none valid yet"
        start = f"{s.start_value:.4g}" if not math.isnan(s.start_value) else "refused or not yet measured"
        with self.page.atomic():
            self.progress.value = min(100.0, 100.0 * s.evaluations / max(1, s.budget))
            self.status.content = (f"**{s.state}**: {s.evaluations} of {s.budget} simulations, "
                                   f"{s.generations} generations · best {run.setup.objective} **{best}** "
                                   f"(start {start})  \n{s.line}")  # fmt: skip
            points = [(n, v) for n, v in s.history if not math.isnan(v)]
            if points:
                xs = np.array([0.0] + [float(n) for n, _ in points])
                ys = np.array([points[0][1]] + [v for _, v in points])
                self.curve.data = (xs, ys)
                self.curve.visible = True  # shown from the first generation: an empty plot would draw a flat line
            if s.best is not None:
                self.best_line.content = f"Best: {_values(run, s)}"
            self._scatter(run, s)

    def _scatter(self, run: TuneRun, s: Snapshot) -> None:
        """Each free parameter's plot: the valid candidates' objective against its value (sorted: uPlot's x)."""
        valid = [(values, value) for values, value in s.samples if not math.isnan(value)]
        for k, free in enumerate(run.frees):
            handle = self.scatters.get(free.name)
            if handle is None or len(valid) < 2:
                continue
            points = sorted((values[k], value) for values, value in valid)
            handle.data = (np.array([x for x, _ in points]), np.array([y for _, y in points]))
            handle.visible = True


def _whole(field: Any, name: str, unit: str) -> int:
    """A number field's value, as the run uses it: a whole number within the field's own bounds, or ValueError
    (what the field shows is what runs: a seed of -1 ran as cma's random seed)."""
    value = float(field.value)
    if not value.is_integer() or not field.min <= value <= field.max:
        raise ValueError(f"{name} is a whole number{f' of {unit}' if unit else ''}, {field.min:g} to {field.max:g}, "
                         f"not {value:g}")  # fmt: skip
    return int(value)


def _values(run: TuneRun, snapshot: Snapshot) -> str:
    return ", ".join(f"{f.name} {v:g}" for f, v in zip(run.frees, snapshot.values, strict=False))
