"""A tool's calls to a robot's modules: client objects looked up once, every call bounded by a timeout that adapts
to the round trips measured, and repeated on a timeout — so a lost frame costs one short retry, never a hang.

A fixed timeout is either long (a frame lost at 1 % loss then costs seconds: deploys took a median of 15 s) or
short (a busy bus then retries needlessly). As TCP does (RFC 6298), each :class:`ModuleCalls` keeps a smoothed
round trip and its variation and waits ``srtt + 4·rttvar`` — at least MIN_TIMEOUT, at most the caller's — plus the
time the request's bytes take on a CAN bus.
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Callable, Sequence
from typing import Any

from asm_py import Node
from asm_py.canbus.fragments import frame_count
from asm_py.errors import AsmError, AsmTimeout, RemoteError
from asm_py.protocol import HEADER_SIZE, Status
from asm_py.remote import RemoteObject

MIN_TIMEOUT = 0.05
"""Seconds a call waits at least (a round trip through a bridge on a quiet bus takes about 2 ms)."""
FIRST_TIMEOUT = 0.5
"""Seconds before any round trip was measured."""
BUSY_PAUSE = 0.05
"""Seconds before a call answered BUSY is tried again, doubled at each BUSY (1.55 s over six attempts): a bridge
answers BUSY while a client has 32 requests in flight, and a request whose reply was lost stays in flight there until
its own deadline — at 1 % loss a deploy's retries could meet that limit and fail (bench/faults.py, once in two)."""
FRAMES_PER_EXTRA_ATTEMPT = 8
"""A request of k CAN frames gets (k - 1) // 8 attempts more than a one-frame call: each of its frames can be lost,
and it is only answered when all arrive. At 1 % loss at each end (the fault suite) a gait table of 22 frames arrives
whole 64 % of the time, so 5 attempts left 0.6 % of modules unstaged (tests/server/test_safety.py's lossy deploys
failed 3-5 % of deploys, each module's five requests all missing a frame, frame traces in docs/benchmarks.md); two
more bring that to 0.08 %. At most MAX_EXTRA_ATTEMPTS more, so a call to a module that never answers stays bounded
whatever its size (a 4 kB request would otherwise be tried 68 times)."""
MAX_EXTRA_ATTEMPTS = 2
BYTES_PER_SECOND = 16_000.0
"""Allowance for a request's size: half of what a 1 Mbit/s bus carries at the bridge's frame rate."""


class DeployError(AsmError):
    """A module could not be given its part of the gait (which module, and at which step, are in the message)."""


_LOOKUPS: weakref.WeakKeyDictionary[Node, dict[tuple[str, str], RemoteObject]] = weakref.WeakKeyDictionary()
"""Client objects a node looked up, kept across calls: a lookup is a round trip, and a module that restarted with
other objects answers NOT_FOUND, after which the object is looked up again."""


class RoundTrips:
    """Smoothed round-trip time and variation (RFC 6298); the timeout they imply, doubled after each timeout until
    a reply is measured again (RFC 6298 §5.5: a busy robot gets longer waits, not the same short one again)."""

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self.srtt: float | None = None
        self.rttvar = 0.0
        self.backoff = 1.0

    def timeout(self, size: int = 0) -> float:
        base = FIRST_TIMEOUT if self.srtt is None else self.srtt + 4 * self.rttvar
        return min(self.limit, max(MIN_TIMEOUT, base) * self.backoff + size / BYTES_PER_SECOND)

    def timed_out(self) -> None:
        self.backoff = min(self.backoff * 2, self.limit / MIN_TIMEOUT)

    def measured(self, seconds: float) -> None:
        self.backoff = 1.0
        if self.srtt is None:
            self.srtt, self.rttvar = seconds, seconds / 2
        else:
            self.rttvar = 0.75 * self.rttvar + 0.25 * abs(self.srtt - seconds)
            self.srtt = 0.875 * self.srtt + 0.125 * seconds


class ModuleCalls:
    """Calls to the modules ``names`` (module ID → node address) of one robot; see the module docstring.

    ``timeout`` bounds each attempt, ``attempts`` how often a timed-out call is tried."""

    def __init__(self, node: Node, names: dict[int, str], timeout: float = 2.0, attempts: int = 6) -> None:
        self.node = node
        self.names = names
        self.attempts = attempts
        self.trips = RoundTrips(timeout)
        self._objects = _LOOKUPS.setdefault(node, {})

    def call(self, module: int, step: str, operation: Callable[[float], Any], size: int = 0) -> Any:
        """``operation(timeout)`` (repeatable), retried on timeouts and BUSY answers; DeployError naming the module
        and step otherwise. ``size``: the request's data bytes (a longer wait, and more attempts on timeouts)."""
        extra = (frame_count(size + HEADER_SIZE) - 1) // FRAMES_PER_EXTRA_ATTEMPT
        tries = self.attempts + min(MAX_EXTRA_ATTEMPTS, extra)
        busy = 0  # BUSY answers so far: they count towards the call's tries, and only they double the pause
        for attempt in range(tries):
            wait = self.trips.timeout(size)
            began = time.monotonic()
            try:
                result = operation(wait)
            except AsmTimeout as exc:
                self.trips.timed_out()  # back off, as TCP does
                if attempt + 1 == tries:
                    raise DeployError(f"module {module} ({self.names[module]}), {step}: {exc}") from exc
                continue
            except RemoteError as exc:  # BUSY: nothing was done, so the call may be made again
                busy += 1
                if exc.status != Status.BUSY or attempt + 1 == tries or busy == self.attempts:
                    raise DeployError(f"module {module} ({self.names[module]}), {step}: {exc}") from exc
                time.sleep(BUSY_PAUSE * 2 ** (busy - 1))
                continue
            except (AsmError, ValueError, LookupError, TypeError, PermissionError) as exc:
                raise DeployError(f"module {module} ({self.names[module]}), {step}: {exc}") from exc
            self.trips.measured(time.monotonic() - began)
            return result
        raise AssertionError("unreachable")

    def obj(self, module: int, name: str, step: str) -> Any:
        """The client object of module ``module``'s object ``name`` (looked up once)."""
        key = (self.names[module], name)
        if key not in self._objects:
            address = self.names[module]
            self._objects[key] = self.call(module, step, lambda t: self.node.lookup(address, name, timeout=t))
        return self._objects[key]

    def on(self, module: int, name: str, step: str, operation: Callable[[Any, float], Any], size: int = 0) -> Any:
        """``operation(obj, timeout)`` on the module's object ``name``; looked up again once if the module no
        longer has it (it restarted)."""
        try:
            return self.call(module, step, lambda t: operation(self.obj(module, name, step), t), size)
        except DeployError as exc:
            if not isinstance(exc.__cause__, LookupError):
                raise
            self._objects.pop((self.names[module], name), None)
            return self.call(module, step, lambda t: operation(self.obj(module, name, step), t), size)

    def peek(self, module: int, name: str, step: str) -> Any:
        return self.on(module, name, step, lambda obj, t: obj.peek(timeout=t))

    def get(self, module: int, name: str, step: str) -> Any:
        return self.on(module, name, step, lambda obj, t: obj.get(timeout=t))

    def set(self, module: int, name: str, value: Any, step: str) -> None:
        size = len(value) if isinstance(value, bytes | bytearray) else 0
        self.on(module, name, step, lambda obj, t: obj.set(value, timeout=t), size)

    def running(self, module: int, step: str) -> bool:
        return bool(self.on(module, "gait.service", step, lambda obj, t: obj.status(timeout=t)[1]))

    def latched(self, modules: Sequence[int], step: str) -> list[int]:
        """The modules among ``modules`` whose e-stop is latched (read now)."""
        return [m for m in modules if self.peek(m, "estop", step)]

    def check_not_latched(self, modules: Sequence[int], step: str) -> None:
        latched = self.latched(modules, step)
        if latched:
            listed = ", ".join(f"module {m} ({self.names[m]})" for m in latched)
            raise DeployError(f"{step}: the emergency stop is latched on {listed}; release it first")
