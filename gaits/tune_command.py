"""``gaits tune``, the command: parse, search (gaits/tune.py), write the best gait — also after Ctrl-C or SIGTERM,
as a scheduler's ``timeout`` sends it — and say how it went in one line per outcome."""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TextIO

from tqdm import tqdm

from .model import Gait, GaitError, load
from .output import refused, write_whole
from .params import Free, check, current
from .terrain import FLAT
from .tune import OBJECTIVES, STILL, Result, Setup, amount, source_of, tune, tuned_text


def _interrupt_once(own_process: bool) -> list[int]:
    """Ctrl-C and SIGTERM raise KeyboardInterrupt in the main thread, once: the search stops, its workers end
    (killed outright, the parent would leave them orphaned) and the best so far is written. From then on both are
    ignored: a second Ctrl-C interrupted the wrap-up or the interpreter's exit, left a traceback and hung the command
    on its pool half shut down. The list holds the signal that came (SIGTERM: exit 143, not 130). In the command's
    own process the first also starts the clock of ``EXIT_DEADLINE``."""
    came: list[int] = []

    def interrupt(number: int, _: object) -> None:
        _ignore_signals()
        came.append(number)
        if own_process:
            _exit_by_deadline(143 if number == signal.SIGTERM else 130)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    signal.signal(signal.SIGTERM, interrupt)
    return came


EXIT_DEADLINE = 30.0
"""Seconds an interrupted command has to write its best gait and exit. Past them it ends at once, saying so: a CI run
saw one not end within 60 s of a double Ctrl-C (once in ~40 runs, not reproduced since; read, not proved: an exit
handler joining a pool thread that never ended). An interrupted search normally ends in 1-3 s."""


def _exit_by_deadline(code: int) -> None:
    """Start the clock of ``EXIT_DEADLINE`` on a daemon thread, which still runs while the interpreter's exit
    handlers do (where the hang was), and which the exit does not wait for."""

    def watch() -> None:
        time.sleep(EXIT_DEADLINE)
        try:
            sys.stderr.write(f"gaits tune: did not exit within {EXIT_DEADLINE:g} s of the interruption: ending it "
                             "now\n")  # fmt: skip
            sys.stderr.flush()
        finally:
            os._exit(code)

    threading.Thread(target=watch, name="gaits-tune-exit-deadline", daemon=True).start()


def _ignore_signals() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)


class Bar:
    """The search's progress on stderr: a bar of the simulations done out of the budget, with the best so far, on a
    terminal (tqdm); one line per generation, saying how many of the budget, where stderr is a file or a pipe."""

    def __init__(self, budget: int, setup: Setup, stream: TextIO | None = None) -> None:
        self.setup = setup
        self.stream: TextIO = stream or sys.stderr
        self.bar = tqdm(total=budget, file=self.stream, desc="tuning", dynamic_ncols=True,
                        disable=not self.stream.isatty(),
                        bar_format="{desc} {percentage:3.0f}%|{bar}| {n}/{total} simulations "
                        "[{elapsed}<{remaining}]{postfix}")  # fmt: skip

    def __call__(self, result: Result, line: str) -> None:
        if self.bar.disable:
            print(line, file=self.stream, flush=True)
            return
        best = "none yet" if math.isnan(result.value) else amount(result.value, self.setup)
        self.bar.set_postfix_str(f"best {self.setup.objective} {best}", refresh=False)
        self.bar.update(result.evaluations - self.bar.n)

    def close(self) -> None:
        self.bar.close()


def command(args: argparse.Namespace, *, own_process: bool = False) -> int:
    """``gaits tune``: parse, search, write the best gait (also after Ctrl-C); exit 1 when nothing met the
    constraints, 130 after an interruption. ``own_process``: the process is the command's, to end after an
    interruption (by ``EXIT_DEADLINE``, the signals ignored meanwhile); else its caller's, which goes on after it
    with its own signal handlers back."""
    try:
        gait = load(args.file)
    except (GaitError, OSError) as exc:
        print(f"gaits tune: error: {args.file}: {exc.lines()[0] if isinstance(exc, GaitError) else exc}",
              file=sys.stderr)  # fmt: skip
        return 1
    frees: list[Free] = args.free
    setup = Setup(args.objective, tuple(args.terrain or [FLAT]), args.seconds, args.warmup, args.max_torque, args.gait)
    out = Path(args.out) if args.out else Path(Path(args.file).stem + ".tuned.toml")  # here, not beside the library
    why = refused(out, args.file, gait)  # before the search: an hour's work must not end unwritable
    if why is not None:
        print(f"gaits tune: error: --out {out} {why}: write the tuned gait to another file", file=sys.stderr)
        return 2
    try:  # the free parameters against this gait, before anything starts: a usage error, as a bad one's syntax is
        check(gait, frees)
    except ValueError as exc:
        print(f"gaits tune: error: {exc}", file=sys.stderr)
        return 2
    print(f"tuning {gait.name}: {len(frees)} free, {args.objective}, budget {args.budget}, seed {args.seed}",
          file=sys.stderr)  # fmt: skip
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    came = _interrupt_once(own_process)  # a scheduler's SIGTERM or `timeout` ends it as Ctrl-C does
    bar = Bar(args.budget, setup)
    try:
        try:
            result = _search(args, gait, frees, setup, bar)
        except FloatingPointError as exc:  # the start's own run, which finds its forward direction, diverged
            bar.close()
            print(f"gaits tune: error: {args.file}: the starting gait: {exc}: nothing to tune from", file=sys.stderr)
            return 1
        _ignore_signals()  # the search is over: the file is written whole
        bar.close()
        if result is None:
            return 1
        return _wrap_up(args, gait, frees, setup, result, out, 143 if signal.SIGTERM in came else 130)
    finally:
        bar.close()
        if not came or not own_process:  # interrupted, its own process is ending: a signal would only interrupt it
            signal.signal(signal.SIGINT, handlers[0])
            signal.signal(signal.SIGTERM, handlers[1])


def _search(args: argparse.Namespace, gait: Gait, frees: list[Free], setup: Setup, bar: Bar) -> Result | None:
    """The search, on local workers or a Dask scheduler's (None: the scheduler could not be used)."""
    if not args.scheduler:
        return tune(gait, frees, setup, budget=args.budget, seed=args.seed, workers=args.workers, progress=bar)
    from .distributed import dask_executor

    try:
        with dask_executor(args.scheduler, say=lambda line: print(line, file=sys.stderr)) as (executor, width):
            print(f"evaluating on the Dask scheduler at {args.scheduler}: {width} worker thread(s)", file=sys.stderr)
            return tune(gait, frees, setup, budget=args.budget, seed=args.seed, workers=width, progress=bar,
                        executor=executor)  # fmt: skip
    except (OSError, RuntimeError) as exc:
        bar.close()
        print(f"gaits tune: error: the Dask scheduler at {args.scheduler}: {exc}", file=sys.stderr)
        return None


def _wrap_up(args: argparse.Namespace, gait: Gait, frees: list[Free], setup: Setup, result: Result, out: Path,
             stopped: int) -> int:  # fmt: skip
    """Say how the search went and write the best gait (or say why nothing is written)."""
    if result.failure:
        print(f"gaits tune: error: the Dask scheduler at {args.scheduler} {result.failure}: keeping the best so far",
              file=sys.stderr)  # fmt: skip
    elif result.interrupted:
        print("interrupted: keeping the best so far", file=sys.stderr)
    elif result.verify_refused:
        print(f"{result.verify_refused} leading candidate(s) broke a constraint or did worse than the start when "
              f"run {setup.verify:g} times longer and were passed over", file=sys.stderr)  # fmt: skip
    if result.setup is not None and result.setup.forward is None and args.objective != "heading_rate":
        print(f"warning: {STILL}: can this robot move this gait? (a module's kp must grow with its stall_torque "
              "and mass: gaits/README.md)", file=sys.stderr)  # fmt: skip
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
    sign = OBJECTIVES[setup.objective][0]
    worse = sign * result.value < sign * result.start_value  # False when the start has no value (nan)
    if not result.start_inside and worse:
        print(f"warning: the best inside the bounds ({amount(result.value, setup)}) is worse than the start "
              f"({amount(result.start_value, setup)}), which lies outside them: it is written, as asked; bounds that "
              "hold the start keep it unless something beats it", file=sys.stderr)  # fmt: skip
    text = tuned_text(result, frees, setup, budget=args.budget, seed=args.seed,
                      source=source_of(Path(args.file).name, gait))  # fmt: skip
    if result.verified:
        print(f"over the {setup.seconds * setup.verify:g} s check run: {args.objective} "
              f"{amount(result.verify_value, setup)}", file=sys.stderr)  # fmt: skip
    values = ", ".join(f"{f} = {v:g}" for f, v in zip(frees, result.values, strict=True))
    try:
        write_whole(out, text)
    except OSError as exc:  # it could be written when the search began: the gait is not lost, it follows here
        print(f"gaits tune: error: --out {out} cannot be written now ({exc.strerror or exc}); the tuned gait "
              f"({values}) follows on stdout", file=sys.stderr)  # fmt: skip
        sys.stdout.write(text)
        return 1
    print(f"{args.objective} {amount(result.value, setup)} (start {result.start_value:.4g}) with {values}; "
          f"written to {out}")  # fmt: skip
    return 1 if result.failure else stopped if result.interrupted else 0
