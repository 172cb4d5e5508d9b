"""A tuning run behind the page's Tune tab: gaits.tune.tune on its own thread, its candidates in worker processes.

The page's callbacks must return at once (viser runs them on a thread pool), so :class:`TuneRun` starts the search
on a thread of its own and the Tune tab reads what it has found (:meth:`TuneRun.snapshot`) at the page's refresh.
The workers are a ProcessPoolExecutor of *spawned* processes: the studio has many threads (viser, Zenoh, the
preview), and a forked child would inherit their locks in whatever state they were.

What was found so far is kept from every generation's progress, not only from tune()'s result: stopping ends the
workers at once (their simulations are killed, not waited for) and the best so far stays — it was a valid
candidate of a finished generation, only not checked over the final longer run. :meth:`TuneRun.stop` and
:meth:`TuneRun.close` leave no worker process behind (the studio's close calls them).
"""

from __future__ import annotations

import math
import multiprocessing
import os
import threading
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace

from gaits.model import Gait
from gaits.params import Free
from gaits.robot import description
from gaits.tune import Result, Setup, resolved, source_of, tune, tuned_text
from gaits.workers import start_worker, stop_pool


@dataclass
class Snapshot:
    """What the Tune tab shows: copied under the run's lock, so the page never sees a half-made update."""

    evaluations: int = 0
    budget: int = 0
    generations: int = 0
    history: list[tuple[int, float]] = field(default_factory=list)
    """(simulations so far, best objective so far) after every generation."""
    best: Gait | None = None
    values: list[float] = field(default_factory=list)
    value: float = math.nan
    start_value: float = math.nan
    line: str = "starting the workers…"
    running: bool = True
    state: str = "running"
    """running, done, stopped or failed."""
    version: int = 0
    """Incremented with every change: the page redraws only what changed."""
    samples: list[tuple[list[float], float]] = field(default_factory=list)
    """Every candidate's free values and objective (NaN: refused)."""


class TuneRun:
    """One search, started at once; see the module docstring."""

    def __init__(self, gait: Gait, frees: list[Free], setup: Setup, *, budget: int, seed: int = 1,
                 workers: int | None = None, popsize: int | None = None) -> None:  # fmt: skip
        self.gait = gait
        self.frees = frees
        self.setup = setup
        self.budget = budget
        self.seed = seed
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._snapshot = Snapshot(budget=budget)
        self.workers = max(1, workers or os.cpu_count() or 1)
        self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context("spawn"),
                                         initializer=start_worker)  # fmt: skip
        self._result: Result | None = None
        self._thread = threading.Thread(target=self._run, args=(popsize,), name="studio-tune", daemon=True)
        self._thread.start()

    def snapshot(self) -> Snapshot:
        with self._lock:
            s = self._snapshot
            return Snapshot(s.evaluations, s.budget, s.generations, list(s.history), s.best, list(s.values), s.value,
                            s.start_value, s.line, s.running, s.state, s.version, list(s.samples))  # fmt: skip

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def worker_pids(self) -> list[int]:
        """The worker processes alive now (tests check that none is left)."""
        processes = getattr(self._pool, "_processes", None) or {}
        return [p.pid for p in list(processes.values()) if p.is_alive() and p.pid is not None]

    def provenance_text(self) -> str:
        """The best candidate as a gait file, its provenance in comments (as ``gaits tune`` writes it)."""
        return self.adoptable()[1]

    def adoptable(self) -> tuple[Gait, str]:
        """The best candidate to make the edited gait: naming the edited gait's robot file again (the workers ran it
        with the description written in, which tuning does not change), and its file, provenance in comments."""
        with self._lock:
            result = self._result
            s = self._snapshot
        if s.best is None:
            raise ValueError("no candidate has met the constraints yet")
        if result is None or result.best is not s.best:  # stopped before tune() returned: say what is known
            result = Result(s.best, s.values, s.value, s.start_value, "", evaluations=s.evaluations,
                            interrupted=True)  # fmt: skip
        best, named = s.best, self.gait.robot
        if named.file is not None and description(best.robot, inline=True) == description(named, inline=True):
            best = replace(best, robot=replace(best.robot, file=named.file))
        text = tuned_text(replace(result, best=best), self.frees, self.setup, budget=self.budget, seed=self.seed,
                          source=source_of(f"the studio's {self.gait.name}", self.gait))  # fmt: skip
        return best, text

    def stop(self, timeout: float = 10.0) -> None:
        """End the search now, keeping the best so far: the workers are killed, the thread joined."""
        self._stop.set()
        stop_pool(self._pool)
        self._thread.join(timeout)

    close = stop

    # -- the search's thread --------------------------------------------------------------------------------------

    def _run(self, popsize: int | None) -> None:
        try:
            self.setup = resolved(self.setup, self.gait)  # its torque limit and forward, as the file will say
            result = tune(self.gait, self.frees, self.setup, budget=self.budget, seed=self.seed,
                          workers=self.workers, popsize=popsize, progress=self._progress,
                          executor=self._pool)  # fmt: skip
        except Exception as exc:  # a killed pool (stopped) or a refused setup
            with self._lock:
                s = self._snapshot
                s.running = False
                s.state = "stopped" if self._stop.is_set() else "failed"
                if not self._stop.is_set():
                    s.line = f"tuning failed: {exc}"
                s.version += 1
        else:
            with self._lock:
                self._result = result
                s = self._snapshot
                s.running = False
                s.state = "stopped" if result.interrupted or self._stop.is_set() else "done"
                if result.failure and not self._stop.is_set():  # the workers went away: the best so far is kept
                    s.state, s.line = "failed", f"tuning failed: {result.failure}"
                s.best, s.values, s.value = result.best, list(result.values), result.value
                s.evaluations = result.evaluations
                if result.best is not None and result.verified:  # the longer check may have passed a leader over
                    s.history.append((result.evaluations, result.value))
                    s.line = (f"the best held every constraint over {self.setup.seconds * self.setup.verify:g} s "
                              f"({result.verify_refused} leading candidate(s) broke a constraint or did worse "
                              "than the start there)")  # fmt: skip
                if result.best is None:
                    s.line = "no candidate met the constraints"
                s.version += 1
        finally:
            stop_pool(self._pool)

    def _progress(self, result: Result, line: str) -> None:
        with self._lock:
            s = self._snapshot
            s.evaluations, s.generations, s.line = result.evaluations, result.generations, line
            s.start_value = result.start_value
            if result.best is not None:
                s.best, s.values, s.value = result.best, list(result.values), result.value
            s.history.append((result.evaluations, result.value))
            s.samples = list(result.samples)
            s.version += 1
        if self._stop.is_set():
            raise KeyboardInterrupt  # tune() keeps its best so far and returns
