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
from collections.abc import Iterator
from concurrent.futures import Executor
from typing import cast

CONNECT_SECONDS = 10.0
"""How long to wait for the scheduler to answer before giving up."""


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
def dask_executor(address: str) -> Iterator[tuple[Executor, int]]:
    """An Executor on the Dask scheduler at ``address`` and how many candidates its workers run at once (their
    threads in all); the client is closed at the end. OSError when the scheduler does not answer, RuntimeError
    when it has no workers."""
    try:
        from distributed import Client
    except ImportError as exc:  # pragma: no cover - a dependency of the package
        raise RuntimeError("--scheduler needs the dask[distributed] package") from exc
    _probe(address, CONNECT_SECONDS)  # read now: tests shorten it
    client = Client(address, timeout=CONNECT_SECONDS, set_as_default=False)
    try:
        width = sum(cast(dict[str, int], client.nthreads()).values())  # a dict from a synchronous client
        if width == 0:
            raise RuntimeError(f"the Dask scheduler at {address} has no workers")
        yield client.get_executor(pure=False), width
    finally:
        client.close()
