"""``gaits tune --scheduler``: the simulations run on a Dask distributed cluster — here a local one, its scheduler in
this process and two worker processes, all on 127.0.0.1 — and give the same gait as local worker processes do."""

from __future__ import annotations

import logging

import pytest

from gaits import distributed as gaits_distributed
from gaits.cli import main
from gaits.model import LIBRARY, load, loads, to_dict
from gaits.params import parse_free
from gaits.tune import Setup, tune
from tests.transports import free_port

pytestmark = [pytest.mark.xdist_group("test_tune_dask"), pytest.mark.timeout(300)]
"""The module's tests run on one worker (an xdist group), so its module-scoped fixture is made once."""
CATERPILLAR = LIBRARY / "caterpillar.toml"
ARGS = ["--free", "amplitude=20:85", "--free", "period=0.6:1.6", "--budget", "9", "--seconds", "2", "--warmup",
        "0.5", "--seed", "3"]  # fmt: skip


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", scheduler_port=0,
                           dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0",
                           silence_logs=logging.ERROR)  # fmt: skip
    try:
        yield cluster
    finally:
        cluster.close()


def test_a_search_on_a_dask_cluster_gives_the_local_result(cluster, tmp_path, capsys):
    out = tmp_path / "tuned.toml"
    assert main(["tune", str(CATERPILLAR), *ARGS, "--scheduler", cluster.scheduler_address, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"evaluating on the Dask scheduler at {cluster.scheduler_address}: 2 worker thread(s)" in err
    # the cluster's workers ran the candidates: 9 of the search and the final check's
    counts = {name: sum(prefix.state_counts.values()) for name, prefix in cluster.scheduler.task_prefixes.items()}
    assert counts.get("evaluate_job", 0) >= 9, counts
    tuned = loads(out.read_text(encoding="utf-8"))
    local = tune(load(CATERPILLAR), [parse_free("amplitude=20:85"), parse_free("period=0.6:1.6")],
                 Setup("speed", seconds=2.0, warmup=0.5), budget=9, seed=3, workers=2)  # fmt: skip
    assert local.best is not None
    assert to_dict(tuned)["automata"] == to_dict(local.best)["automata"]  # the same gait, wherever it was simulated
    assert to_dict(tuned)["modules"] == to_dict(local.best)["modules"]


def test_a_scheduler_that_does_not_answer_is_a_clear_error(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(gaits_distributed, "CONNECT_SECONDS", 1.0)
    address = f"tcp://127.0.0.1:{free_port()}"  # nothing listens there
    out = tmp_path / "tuned.toml"
    assert main(["tune", str(CATERPILLAR), *ARGS, "--scheduler", address, "--out", str(out)]) == 1
    assert f"gaits tune: error: the Dask scheduler at {address}" in capsys.readouterr().err
    assert not out.exists()


def test_a_listener_that_accepts_and_never_answers_is_a_clear_error_in_time(tmp_path, capsys, monkeypatch):
    """A second user review: a Client made to such a listener waited for ever (5 minutes and counting)."""
    import socket
    import threading
    import time

    monkeypatch.setattr(gaits_distributed, "CONNECT_SECONDS", 1.0)
    listener = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []
    stop = threading.Event()

    def accept() -> None:
        listener.settimeout(0.2)
        while not stop.is_set():
            try:
                accepted.append(listener.accept()[0])
            except TimeoutError:
                continue

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    address = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    out = tmp_path / "tuned.toml"
    try:
        began = time.monotonic()
        assert main(["tune", str(CATERPILLAR), *ARGS, "--scheduler", address, "--out", str(out)]) == 1
        assert time.monotonic() - began < 30
        assert "no answer within 1 s" in capsys.readouterr().err
        assert accepted, "it did connect"
        assert not out.exists()
    finally:
        stop.set()
        thread.join(5)
        for conn in accepted:
            conn.close()
        listener.close()


@pytest.mark.parametrize("address", ["garbage", "inproc://x", "tls://127.0.0.1:5", "tcp://127.0.0.1:99999",
                                     "tcp://:5", "tcp://127.0.0.1:86x"])  # fmt: skip
def test_an_address_that_is_no_scheduler_address_is_a_usage_error_at_once(address, tmp_path, capsys):
    """Refused before a Dask client is made (one made from a bad address blocked the exit 20 s closing itself)."""
    with pytest.raises(SystemExit) as exit_:
        main(["tune", str(CATERPILLAR), *ARGS, "--scheduler", address, "--out", str(tmp_path / "t.toml")])
    assert exit_.value.code == 2
    assert "a Dask scheduler address is tcp://HOST:PORT" in capsys.readouterr().err


def test_a_scheduler_lost_mid_search_keeps_the_best_so_far():
    """The cluster goes away after the first generation: the search ends as after Ctrl-C, with the best so far and
    why it ended, never a traceback."""
    from distributed import LocalCluster

    lost = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1", scheduler_port=0,
                        dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0",
                        silence_logs=logging.CRITICAL)  # fmt: skip
    try:
        with gaits_distributed.dask_executor(lost.scheduler_address) as (executor, width):
            result = tune(load(CATERPILLAR), [parse_free("amplitude=20:85")], Setup("speed", seconds=1.0, warmup=0.5),
                          budget=40, seed=1, workers=width, popsize=4, executor=executor,
                          progress=lambda r, line: lost.close() if r.generations == 1 else None)  # fmt: skip
    finally:
        lost.close()
    assert result.interrupted and result.failure, result
    assert result.best is not None and result.evaluations < 40


def test_a_cluster_that_loses_every_worker_mid_search_ends_it_with_the_best_so_far(monkeypatch, capsys):
    """A user review: every worker killed after the first generation, the search waited for ever, silent (Dask keeps
    a task waiting for a worker). Now it waits WORKERLESS_SECONDS for one to come back, then ends as after Ctrl-C,
    with the best so far and why."""
    import time

    from distributed import LocalCluster

    monkeypatch.setattr(gaits_distributed, "WORKERLESS_SECONDS", 2.0)
    monkeypatch.setattr(gaits_distributed, "POLL_SECONDS", 0.2)
    alone = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1", scheduler_port=0,
                         dashboard_address="127.0.0.1:0", worker_dashboard_address="127.0.0.1:0",
                         silence_logs=logging.CRITICAL)  # fmt: skip
    try:
        began = time.monotonic()
        with gaits_distributed.dask_executor(alone.scheduler_address) as (executor, width):
            result = tune(load(CATERPILLAR), [parse_free("amplitude=20:85")], Setup("speed", seconds=1.0, warmup=0.5),
                          budget=40, seed=1, workers=width, popsize=4, executor=executor,
                          progress=lambda r, line: alone.scale(0) if r.generations == 1 else None)  # fmt: skip
        assert time.monotonic() - began < 60
    finally:
        alone.close()
    assert result.interrupted and result.failure == "has had no workers for 2 s", result.failure
    assert result.best is not None and result.evaluations < 40
    assert "distributed" not in capsys.readouterr().err  # Dask's own log lines stay quiet meanwhile


class _Scheduler:
    """What WatchedExecutor asks a Dask client: its workers' threads (``sync(scheduler.ncores)``), or no answer."""

    def __init__(self, threads: int, hung: bool = False) -> None:
        self.threads, self.hung = threads, hung
        self.scheduler = self

    def ncores(self) -> None:  # only named: sync() answers for it
        raise AssertionError("called through sync")

    def sync(self, _call: object, callback_timeout: float | None = None) -> dict[str, int]:
        if self.hung:
            raise TimeoutError(f"no answer in {callback_timeout}")
        return {f"w{k}": 1 for k in range(self.threads)}


@pytest.mark.parametrize(
    ("scheduler", "job", "says"),
    [
        (_Scheduler(1, hung=True), "wait", "stopped answering (no answer within 0.1 s)"),  # a review's SIGSTOP
        (_Scheduler(0), "wait", "has had no workers for 0.3 s"),
        (_Scheduler(1), "divide", "ran a simulation that failed (ZeroDivisionError: division by zero)"),
    ],
)
def test_the_watched_executor_says_what_failed(monkeypatch, scheduler, job: str, says: str) -> None:
    """A second review: a scheduler that hung (SIGSTOP) was waited on for ever, and a simulation that raised on a
    worker was blamed on the scheduler ("stopped answering")."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    monkeypatch.setattr(gaits_distributed, "ASK_SECONDS", 0.1)
    monkeypatch.setattr(gaits_distributed, "POLL_SECONDS", 0.05)
    release = threading.Event()
    said: list[str] = []
    jobs = {"wait": lambda _: release.wait(30), "divide": lambda x: 1 / x}
    with ThreadPoolExecutor(2) as pool:
        watched = gaits_distributed.WatchedExecutor(scheduler, pool, 0.3, said.append)
        try:
            with pytest.raises(RuntimeError) as failed:
                list(watched.map(jobs[job], [0, 0]))
        finally:
            release.set()
    assert str(failed.value) == says
    assert said == (["the Dask cluster has no worker now: waiting up to 0.3 s for one"] if scheduler.threads == 0
                    else [])  # fmt: skip
