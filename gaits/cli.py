"""The ``gaits`` command: validate a gait file, or print its expanded control table.

gaits validate FILE...        exit 1 and list every problem (with its line) if a file is bad
gaits expand FILE [--samples 16]
gaits simulate FILE [--seconds 10] [--warmup 2] [--direction -1] [--push-at 6] [--mjcf OUT.xml] [--terrain SPEC]…
                               run it in MuJoCo (headless, on the modules' own runtime) and print the metrics,
                               once per terrain (gaits/terrain.py: flat, slope:5, step:0.03, rough:seed=3, …)
gaits tune FILE --free NAME=LOW:HIGH… [--objective speed] [--budget 60] [--seed 1] [--terrain SPEC]…
           [--scheduler tcp://HOST:PORT] [--out FILE]
                               search the free parameters with CMA-ES in simulation (gaits/tune.py)
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from asm_py.cli import bounded, output_file, reader_gone, run, summary

from .distributed import scheduler_address
from .metrics import unsigned_zero
from .model import GaitError, load
from .params import argument as free_argument
from .table import format_table
from .terrain import FLAT, Terrain
from .terrain import argument as terrain_argument

TICK = 0.02
"""Seconds of one control tick at the simulation's 50 Hz (gaits.sim.Simulation's control_rate, not imported here:
parsing the flags loads no MuJoCo; tests/gaits/test_metrics.py keeps the two equal): the shortest time a run can
measure."""

if TYPE_CHECKING:
    from .sim import Metrics


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(argv)
    except BrokenPipeError:  # `gaits expand FILE | head`
        return reader_gone()


def _main(argv: list[str] | None) -> int:
    cli = argparse.ArgumentParser(prog="gaits", description=summary(__doc__))
    commands = cli.add_subparsers(dest="command", required=True)
    validate = commands.add_parser("validate", help="check gait files")
    validate.add_argument("files", nargs="+")
    expand = commands.add_parser("expand", help="print the module x time table")
    expand.add_argument("file")
    expand.add_argument("--samples", type=bounded(int, 1, 1024, what="samples per period"), default=16,
                        help="samples per period, 1..1024 (default 16)")  # fmt: skip
    simulate = commands.add_parser("simulate", help="run the gait in MuJoCo and print the metrics")
    simulate.add_argument("file")
    simulate.add_argument("--seconds", type=bounded(float, TICK, 3600, what="the measured time"),
                          default=10.0, help="measured simulated time, seconds (default 10)")  # fmt: skip
    simulate.add_argument("--warmup", type=bounded(float, 0, 3600, what="the warm-up"), default=2.0,
                          help="simulated seconds before measuring (default 2)")  # fmt: skip
    simulate.add_argument("--direction", type=int, choices=(1, -1), default=1, help="-1 runs every automaton backwards")
    simulate.add_argument("--push-at", type=bounded(float, 0, 3600, what="the push time"),
                          help="push the robot sideways (1 N, 0.1 s) at this simulated time")  # fmt: skip
    simulate.add_argument("--mjcf", type=output_file, metavar="OUT.xml",
                          help="also write the model (the first terrain's) as MJCF for MuJoCo's viewer")  # fmt: skip
    simulate.add_argument("--terrain", type=terrain_argument, action="append", default=[], metavar="SPEC",
                          help="flat (default), slope:DEG, step:HEIGHT, rough:seed=N,roughness=M, patches:friction=MU; "
                          "repeat for several (metrics for each)")  # fmt: skip
    tune = commands.add_parser("tune", help="tune free parameters of a gait with CMA-ES in simulation")
    tune.add_argument("file")
    tune.add_argument("--free", type=free_argument, action="append", required=True, metavar="NAME=LOW:HIGH",
                      help="a free parameter and its range, e.g. automata.wave.states[3].angle=20:70, "
                      "modules[2].phase=0:1, amplitude=20:80, wavelength=4:12, period=0.5:2 (repeat)")  # fmt: skip
    tune.add_argument("--objective", choices=("speed", "cost_of_transport", "heading_rate"), default="speed",
                      help="maximise speed (default), minimise cost of transport, maximise |heading rate|")  # fmt: skip
    tune.add_argument("--budget", type=bounded(int, 1, 100_000, what="the budget"), default=60,
                      help="simulations (candidates) in all, the start included (default 60)")  # fmt: skip
    tune.add_argument("--seed", type=bounded(int, 0, 2**31 - 2, what="the seed"), default=1,
                      help="the search's seed: the same seed gives the same result (default 1)")  # fmt: skip
    tune.add_argument(
        "--terrain",
        type=terrain_argument,
        action="append",
        default=[],
        metavar="SPEC",
        help="evaluate on this terrain (repeat: the objective is the mean over them; default flat)",
    )
    tune.add_argument("--workers", type=bounded(int, 1, 256, what="workers"), default=None,
                      help="worker processes (default: one per CPU core)")  # fmt: skip
    tune.add_argument("--seconds", type=bounded(float, TICK, 600, what="the measured time"), default=6.0,
                      help="simulated seconds measured per candidate (default 6)")  # fmt: skip
    tune.add_argument("--warmup", type=bounded(float, 0, 600, what="the warm-up"), default=1.0,
                      help="simulated seconds before measuring (default 1)")  # fmt: skip
    tune.add_argument("--max-torque", type=bounded(float, above=0, high=10_000, what="the torque limit"), default=None,
                      help="peak joint torque allowed, N·m, at most 10000 as a stall torque (default 95%% of the "
                      "gait's own servos' stall torque, [robot.module] stall_torque: 1.425 for the library "
                      "module)")  # fmt: skip
    tune.add_argument(
        "--gait",
        default="forward",
        metavar="NAME",
        help="the program gait to simulate: forward (default) or one of the file's [gaits], e.g. left",
    )
    tune.add_argument("--scheduler", metavar="ADDRESS", default=None, type=scheduler_address,
                      help="run the simulations on the Dask distributed scheduler at ADDRESS (tcp://HOST:PORT) "
                      "instead of local worker processes (gaits/distributed.py)")  # fmt: skip
    tune.add_argument(
        "--out",
        type=output_file,
        metavar="OUT.toml",
        help="the tuned gait (default: NAME.tuned.toml in the current folder, NAME the file's stem; never over FILE "
        "or its robot file)",
    )
    args = cli.parse_args(argv)
    if args.command == "simulate":
        return run("gaits simulate", lambda: _simulate(args))
    if args.command == "tune":
        from .tune_command import command  # cma and MuJoCo load only for this command

        # the process is the command's own only when its arguments are (`gaits`, `python -m gaits.cli`): a caller
        # of main(argv) in its own process (a test, a notebook) must not inherit its exit deadline
        return run("gaits tune", lambda: command(args, own_process=argv is None))
    if args.command == "validate":
        return _validate(args.files)
    try:
        gait = load(args.file)
    except (GaitError, OSError) as exc:
        _report(args.file, exc)
        return 1
    if not gait.timed:
        print(f"gaits expand: error: {args.file}: {gait.name} has automata that wait for events or end (one-shot), "
              "so its timing is not a table; `gaits simulate` runs it", file=sys.stderr)  # fmt: skip
        return 1
    print(format_table(gait, samples=args.samples))
    return 0


def _report(path: str, exc: GaitError | OSError) -> None:
    print(f"{path}: INVALID", file=sys.stderr)
    lines = exc.lines() if isinstance(exc, GaitError) else [exc.strerror or str(exc)]
    for line in lines:
        print(f"  {line}", file=sys.stderr)


def _validate(files: list[str]) -> int:
    """Exit 1 if any file is bad; every file gets one verdict line, a bad one its problems (at most 50)."""
    failed = 0
    for path in files:
        try:
            gait = load(path)
        except (GaitError, OSError) as exc:
            failed += 1
            _report(path, exc)
            continue
        print(f"{path}: ok ({gait.name}: {gait.robot.modules} modules, {len(gait.automata)} automata)")
    return 1 if failed else 0


def _simulate(args: argparse.Namespace) -> int:
    """One run per terrain; each prints its metrics."""
    from pathlib import Path

    from .output import refused
    from .sim import Simulation  # MuJoCo loads only for this command

    try:
        gait = load(args.file)
    except (GaitError, OSError) as exc:
        _report(args.file, exc)
        return 1
    robot = gait.robot
    why = refused(Path(args.mjcf), args.file, gait) if args.mjcf else None
    if why is not None:
        print(f"gaits simulate: error: --mjcf {args.mjcf} {why}", file=sys.stderr)
        return 2
    timing = f"period {gait.period:g} s" if gait.timed else "timed by events"
    print(f"{gait.name}: {robot.modules}-module {robot.shape}, {timing}, direction {args.direction:+d}")
    for k, terrain in enumerate(args.terrain or [FLAT]):
        with Simulation(gait, direction=args.direction, terrain=terrain) as sim:
            if args.mjcf and k == 0:
                Path(args.mjcf).write_text(sim.mjcf, encoding="utf-8")
                print(f"model written to {args.mjcf}")
            try:
                metrics = sim.run(args.seconds, warmup=args.warmup, push_at=args.push_at)
            except FloatingPointError as exc:
                print(f"gaits simulate: error: {args.file} on {terrain.spec}: {exc}", file=sys.stderr)
                return 1
        _print_metrics(terrain, metrics)
    return 0


def _print_metrics(terrain: Terrain, metrics: Metrics) -> None:
    print(f"terrain      {terrain.spec}")
    print(
        f"distance     {metrics.distance:.3f} m ({metrics.body_lengths:.2f} body lengths of {metrics.body_length:g} m)"
    )
    print(f"mean speed   {metrics.speed:.3f} m/s ({metrics.body_lengths_per_10s:.2f} BL per 10 s)")
    print(
        f"heading      {metrics.heading_text()}, drift {unsigned_zero(metrics.turned, 1)} "
        f"degrees ({unsigned_zero(metrics.heading_rate, 2)} degrees/s)"
    )
    print(f"cost of transport {metrics.cost_text()}; {metrics.energy:.1f} J of joint work for {metrics.mass:.2f} kg")
    print(f"peak torque  {metrics.peak_torque:.2f} N·m")
    print(f"fell         {'yes' if metrics.fell else 'no'}")
    print(f"stuck        {'yes' if metrics.stuck else 'no'} (under half a body length per 10 s)")
    print(f"speed-up     {metrics.real_time_factor:.1f}x real time")


if __name__ == "__main__":
    raise SystemExit(main())
