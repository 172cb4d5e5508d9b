"""The gait tuner (issue 30): how much faster it makes the library caterpillar, and how well its workers use the cores.

    .venv/bin/python bench/tune.py            # about 8 minutes on 2 idle cores
    .venv/bin/python bench/tune.py --quick    # about 4 minutes on 2 idle cores

1. ``tuned_caterpillar_speed_vs_library``: gaits.tune.tune on the library caterpillar, three generator parameters
   free (amplitude 20-85°, period 0.35-1.5 s, wavelength 3-14 modules), speed on flat ground, the default
   constraints (peak torque <= 1.425 N·m, no fall, joint limits). Then the library gait and the tuned one each run
   10 s after a 2 s warm-up (as bench/sim.py measures the library), and the ratio of their speeds is printed.
2. ``tune_evals_per_s_vs_cores``: the same short search (same seed, so the same candidates) with 1 worker, then with
   2, three rounds interleaved; the best simulations per second with 2 over the best with 1, divided by 2 (1.0: the
   second core doubles the rate). The final check's longer runs count as as many search runs as they last; the
   pool's start and the wait for a generation's slowest candidate count, as they do in a real run. Each round also
   says how busy the workers were and what share of the CPU they got: a miss caused by other processes on the
   machine shows there, not in the tuner. ``tune_evals_per_s_vs_cores_dask``: the same against a local Dask cluster
   of 1, then 2 worker processes (``gaits tune --scheduler``), each started before the clock and alone on the
   machine in its rounds; the measure before 2026-11-27, both clusters up in every round, follows as a comment.
3. ``tuned_rough_speed_vs_library_rough``: tuned as in 1 but for the mean speed over two rough fields (seeds 1, 2)
   and a 5° slope (the robust objective); then the library gait and the tuned one run 10 s after 2 s on three rough
   fields the search never saw (seeds 11-13) and the slope, and the ratio of their mean speeds is printed.
4. ``tuned_live_distance_vs_preview``: the gait tuned in 1, deployed on ``asm-robot --sim`` in its own process:
   metres in 10 s of wall time after 2 s over its preview's in 10 s simulated (bench/robot.py's measure).

The tuned gaits are written to gaits/tuned/ with their provenance (``--quick``: to a temporary folder, its smaller
budgets tune worse gaits; tests/gaits/test_tuned.py checks that they run
backwards with direction -1 and shrug off the 1 N push as the library gaits do).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import tempfile
import time
from collections.abc import Iterator
from concurrent.futures import Executor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from gaits.model import LIBRARY, Gait, load
from gaits.params import parse_free
from gaits.sim import Simulation
from gaits.terrain import FLAT, Terrain, parse
from gaits.tune import Setup, tune, tuned_text

FREES = ["amplitude=20:85", "period=0.35:1.5", "wavelength=3:14"]
TUNED = Path(__file__).resolve().parent.parent / "gaits" / "tuned"
"""Where the tuned gaits are written (with their provenance): tests/gaits/test_tuned.py checks them."""
ROUGH_TUNE = ("rough:seed=1", "rough:seed=2", "slope:5")
"""The robust objective's grounds: the mean speed over two rough fields and a 5° slope uphill."""
ROUGH_TEST = ("rough:seed=11", "rough:seed=12", "rough:seed=13", "slope:5")
"""What the robust gait is judged on: rough fields it never saw (other seeds), and the slope."""


def speed(gait: Gait, terrain: Terrain = FLAT) -> tuple[float, float]:
    """Speed (m/s) and peak torque over 10 s after 2 s of warm-up."""
    with Simulation(gait, terrain=terrain) as sim:
        metrics = sim.run(10.0, warmup=2.0)
    return metrics.speed, metrics.peak_torque


def tuned_ratio(budget: int, seconds: float, out: Path) -> Path:
    library = load(LIBRARY / "caterpillar.toml")
    frees = [parse_free(text) for text in FREES]
    setup = Setup("speed", seconds=seconds, warmup=1.0)
    wall = time.perf_counter()
    result = tune(library, frees, setup, budget=budget, seed=1, workers=2,
                  progress=lambda _, line: print(f"#   {line}", flush=True))  # fmt: skip
    wall = time.perf_counter() - wall
    assert result.best is not None
    base, base_peak = speed(library)
    best, best_peak = speed(result.best)
    values = ", ".join(f"{f.name} {v:g}" for f, v in zip(frees, result.values, strict=True))
    print(f"# tuned in {wall:.0f} s ({result.evaluations} simulations of {seconds:g} s): {values}; "
          f"scored {result.value:.3f} m/s, the best refused {result.refused_value:.3f} m/s; "
          f"{result.verify_refused} leader(s) failed the longer check")  # fmt: skip
    print(f"# 10 s runs: library {base:.3f} m/s (peak {base_peak:.2f} N·m), tuned {best:.3f} m/s "
          f"(peak {best_peak:.2f} N·m)")  # fmt: skip
    print(f"ratio tuned_caterpillar_speed_vs_library {best / base:.2f} (target >= 1.5)")
    path = out / "caterpillar_flat.toml"
    path.write_text(tuned_text(result, frees, setup, budget=budget, seed=1, source="caterpillar.toml"), "utf-8")
    return path


def rough_ratio(budget: int, seconds: float, out: Path) -> None:
    """Tuned for the mean speed over ROUGH_TUNE, then it and the library gait run 10 s (after 2 s) on each ground of
    ROUGH_TEST: the ratio of their mean speeds. A tuned gait that falls or is stuck on an unseen field counts its
    speed there as it is."""
    library = load(LIBRARY / "caterpillar.toml")
    frees = [parse_free(text) for text in FREES]
    setup = Setup("speed", tuple(parse(t) for t in ROUGH_TUNE), seconds=seconds, warmup=1.0)
    wall = time.perf_counter()
    result = tune(library, frees, setup, budget=budget, seed=1, workers=2,
                  progress=lambda _, line: print(f"#   {line}", flush=True))  # fmt: skip
    wall = time.perf_counter() - wall
    assert result.best is not None
    values = ", ".join(f"{f.name} {v:g}" for f, v in zip(frees, result.values, strict=True))
    print(f"# tuned for {', '.join(ROUGH_TUNE)} in {wall:.0f} s ({result.evaluations} candidates): {values}; "
          f"scored {result.value:.3f} m/s")  # fmt: skip
    base, best = [], []
    for spec in ROUGH_TEST:
        (b, _), (t, peak) = speed(library, parse(spec)), speed(result.best, parse(spec))
        base.append(b)
        best.append(t)
        print(f"#   {spec}: library {b:.3f} m/s, tuned {t:.3f} m/s (peak {peak:.2f} N·m)")
    ratio = sum(best) / sum(base)
    print(f"ratio tuned_rough_speed_vs_library_rough {ratio:.2f} (target >= 1.3)", flush=True)
    path = out / "caterpillar_rough.toml"
    path.write_text(tuned_text(result, frees, setup, budget=budget, seed=1, source="caterpillar.toml"), "utf-8")


def live_ratio(path: Path) -> None:
    """The tuned gait deployed on ``asm-robot --sim`` (its own process): metres in 10 s of wall time after 2 s, over
    its preview's in 10 s of simulated time (bench/robot.py's measure)."""
    from bench.robot import live_vs_preview

    load_average = os.getloadavg()[0]
    live, preview = live_vs_preview(path)
    print(f"# {path.name}: live {live:.3f} m in 10 s of wall time, preview {preview:.3f} m in 10 s simulated (load "
          f"average {load_average:.2f} before: a robot process behind the wall clock covers less)")  # fmt: skip
    ratio = live / preview if preview > 0 else 0.0
    print(f"ratio tuned_live_distance_vs_preview {ratio:.2f} (target >= 0.9)")
    print(f"ratio tuned_live_distance_vs_preview {ratio:.2f} (target <= 1.1)", flush=True)


def scaling(budget: int, seconds: float, rounds: int, *, dask: bool = False, together: bool = False) -> float:
    """Rounds of 1 worker then 2, interleaved, the best rate of each: the other loads of a shared machine come and
    go, and the load average is printed with every round so a miss shows whether the second core was free. The
    ratio printed is returned.

    With ``dask`` the workers are a local Dask cluster's (gaits/distributed.py: a scheduler in this process, worker
    processes of one thread each on 127.0.0.1), started before the clock, as an existing cluster would be; the
    local pool's start counts, as it does in a run of ``gaits tune``. Each round has only its own cluster on the
    machine (since 2026-11-27); ``together`` is the measure before that, both clusters up for every round, so the
    idle one's worker, nanny and scheduler took their share of the two cores from the cluster measured."""
    library = load(LIBRARY / "caterpillar.toml")
    frees = [parse_free(text) for text in FREES]
    setup = Setup("speed", seconds=seconds, warmup=1.0)
    rates: dict[int, float] = {1: 0.0, 2: 0.0}
    with contextlib.ExitStack() as stack:
        kept = {n: stack.enter_context(_dask_cluster(n)) for n in (1, 2)} if dask and together else {}
        for _ in range(rounds):
            for workers in (1, 2):
                with contextlib.ExitStack() as own:
                    executor = kept.get(workers)
                    if dask and not together:
                        executor = own.enter_context(_dask_cluster(workers))
                    load_average = os.getloadavg()[0]
                    wall = time.perf_counter()
                    result = tune(library, frees, setup, budget=budget, seed=2, workers=workers, popsize=8,
                                  executor=executor)  # fmt: skip
                    wall = time.perf_counter() - wall
                evaluations = result.simulated / (setup.warmup + setup.seconds)  # the final check's longer runs too
                rate = evaluations / wall
                rates[workers] = max(rates[workers], rate)
                # busy: the workers' simulating time over workers × wall (the rest: pool start, generation barriers);
                # cpu: the CPU time they got over that (the rest went to other processes on the machine)
                print(f"#   {workers} {'Dask ' if dask else ''}worker(s): {evaluations:.0f} simulations' worth in "
                      f"{wall:.1f} s = {rate:.2f}/s, workers busy {result.busy / (workers * wall):.0%}, with the CPU "
                      f"{result.cpu / result.busy:.0%} of that (load average {load_average:.2f} before)")  # fmt: skip
    ratio = rates[2] / rates[1] / 2
    if together:
        print(f"# tune_evals_per_s_vs_cores_dask measured as before 2026-11-27 (both clusters up in every round): "
              f"{ratio:.2f}", flush=True)  # fmt: skip
    else:
        name = "tune_evals_per_s_vs_cores_dask" if dask else "tune_evals_per_s_vs_cores"
        print(f"ratio {name} {ratio:.2f} (target >= 0.8)", flush=True)
    return ratio


@contextlib.contextmanager
def _dask_cluster(workers: int) -> Iterator[Executor]:
    from distributed import LocalCluster

    from gaits.distributed import dask_executor

    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           scheduler_port=0, dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0",
                           silence_logs=logging.WARNING)  # fmt: skip
    try:
        with dask_executor(cluster.scheduler_address) as (executor, width):
            assert width == workers
            yield executor
    finally:
        cluster.close()


def main() -> None:
    cli = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    cli.add_argument("--quick", action="store_true", help="smaller budgets and shorter simulations (under 2 minutes)")
    args = cli.parse_args()
    if args.quick:  # smaller budgets tune worse gaits: they go to a temporary folder, never over gaits/tuned/
        with tempfile.TemporaryDirectory(prefix="asm-tune-quick-") as out:
            flat = tuned_ratio(budget=150, seconds=3.0, out=Path(out))
            rough_ratio(budget=60, seconds=3.0, out=Path(out))
            live_ratio(flat)
        scaling(budget=33, seconds=2.0, rounds=3)
        scaling(budget=33, seconds=2.0, rounds=3, dask=True)
        scaling(budget=33, seconds=2.0, rounds=3, dask=True, together=True)
    else:
        TUNED.mkdir(exist_ok=True)
        flat = tuned_ratio(budget=400, seconds=6.0, out=TUNED)
        rough_ratio(budget=90, seconds=4.0, out=TUNED)
        live_ratio(flat)
        scaling(budget=49, seconds=4.0, rounds=3)
        scaling(budget=49, seconds=4.0, rounds=3, dask=True)
        scaling(budget=49, seconds=4.0, rounds=3, dask=True, together=True)


if __name__ == "__main__":
    main()
