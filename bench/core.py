"""Core benchmark: attribute operations against the bare Python primitives they are built from.

Prints, as ratios measured in the same run (higher is better):
- set+get on an uncontended plain attribute vs. a variable guarded by a bare ``threading.Lock``;
- producer→consumer hand-off through a sync_get+sync_set attribute vs. ``queue.Queue(maxsize=1)``.

Each figure is the best of several interleaved rounds, so background noise hits both sides alike.
Run: .venv/bin/python bench/core.py
"""

from __future__ import annotations

import platform
import queue
import threading
import time

from asm_py import Attribute

ROUNDS = 5
UNCONTENDED_OPS = 200_000
HANDOFF_ITEMS = 20_000


def uncontended_lock() -> float:
    lock = threading.Lock()
    shared = 0
    start = time.perf_counter()
    for i in range(UNCONTENDED_OPS):
        with lock:
            shared = i
        with lock:
            _ = shared
    return UNCONTENDED_OPS / (time.perf_counter() - start)


def uncontended_attribute() -> float:
    attr = Attribute("bench")
    set_, get = attr.set, attr.get
    start = time.perf_counter()
    for i in range(UNCONTENDED_OPS):
        set_(i)
        get()
    return UNCONTENDED_OPS / (time.perf_counter() - start)


def handoff(put, take) -> float:
    def consume() -> None:
        for _ in range(HANDOFF_ITEMS):
            take()

    consumer = threading.Thread(target=consume)
    start = time.perf_counter()
    consumer.start()
    for i in range(HANDOFF_ITEMS):
        put(i)
    consumer.join()
    return HANDOFF_ITEMS / (time.perf_counter() - start)


def handoff_queue() -> float:
    q: queue.Queue[int] = queue.Queue(maxsize=1)
    return handoff(q.put, q.get)


def handoff_attribute() -> float:
    attr = Attribute("bench", sync_get=True, sync_set=True)
    return handoff(attr.set, attr.get)


def best(fn, rounds: int = ROUNDS) -> float:
    return max(fn() for _ in range(rounds))


def main() -> None:
    print(f"# bench/core.py on {platform.python_implementation()} {platform.python_version()}, {platform.machine()}")
    lock_rate = attr_rate = queue_rate = handoff_rate = 0.0
    for _ in range(ROUNDS):  # interleave, keep the best of each
        lock_rate = max(lock_rate, uncontended_lock())
        attr_rate = max(attr_rate, uncontended_attribute())
        queue_rate = max(queue_rate, handoff_queue())
        handoff_rate = max(handoff_rate, handoff_attribute())
    print(f"uncontended set+get: attribute {attr_rate:,.0f}/s, bare lock {lock_rate:,.0f}/s")
    print(f"hand-off: attribute {handoff_rate:,.0f}/s, queue.Queue(maxsize=1) {queue_rate:,.0f}/s")
    print(f"ratio core_set_get_vs_lock {attr_rate / lock_rate:.2f} (target >= 0.5)")
    print(f"ratio core_handoff_vs_queue {handoff_rate / queue_rate:.2f} (target >= 0.8)")


if __name__ == "__main__":
    main()
