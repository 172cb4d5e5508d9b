"""Give the heap a burst of traffic left behind back to the operating system.

Everything the bridge holds per request is bounded and released (docs/security.md), yet after a flood of 2,000
refused requests a second its process stayed about 40 % larger: glibc keeps freed chunks for reuse, and the
long-lived objects scattered between them keep its arenas from shrinking by themselves. On a robot computer that
memory belongs to the other processes. ``malloc_trim(0)`` returns the free pages of every arena in about 2 ms, so
the bridge calls it once each time a burst of traffic has died down — never during the burst (trimming then
would only be undone), and never where the C library has no such call (musl, macOS: there it does nothing).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import time
from collections.abc import Callable

BURST_RATE = 200.0
"""Requests per second that count as a burst worth trimming after."""

QUIET_FRACTION = 0.1
"""The burst is over when the rate falls below this fraction of its peak."""


def _malloc_trim() -> Callable[[], None] | None:
    """glibc's ``malloc_trim(0)``, or None where the C library has none."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return lambda: trim(0)


MALLOC_TRIM = _malloc_trim()


class HeapTrimmer:
    """Watches a traffic counter; trims the heap once after each burst. Call ``tick`` often (no thread of its own)."""

    def __init__(
        self,
        traffic: Callable[[], int],
        *,
        window: float = 1.0,
        burst_rate: float = BURST_RATE,
        trim: Callable[[], None] | None = MALLOC_TRIM,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._traffic = traffic
        self._window = window
        self._burst_rate = burst_rate
        self._trim = trim
        self._clock = clock
        self._since = clock()
        self._count = traffic()
        self._peak = 0.0
        self.trims = 0
        """How many times the heap was trimmed (for the bridge's status and tests)."""

    def tick(self) -> bool:
        """Measure the last window's rate; trim if a burst just ended. True when it trimmed."""
        now = self._clock()
        if now - self._since < self._window:
            return False
        count = self._traffic()
        rate = (count - self._count) / (now - self._since)
        self._since, self._count = now, count
        self._peak = max(self._peak, rate)
        if self._peak < self._burst_rate or rate >= self._peak * QUIET_FRACTION:
            return False
        self._peak = 0.0
        if self._trim is None:
            return False
        self._trim()
        self.trims += 1
        return True
