"""Small helpers shared by the tests."""

from __future__ import annotations

import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
"""The repository."""
VECTORS = ROOT / "tests" / "vectors"
"""The golden vectors every implementation checks (Python, C)."""
ARTIFACTS = ROOT / "tests" / "artifacts"
"""Screenshots and logs a test leaves for a person to look at."""


def run_in_thread(target, *args) -> tuple[threading.Thread, dict]:
    """Run ``target(*args)`` in a daemon thread; the dict gets 'result' or 'error'."""
    box: dict = {}

    def main() -> None:
        try:
            box["result"] = target(*args)
        except BaseException as exc:
            box["error"] = exc

    thread = threading.Thread(target=main, daemon=True)
    thread.start()
    return thread, box


def wait_until(predicate, timeout: float = 5.0, interval: float = 0.002) -> bool:
    """Poll ``predicate`` in real time until it holds or ``timeout`` passes (a generous deadline, not a sleep)."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(interval)
    return True


def until_answered(session, key: str, *, payload: bytes | None = None, timeout: float = 10.0) -> bool:
    """Ask ``key`` from the Zenoh ``session`` until one good reply comes, before a test counts replies: a fresh
    session's first query can go nowhere, as Zenoh ends a get at once with no reply while its routing table does
    not know the queryable yet (eclipse-zenoh/zenoh#2516, #2767, open; 1 loaded run in ~30 here)."""
    return wait_until(
        lambda: any(reply.ok is not None for reply in session.get(key, payload=payload, timeout=2.0)), timeout
    )


def mutations(valid: list[bytes], max_index: int = 63, max_flips: int = 4):
    """A hypothesis strategy: one of the ``valid`` messages with a few bytes replaced and its tail cut."""
    from hypothesis import strategies as st

    def mutate(base: bytes, flips: list[tuple[int, int]], cut: int) -> bytes:
        raw = bytearray(base)
        for index, value in flips:
            raw[index % len(raw)] = value
        return bytes(raw[: max(0, len(raw) - cut)])

    flips = st.lists(st.tuples(st.integers(0, max_index), st.integers(0, 255)), max_size=max_flips)
    return st.builds(mutate, st.sampled_from(valid), flips, st.integers(0, 3))


class FakeTime:
    """A wall clock the test moves."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now
