"""The tuner's evaluations on an existing Dask distributed cluster: ``gaits tune --scheduler tcp://HOST:PORT``.

Where one machine's cores are not enough, the candidates of each generation go to a Dask scheduler, which spreads
them over its workers (each must be able to import this project: the same checkout and environment). The search
itself stays here: CMA-ES asks, the cluster simulates, the results come back in the order asked, so a run on a
cluster gives the same gait as a run on local worker processes with the same seed. The client is
``distributed.Client(ADDRESS).get_executor()``: a concurrent.futures Executor, which is all gaits.tune.tune needs.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import time
from collections.abc import Callable, Iterator
from concurrent.futures import CancelledError, Executor, Future, wait
from typing import Any, cast

CONNECT_SECONDS = 10.0
"""How long to wait for the scheduler to answer before giving up."""
WORKERLESS_SECONDS = 30.0
"""How long a search waits on a cluster that has no worker left (they may come back, or an adaptive cluster may
start some) before it ends with the best so far."""
POLL_SECONDS = 1.0
"""How often a waiting search asks the scheduler how many workers it has."""
ASK_SECONDS = 10.0
"""How long that question may take: a scheduler that does not answer it (hung, or cut off) has stopped answering."""


def scheduler_address(text: str) -> str:
    """``--scheduler``: ``tcp://HOST:PORT``, checked before a client is made — a Dask client made from an address it
    cannot use fails, then blocks the process's exit for 20 s closing itself (and prints a traceback doing it)."""
    scheme, sep, rest = text.partition("://")
    host, colon, port = rest.rpartition(":")
    if scheme != "tcp" or not sep or not colon or not host.strip("[]") or not port.isdigit() \
            or not 1 <= int(port) <= 65535:  # fmt: skip
        raise argparse.ArgumentTypeError(f"a Dask scheduler address is tcp://HOST:PORT (port 1-65535), not {text!r}")
    return text


def _probe(address: str, seconds: float) -> None:
    """Ask the scheduler who it is, within ``seconds`` in all; OSError if it does not say. A Client made to a
    listener that accepts and never answers waited for ever (its registration's reply has no timeout)."""
    import asyncio

    from distributed.comm.core import connect

    async def ask() -> None:
        comm = await connect(address, timeout=seconds)
        try:
            await comm.write({"op": "identity", "reply": True})
            await comm.read()
        finally:
            comm.abort()

    try:
        asyncio.run(asyncio.wait_for(ask(), seconds))
    except TimeoutError:  # (asyncio.TimeoutError is it since 3.11; an OSError too, so caught first)
        raise OSError(f"no answer within {seconds:g} s (is a Dask scheduler listening there?)") from None
    except OSError:
        raise
    except Exception as exc:  # what answered is not a Dask scheduler
        raise OSError(f"not a Dask scheduler ({type(exc).__name__}: {exc})") from None


@contextlib.contextmanager
def dask_executor(address: str, say: Callable[[str], None] | None = None) -> Iterator[tuple[Executor, int]]:
    """An Executor on the Dask scheduler at ``address`` and how many candidates its workers run at once (their
    threads in all); the client is closed at the end. OSError when the scheduler does not answer, RuntimeError
    when it has no workers. ``say`` is told when a search waits for a worker (a cluster that has none left)."""
    try:
        from distributed import Client
    except ImportError as exc:  # pragma: no cover - a dependency of the package
        raise RuntimeError("--scheduler needs the dask[distributed] package") from exc
    _probe(address, CONNECT_SECONDS)  # read now: tests shorten it
    with _quiet_dask():
        client = Client(address, timeout=CONNECT_SECONDS, set_as_default=False)
        try:
            width = _threads(client, CONNECT_SECONDS)
            if width == 0:
                raise RuntimeError("it has no workers")
            yield WatchedExecutor(client, client.get_executor(pure=False), WORKERLESS_SECONDS, say), width
        finally:
            client.close()


def _threads(client: Any, timeout: float | None = None) -> int:
    """Worker threads the scheduler has; TimeoutError when it does not say within ``timeout`` (a client's own call
    waits for ever on a scheduler that hangs: a review stopped one with SIGSTOP)."""
    ncores = client.sync(client.scheduler.ncores, callback_timeout=timeout)
    return sum(cast(dict[str, int], ncores).values())


class _Failed(RuntimeError):
    """The cluster failed the search; the message completes "the Dask scheduler at ADDRESS …"."""


class WatchedExecutor(Executor):
    """The Dask client's executor, whose ``map`` gives up on a cluster that has had no worker for ``workerless``
    seconds: Dask keeps such tasks waiting for a worker for ever, and a search whose workers were all killed sat
    silent (a user review). It raises RuntimeError then, which tune() takes as the executor failing: the best so
    far is kept and the reason said."""

    def __init__(self, client: Any, inner: Executor, workerless: float,
                 say: Callable[[str], None] | None = None) -> None:  # fmt: skip
        self._client, self._inner, self._workerless, self._say = client, inner, workerless, say

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        return self._inner.submit(fn, *args, **kwargs)

    def map(self, fn: Callable[..., Any], *iterables: Any, timeout: float | None = None,
            chunksize: int = 1) -> Iterator[Any]:  # fmt: skip
        try:
            futures = [self._inner.submit(fn, *args) for args in zip(*iterables, strict=True)]
            alone_since: float | None = None
            while True:
                _, pending = wait(futures, timeout=POLL_SECONDS)
                if not pending:
                    break
                try:
                    threads = _threads(self._client, ASK_SECONDS)
                except TimeoutError:
                    raise _Failed(f"stopped answering (no answer within {ASK_SECONDS:g} s)") from None
                if threads > 0:
                    alone_since = None
                    continue
                if alone_since is None:
                    alone_since = time.monotonic()
                    if self._say is not None:
                        self._say(f"the Dask cluster has no worker now: waiting up to {self._workerless:g} s for one")
                if time.monotonic() - alone_since >= self._workerless:
                    for future in pending:
                        future.cancel()
                    raise _Failed(f"has had no workers for {self._workerless:g} s")
            return iter([future.result() for future in futures])
        except _Failed:
            raise
        except Exception as exc:  # the scheduler lost (a cancelled future, a closed client) or a task that failed
            said = str(exc).strip().splitlines()
            what = f"{type(exc).__name__}{': ' + said[0] if said else ''}"
            if isinstance(exc, (CancelledError, TimeoutError, OSError)) or type(exc).__module__.startswith(
                    "distributed"):  # fmt: skip
                raise _Failed(f"stopped answering ({what})") from exc
            raise _Failed(f"ran a simulation that failed ({what})") from exc  # the cluster is not to blame

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._inner.shutdown(wait=wait, cancel_futures=cancel_futures)


@contextlib.contextmanager
def _quiet_dask() -> Iterator[None]:
    """Dask's own loggers silenced while the search uses the cluster: a scheduler lost mid-run printed Dask's error
    lines and tracebacks before the command's one line saying so (which keeps the best so far)."""
    names = {name for name in list(logging.root.manager.loggerDict) if name.startswith("distributed.")}
    loggers = [logging.getLogger(name) for name in sorted(names | {"distributed"})]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)
