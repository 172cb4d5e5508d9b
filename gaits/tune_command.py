"""``gaits tune``, the command: parse, search (gaits/tune.py), write the best gait — also after Ctrl-C or SIGTERM,
as a scheduler's ``timeout`` sends it — and say how it went in one line per outcome."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from pathlib import Path

from .model import GaitError, load
from .params import Free, check, current
from .terrain import FLAT
from .tune import Progress, Setup, amount, tune, tuned_text


def _terminate_as_interrupt() -> threading.Event:
    """SIGTERM raises KeyboardInterrupt in the main thread, as Ctrl-C does: the best so far is kept and written, and
    the worker processes are shut down (killed outright, the parent would leave them orphaned). The event says a
    SIGTERM came (exit 143, not 130)."""
    terminated = threading.Event()

    def interrupt(*_: object) -> None:
        terminated.set()
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
    return terminated


def command(args: argparse.Namespace) -> int:
    """``gaits tune``: parse, search, write the best gait (also after Ctrl-C); exit 1 when nothing met the
    constraints, 130 after an interruption."""
    try:
        gait = load(args.file)
    except (GaitError, OSError) as exc:
        print(f"gaits tune: error: {args.file}: {exc.lines()[0] if isinstance(exc, GaitError) else exc}",
              file=sys.stderr)  # fmt: skip
        return 1
    frees: list[Free] = args.free
    setup = Setup(args.objective, tuple(args.terrain or [FLAT]), args.seconds, args.warmup, args.max_torque, args.gait)
    out = Path(args.out) if args.out else Path(Path(args.file).stem + ".tuned.toml")  # here, not beside the library
    if out.resolve() == Path(args.file).resolve() or (out.exists() and out.samefile(args.file)):  # a hard link too
        print(f"gaits tune: error: --out {out} is the gait being tuned: write the tuned gait to another file",
              file=sys.stderr)  # fmt: skip
        return 2
    try:  # the free parameters against this gait, before anything starts: a usage error, as a bad one's syntax is
        check(gait, frees)
    except ValueError as exc:
        print(f"gaits tune: error: {exc}", file=sys.stderr)
        return 2
    print(f"tuning {gait.name}: {len(frees)} free, {args.objective}, budget {args.budget}, seed {args.seed}",
          file=sys.stderr)  # fmt: skip
    progress: Progress = lambda _, line: print(line, file=sys.stderr, flush=True)  # noqa: E731
    terminated = _terminate_as_interrupt()  # a scheduler's SIGTERM or `timeout` ends it as Ctrl-C does
    if args.scheduler:
        from .distributed import dask_executor

        try:
            with dask_executor(args.scheduler) as (executor, width):
                print(f"evaluating on the Dask scheduler at {args.scheduler}: {width} worker thread(s)",
                      file=sys.stderr)  # fmt: skip
                result = tune(gait, frees, setup, budget=args.budget, seed=args.seed, workers=width,
                              progress=progress, executor=executor)  # fmt: skip
        except (OSError, RuntimeError) as exc:
            print(f"gaits tune: error: the Dask scheduler at {args.scheduler}: {exc}", file=sys.stderr)
            return 1
    else:
        result = tune(gait, frees, setup, budget=args.budget, seed=args.seed, workers=args.workers,
                      progress=progress)  # fmt: skip
    if result.failure:
        print(f"gaits tune: error: the Dask scheduler at {args.scheduler} stopped answering ({result.failure}): "
              "keeping the best so far", file=sys.stderr)  # fmt: skip
    elif result.interrupted:
        print("interrupted: keeping the best so far", file=sys.stderr)
    elif result.verify_refused:
        print(f"{result.verify_refused} leading candidate(s) broke a constraint or did worse than the start when "
              f"run {setup.verify:g} times longer and were passed over", file=sys.stderr)  # fmt: skip
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    stopped = 143 if terminated.is_set() else 130
    if result.best is None:
        inside = "" if result.start_inside else " inside the bounds (the start lies outside them)"
        start = f"; the start: {result.start_problem}" if result.start_problem else ""
        hint = (" (--max-torque sets the limit: by default 95 % of the servos' stall torque)"
                if "peak torque" in result.start_problem else "")  # fmt: skip
        print(f"gaits tune: error: no candidate{inside} met the constraints{start}{hint}; nothing written",
              file=sys.stderr)  # fmt: skip
        return stopped if result.interrupted and not result.failure else 1
    if result.start_inside and result.values == [current(gait, f) for f in frees]:
        print("no candidate beat the start inside the bounds: the start is written again", file=sys.stderr)
    out.write_text(tuned_text(result, frees, setup, budget=args.budget, seed=args.seed, source=Path(args.file).name),
                   encoding="utf-8")  # fmt: skip
    if result.verified:
        print(f"over the {setup.seconds * setup.verify:g} s check run: {args.objective} "
              f"{amount(result.verify_value, setup)}", file=sys.stderr)  # fmt: skip
    print(f"{args.objective} {amount(result.value, setup)} (start {result.start_value:.4g}); written to {out}")
    return 1 if result.failure else stopped if result.interrupted else 0
