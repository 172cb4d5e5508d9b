"""Tune a gait for a robot and its ground: CMA-ES over a few free parameters, each candidate simulated.

A library gait is a starting point, not the best gait for this robot on this floor. :func:`tune` searches the free
parameters (gaits/params.py: a state's angle or duration, a module's phase, the generator's amplitude, period,
wavelength) with CMA-ES (the ``cma`` package, ask/tell), in a box normalised to [0, 1] per parameter. Every
candidate is a whole gait file, checked by the loader (joint limits among the rest) and run by the modules' own
automata in gaits.sim.Simulation on every terrain asked for, in worker processes (one per core by default) or on a
Dask cluster (gaits/distributed.py, ``--scheduler``): what is scored is exactly what a robot would run.

Constraints are never traded against the objective: a candidate whose file is invalid, whose simulation diverges,
whose peak torque (warm-up included) exceeds the limit or that falls is scored far above any valid one (its
violation and mean joint power added, so the search still sees which way is better), and only a candidate that met
every constraint can become the best. At the end the best few valid ones run again, ``verify`` times longer, and
the first that still meets every constraint is the result: a gait at the edge of its servos may meet a torque peak
only every few seconds. If none does, there is no result.

The same seed gives the same result: CMA-ES draws from its own seeded generator, every simulation is
deterministic, and the results come back in the order they were asked for whatever the number of workers. Ctrl-C
(or a callback raising KeyboardInterrupt) stops the search and keeps the best so far.
"""

from __future__ import annotations

import itertools
import math
import os
import time
import warnings
from collections.abc import Callable
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .model import FORWARD, Gait, GaitError, dumps, from_dict, to_dict
from .params import Free, apply, check, current
from .terrain import FLAT, Terrain
from .workers import start_worker, stop_pool

OBJECTIVES = {"speed": (1.0, "m/s"), "cost_of_transport": (-1.0, ""), "heading_rate": (1.0, "°/s")}
"""Objective → (+1: maximised, -1: minimised; its unit)."""
INVALID = 1e4
"""The score of a candidate that could not be simulated (a bad file, a diverged simulation)."""
VIOLATION = 1e3
"""The score of a candidate that broke a constraint, plus by how much it did and its mean joint power."""
WORST_COST = 100.0
"""Cost of transport counted for a robot that did not move (inf otherwise): keeps the scores finite for CMA-ES."""
LEADERS = 8
"""How many of the best valid candidates are kept for the final, longer check (the start, if valid, besides)."""
CHECK_ROUND = 2
"""Leaders run at once in the final check (the start besides, in the first round): a fixed number, so one worker
or many choose the same best."""
TORQUE_MARGIN = 0.95
"""The default torque constraint, as a share of the robot's servo stall torque (``[robot.module] stall_torque``):
a gait that keeps its servos at their limit cannot follow its own references (and the torque saturates there, so
a constraint at the stall torque itself could never be broken). A robot whose module types have servos of
different stall torques holds each module to this share of its own (``Metrics.peak_load``)."""


def default_max_torque(gait: Gait) -> float | None:
    """The torque constraint of ``gait``'s own servos (the library module's 1.5 N·m gives 1.425); None when its
    modules' servos differ: then each is held to TORQUE_MARGIN of its own stall torque."""
    stalls = {t.stall_torque for t in gait.robot.every_module()}
    return round(TORQUE_MARGIN * stalls.pop(), 3) if len(stalls) == 1 else None


@dataclass(frozen=True)
class Setup:
    """What every evaluation needs besides the candidate: sent once to every worker with each job."""

    objective: str = "speed"
    terrains: tuple[Terrain, ...] = (FLAT,)
    seconds: float = 6.0
    warmup: float = 1.0
    max_torque: float | None = None
    """N·m; None: :func:`default_max_torque` of the gait tuned (tune() fills it in before any evaluation)."""
    gait: str = FORWARD
    """The program gait simulated: ``forward`` (the file's ``modules``) or one of its ``[gaits]`` (``left`` to tune a
    turn); the robot starts in forward and switches at its first cycle boundary, within the warm-up."""
    verify: float = 2.0
    """The best candidates are checked again over this many times ``seconds``: a rare torque peak (a gait near its
    servos' limit can meet one only every few seconds) must not slip through a short search run."""
    forward: float | None = None
    """The direction of "forward", degrees from +x: the way the starting gait travels on flat ground (tune() measures
    it). Speed and cost of transport count progress along it, signed: a candidate that goes backwards, or slides
    down a slope, makes negative progress, never a fast gait. None: the distance travelled, whichever way."""


@dataclass
class Outcome:
    """One candidate's simulations: its score for CMA-ES (lower is better) and why it was refused, if it was."""

    score: float
    value: float = math.nan
    """The objective in its own units (mean over the terrains), NaN when refused."""
    problem: str = ""
    """Empty when every constraint held."""
    peak_torque: float = 0.0
    fell: bool = False
    wall: float = 0.0
    """Seconds the worker spent on it, and of those the CPU seconds it got: how busy the pool was, and how much of
    the cores other processes took (bench/tune.py reports both)."""
    cpu: float = 0.0

    @property
    def feasible(self) -> bool:
        return not self.problem


def evaluate(document: dict[str, Any], setup: Setup) -> Outcome:
    """Simulate one candidate on every terrain (in a worker process) and score it."""
    from .sim import Simulation  # MuJoCo loads where it runs

    try:
        gait = from_dict(document, source="<candidate>")
        runs = []
        start_peak = start_load = 0.0
        for terrain in setup.terrains:
            with Simulation(gait, terrain=terrain) as sim:
                sim.start()
                if setup.gait != FORWARD:
                    sim.drive(setup.gait)
                sim.advance(setup.warmup)  # the warm-up (the gait's ramp-in) counts for the constraints too
                start_peak, start_load = max(start_peak, sim.peak_torque), max(start_load, sim.peak_load)
                runs.append(sim.run(setup.seconds, warmup=0.0))
    except GaitError as exc:
        return Outcome(INVALID, problem=f"invalid: {exc.lines()[0] if exc.lines() else exc}")
    except (ValueError, FloatingPointError, RuntimeError) as exc:  # a table the runtime refuses, a divergence
        return Outcome(INVALID, problem=f"not simulated: {exc}")
    peak = max(start_peak, *(m.peak_torque for m in runs))
    load = max(start_load, *(m.peak_load for m in runs))
    fell = any(m.fell for m in runs)
    max_torque = setup.max_torque if setup.max_torque is not None else default_max_torque(gait)
    progress = [m.along(setup.forward) if setup.forward is not None else m.distance for m in runs]
    if setup.objective == "speed":
        value = float(np.mean([p / m.seconds for p, m in zip(progress, runs, strict=True)]))
    elif setup.objective == "cost_of_transport":
        value = float(np.mean([min(m.energy / (m.mass * 9.81 * p), WORST_COST) if p > 0 and m.mass > 0
                               else WORST_COST for p, m in zip(progress, runs, strict=True)]))  # fmt: skip
    else:
        value = float(np.mean([abs(m.heading_rate) for m in runs]))
    problems = []
    if max_torque is None:  # servos of several stall torques: each module within its own
        excess = max(0.0, load - TORQUE_MARGIN)
        if excess > 0:
            problems.append(f"peak torque {load:.0%} of a module's stall torque > {TORQUE_MARGIN:.0%}")
    else:
        excess = max(0.0, peak - max_torque)
        if excess > 0:
            problems.append(f"peak torque {peak:.2f} > {max_torque:g} N·m")
    if fell:
        problems.append("fell")
    if problems:
        # The peak saturates at the servos' limit, so by itself it scores many refused candidates alike: their mean
        # joint power (W) tells them apart, steering the search towards gentler gaits, which is where it comes back.
        excess += 1.0 if fell else 0.0
        power = float(np.mean([m.energy / m.seconds for m in runs]))
        return Outcome(VIOLATION + excess + power, value, ", ".join(problems), peak, fell)
    return Outcome(-OBJECTIVES[setup.objective][0] * value, value, "", peak, fell)


def _evaluate_job(job: tuple[dict[str, Any], Setup]) -> Outcome:
    wall, cpu = time.perf_counter(), time.process_time()
    outcome = evaluate(*job)
    outcome.wall, outcome.cpu = time.perf_counter() - wall, time.process_time() - cpu
    return outcome


@dataclass
class Result:
    """The search's outcome: the best candidate that met every constraint (None if none did)."""

    best: Gait | None
    values: list[float]
    """The best candidate's free parameter values (as rounded into its file)."""
    value: float
    """Its objective (NaN when there is no best)."""
    start_value: float
    """The starting gait's objective (NaN when it broke a constraint)."""
    start_problem: str
    evaluations: int = 0
    rejected: int = 0
    """Candidates refused for a constraint or an invalid file."""
    generations: int = 0
    interrupted: bool = False
    history: list[float] = field(default_factory=list)
    """The best objective after each generation."""
    samples: list[tuple[list[float], float]] = field(default_factory=list)
    """Every candidate searched: its free values and its objective (NaN when refused), in the order asked."""
    refused_value: float = math.nan
    """The best objective among the candidates refused for a constraint (what keeping the constraints cost)."""
    verified: bool = False
    """The best held every constraint over the longer check run too (False after an interruption: not checked)."""
    verify_value: float = math.nan
    """The best's objective over the longer check run: a score found in short runs can be luck, and this says how
    it held (the search's own value is the one its file reproduces over the search's run)."""
    verify_refused: int = 0
    """Leading candidates that broke a constraint in the longer check run and were passed over."""
    busy: float = 0.0
    """Seconds the workers spent simulating, in all (Outcome.wall)."""
    cpu: float = 0.0
    """CPU seconds they got meanwhile (Outcome.cpu)."""
    simulated: float = 0.0
    """Simulated seconds in all, the final check's runs included."""
    setup: Setup | None = None
    """The setup searched with, its defaults filled in (the torque limit, the forward direction)."""
    failure: str = ""
    """Why the executor given to tune() stopped answering mid-search (empty: it did not); the best so far is kept."""
    start_inside: bool = True
    """The starting gait's values lie inside the free parameters' bounds (else it is measured, never the result)."""

    def account(self, outcomes: list[Outcome], setup: Setup) -> None:
        self.simulated += len(outcomes) * len(setup.terrains) * (setup.warmup + setup.seconds)
        self.busy += sum(o.wall for o in outcomes)
        self.cpu += sum(o.cpu for o in outcomes)


Progress = Callable[[Result, str], None]
"""Called after every generation with the result so far and a one-line summary; may raise KeyboardInterrupt."""


def tune(gait: Gait, frees: list[Free], setup: Setup, *, budget: int = 60, seed: int = 1, workers: int | None = None,
         popsize: int | None = None, progress: Progress | None = None,
         executor: Executor | None = None) -> Result:  # fmt: skip
    """Search ``frees`` to optimise ``setup.objective``; at most ``budget`` simulations, the start's included."""
    check(gait, frees)
    if setup.gait not in gait.program_gaits():
        raise ValueError(f"the file has no gait {setup.gait!r} (it has {', '.join(gait.program_gaits())})")
    if setup.objective not in OBJECTIVES:
        raise ValueError(f"objective must be one of {', '.join(OBJECTIVES)}, not {setup.objective!r}")
    setup = resolved(setup, gait)
    document = to_dict(gait, inline=True)  # the workers read no robot file: they may run anywhere
    low = np.array([f.low for f in frees])
    span = np.array([f.high - f.low for f in frees])
    start = [current(gait, f) for f in frees]
    x0 = np.clip((np.array(start) - low) / span, 0.0, 1.0)
    if len(x0) == 1:  # cma searches 2 or more dimensions: one free parameter gets a dummy one, ignored
        x0 = np.append(x0, 0.5)
    own = executor is None
    pool = executor or ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1, initializer=start_worker)
    result = Result(None, [], math.nan, math.nan, "", setup=setup)
    result.start_inside = all(f.low <= v <= f.high for f, v in zip(frees, start, strict=True))
    sign = OBJECTIVES[setup.objective][0]
    order = itertools.count()
    leaders: list[Leader] = []
    fallback: Leader | None = None

    def lead(value: float, values: list[float], doc: dict[str, Any]) -> None:
        leaders.append((-sign * value, next(order), values, doc))
        leaders.sort(key=lambda entry: entry[:2])
        del leaders[LEADERS:]

    try:
        es = _strategy(x0, seed, popsize, budget)
        while result.evaluations < budget and not es.stop():
            first = result.evaluations == 0  # the start runs with the first generation: no core waits for it alone
            xs = es.ask()
            xs = xs[: budget - result.evaluations - first]
            points = [xi[: len(frees)] for xi in xs]
            candidates = [[f.rounded(lo + x * s) for f, lo, s, x in zip(frees, low, span, p, strict=True)]
                          for p in points]  # fmt: skip
            documents = [apply(document, frees, values) for values in candidates]
            outcomes = list(pool.map(_evaluate_job, [(d, setup) for d in [document] * first + documents]))
            result.evaluations += len(outcomes)
            result.account(outcomes, setup)
            result.generations += 1
            if first:
                own_start, outcomes = outcomes[0], outcomes[1:]
                result.start_value = own_start.value if own_start.feasible else math.nan
                result.start_problem = own_start.problem
                if own_start.feasible and result.start_inside:  # a start outside the bounds is no answer to them
                    result.best, result.values, result.value = gait, start, own_start.value
                    lead(own_start.value, start, document)
                    fallback = leaders[0]
                elif not own_start.feasible:
                    result.rejected += 1
            for values, doc, outcome in zip(candidates, documents, outcomes, strict=True):
                result.samples.append((values, outcome.value if outcome.feasible else math.nan))
                if not outcome.feasible:
                    result.rejected += 1
                    if not math.isnan(outcome.value) and not sign * outcome.value <= sign * result.refused_value:
                        result.refused_value = outcome.value
                else:
                    lead(outcome.value, values, doc)
                    if math.isnan(result.value) or sign * outcome.value > sign * result.value:
                        result.best, result.values, result.value = from_dict(doc), values, outcome.value
            if len(xs) == es.popsize:  # a budget's last, partial generation is not told: CMA-ES wants all of it
                es.tell(xs, [o.score for o in outcomes])
            result.history.append(result.value)
            if progress is not None:
                best = min((o for o in outcomes if o.feasible), key=lambda o: -sign * o.value, default=None)
                progress(result, _line(result, setup, best, outcomes, float(es.sigma), budget))
        _verify(result, leaders, pool, setup, fallback)  # the start checked beside the first leaders
    except KeyboardInterrupt:
        result.interrupted = True
    except Exception as exc:
        if own:
            raise
        # someone else's executor went away (a Dask scheduler lost, a pool killed): the best so far stands, as after
        # Ctrl-C, and the failure is said
        result.interrupted = True
        result.failure = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    finally:
        if own:
            if result.interrupted:  # its running simulations killed, not waited for
                stop_pool(pool)
            else:
                pool.shutdown(wait=True, cancel_futures=True)
    return result


def resolved(setup: Setup, gait: Gait) -> Setup:
    """``setup`` with its defaults filled in for ``gait``: its servos' torque limit, and for speed and cost of
    transport the direction the gait travels on flat ground (see ``Setup.forward``)."""
    if setup.max_torque is None:
        setup = replace(setup, max_torque=default_max_torque(gait))
    if setup.forward is None and setup.objective in ("speed", "cost_of_transport"):
        setup = replace(setup, forward=forward_heading(gait, setup))
    return setup


def forward_heading(gait: Gait, setup: Setup) -> float | None:
    """Degrees from +x the starting gait travels on flat ground over the setup's run (None: it hardly moves, a
    tenth of a body length, so no direction is its own: then distance counts, whichever way)."""
    from .sim import Simulation  # MuJoCo loads where it runs

    with Simulation(gait) as sim:
        sim.start()
        if setup.gait != FORWARD:
            sim.drive(setup.gait)
        metrics = sim.run(setup.seconds, warmup=setup.warmup)
    return round(metrics.heading, 3) if metrics.body_lengths >= 0.1 else None


Leader = tuple[float, int, list[float], dict[str, Any]]
"""A valid candidate kept for the final check: (score, order found, values, document); sorted, the best first."""


def _verify(result: Result, leaders: list[Leader], pool: Executor, setup: Setup, start: Leader | None) -> None:
    """The final check: leaders run ``setup.verify`` × the search's run, CHECK_ROUND at a time, the start with the
    first round. Of a round's leaders that keep every constraint and, when the start held, do at least as well as
    the start over the longer run (a score a short run found by luck — a tumble end over end that looked fast —
    does not), the best-scored in the search is the best; none in any round: the start if it held, else no best (the
    start is only the floor: were it a candidate of the first round, its holding would end the check there with the
    start as best whenever that round's two leaders failed, and the next rounds' leaders never ran — as it did, from
    c3e1d78 on: the flat caterpillar's tuned gait was the library's own). The search's value stays the
    result's (its file reproduces it), the longer run's is ``verify_value``. Interrupted, the best is never a leader
    the check already refused."""
    longer = replace(setup, seconds=setup.seconds * setup.verify)
    sign = OBJECTIVES[setup.objective][0]
    # only the leaders the search scored above the start are checked: one below it is never written over it
    ahead = next((k for k, leader in enumerate(leaders) if leader is start), len(leaders))
    rest = leaders[:ahead]
    batch = rest[:CHECK_ROUND] + ([start] if start is not None else [])
    rest = rest[CHECK_ROUND:]
    start_held: tuple[float, Leader] | None = None
    while batch:
        outcomes = list(pool.map(_evaluate_job, [(doc, longer) for *_, doc in batch]))
        result.account(outcomes, longer)
        held = [(outcome.value, leader) for leader, outcome in zip(batch, outcomes, strict=True) if outcome.feasible]
        if start is not None and start in batch:  # the start is the floor, not a leader: the next round may hold
            start_held = next((h for h in held if h[1] is start), None)
            held = [h for h in held if h[1] is not start]
            batch = [leader for leader in batch if leader is not start]
        result.verify_refused += len(batch) - len(held)  # leading candidates only: the start is not one
        if start_held is not None:  # a leader that does worse than the start over the longer run is passed over
            floor = start_held[0]
            result.verify_refused += sum(sign * value < sign * floor for value, _ in held)
            held = [(value, leader) for value, leader in held if sign * value >= sign * floor]
        if held:  # the best search score of those that held
            _take(result, min(held, key=lambda h: h[1][:2]), sign)
            return
        # What an interruption from here on keeps: the start if it held (a review saw an unchecked leader written,
        # scored below the start), else the next leader — never one the check refused.
        if start_held is not None:
            _take(result, start_held, sign)
        elif rest:
            score, _, values, doc = rest[0]
            result.best, result.values, result.value = from_dict(doc), values, -sign * score
            result.verified = False
        batch, rest = rest[:CHECK_ROUND], rest[CHECK_ROUND:]
    if start_held is not None:  # no leader held in any round: the start, which did
        _take(result, start_held, sign)
        return
    result.best, result.values, result.value = None, [], math.nan


def _take(result: Result, held: tuple[float, Leader], sign: float) -> None:
    """``held``'s leader is the best: its search score stays the result's value, the longer run's is verify_value."""
    value, (score, _, values, doc) = held
    result.best, result.values, result.verified = from_dict(doc), values, True
    result.verify_value, result.value = value, -sign * score


def _strategy(x0: np.ndarray, seed: int, popsize: int | None, budget: int) -> Any:
    with warnings.catch_warnings():  # cma warns that matplotlib (its plots) is missing
        warnings.simplefilter("ignore")
        import cma
    # cma's seed 0 means a random one; the budget alone ends the search (a generation of refused candidates
    # scores alike, and cma's flat-fitness and tolfun stops would end it there)
    options: dict[str, Any] = {"seed": seed + 1, "bounds": [0.0, 1.0], "verbose": -9, "tolfun": 0.0,
                               "tolfunhist": 0.0, "tolflatfitness": budget}  # fmt: skip
    default = 4 + int(3 * math.log(len(x0)))
    options["popsize"] = max(2, min(popsize or default, budget - 1))
    return cma.CMAEvolutionStrategy(x0.tolist(), 0.3, options)


def _line(result: Result, setup: Setup, best: Outcome | None, outcomes: list[Outcome], sigma: float,
          budget: int) -> str:  # fmt: skip
    gen = f"{best.value:.4g}" if best is not None else "none valid"
    refused = sum(not o.feasible for o in outcomes)
    return (f"generation {result.generations}: {result.evaluations} of {budget} simulations, best {setup.objective} "
            f"{'none yet' if math.isnan(result.value) else amount(result.value, setup)} (this generation {gen}, "
            f"{refused} refused), "
            f"sigma {sigma:.3f}")  # fmt: skip


def provenance(result: Result, frees: list[Free], setup: Setup, *, budget: int, seed: int, source: str) -> str:
    """The comment lines at the top of a tuned file: how it was made, so it can be made again."""
    setup = result.setup or setup
    max_torque = setup.max_torque
    if max_torque is None and result.best is not None:  # a robot of several servos, or a result put together
        max_torque = default_max_torque(result.best)  # before the search filled it in (the studio's, stopped early)
    limit = (f"peak torque <= {TORQUE_MARGIN:.0%} of each module's stall torque" if max_torque is None
             else f"peak torque <= {max_torque:g} N·m")  # fmt: skip
    goal = "maximised" if OBJECTIVES[setup.objective][0] > 0 else "minimised"
    start = amount(result.start_value, setup) if result.start_problem == "" else f"refused: {result.start_problem}"
    checked = (f"held again over {setup.seconds * setup.verify:g} s, {setup.objective} "
               f"{amount(result.verify_value, setup)} there ({result.verify_refused} leading candidates broke a "
               "constraint or did worse than the start there)"
               if result.verified else "not checked over a longer run (interrupted)")  # fmt: skip
    lines = [
        f"Tuned by `gaits tune` from {source}: objective {setup.objective} ({goal}), seed {seed}, budget {budget} "
        f"({result.evaluations} simulated{', interrupted' if result.interrupted else ''})",
        f"gait {setup.gait}; terrains {', '.join(t.spec for t in setup.terrains)}; {setup.seconds:g} s measured after "
        f"{setup.warmup:g} s" + _forward(setup),
        f"score {setup.objective} {amount(result.value, setup)} (start {start})",
        f"constraints: {limit} (warm-up included), no fall, joint limits (the loader's); {checked}",
        *(f"free {f} = {v:g}" for f, v in zip(frees, result.values, strict=True)),
    ]
    return "".join(f"# {line}\n" for line in lines)


def _forward(setup: Setup) -> str:
    if setup.forward is not None:
        return f"; forward = {setup.forward + 0.0:g}° from +x (the start's direction)"
    if setup.objective == "cost_of_transport" or setup.objective == "speed":
        return f"; forward: none ({STILL})"
    return ""


STILL = "the start moved less than a tenth of a body length, so distance counts whichever way"
"""Why a search has no forward direction (Setup.forward None): the start hardly moves."""


def source_of(name: str, gait: Gait) -> str:
    """What a tuned file was tuned from, as its provenance says: ``name``, and the robot file that describes its
    modules (the tuned file carries the description written in)."""
    return name + (f" (its modules described by the robot file {gait.robot.file})" if gait.robot.file else "")


def tuned_text(result: Result, frees: list[Free], setup: Setup, *, budget: int, seed: int, source: str) -> str:
    """The tuned gait file: its provenance in comments, then the best gait, described by what it was tuned for."""
    assert result.best is not None
    header = provenance(result, frees, setup, budget=budget, seed=seed, source=source)
    return header + dumps(replace(result.best, description=_described(result, setup)))


def amount(value: float, setup: Setup) -> str:
    """An objective's value with its unit, as the command line, the file's comments and the page print it."""
    unit = OBJECTIVES[setup.objective][1]
    return f"{value:.4g} {unit}" if unit else f"{value:.4g}"


def _described(result: Result, setup: Setup) -> str:
    """The tuned file's description: what it was tuned for first (the studio shows it), then the old one; within the
    schema's 4096 characters however often a file is tuned again."""
    assert result.best is not None
    terrains = ", ".join(t.kind for t in setup.terrains)
    text = f"Tuned for {setup.objective} ({amount(result.value, setup)} on {terrains}) from: {result.best.description}"
    return text.strip()[:4096]
