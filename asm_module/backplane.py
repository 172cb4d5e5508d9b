"""The emulated boards of one process on one CAN channel share one python-can bus and one thread reading it: a
backplane (asm_module/emulated.py).

Why: with a bus each, every frame of the channel was copied into every board's queue (python-can's ``virtual``
bus deep-copies a frame for each of its endpoints; ``asm_sim`` queues it for each endpoint without filters) and
woke every board's thread, whatever the board's acceptance filters then did with it: during a firmware update of
eight boards (~35,000 frames) that was about as much of the process's time as running the boards' images
(docs/benchmarks.md, 2026-11-27). A CAN controller's filters keep what its core does not want from ever reaching
it; here each frame reaches each board's bxCAN model once (asm_module/bxcan.py: the filters its image set, asked
in the reading thread) and only a board that took it is woken.

Each board is still its own node with its own controller: only the python-can bus object and its reader are
shared. A board's frames go on the bus once, and to the other boards of the backplane at once — a bus carries a
frame to every controller but the sender's. A bus given by the caller gets a backplane of its own (one board), and
is not shut down with it.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, ClassVar

import can

Receiver = Callable[[int, bool, bytes], None]
"""What a board does with a frame seen on the bus: (identifier, extended, data)."""


class Backplane:
    """One python-can bus and the boards on it (their receivers); see the module docstring."""

    _lock = threading.Lock()
    _shared: ClassVar[dict[str, Backplane]] = {}

    def __init__(self, key: str | None, bus: can.BusABC, own: bool) -> None:
        self.key, self.bus, self._own = key, bus, own
        self._receivers: list[Receiver] = []  # replaced, never changed in place: the reader iterates it unlocked
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name=f"asm-backplane:{bus.channel_info}", daemon=True)

    @classmethod
    def join(cls, receiver: Receiver, bus: can.BusABC | None = None, **bus_options: Any) -> Backplane:
        """``receiver`` on ``bus`` (a backplane of its own), or on the backplane of this process that has
        ``bus_options``' bus (opened now if none has)."""
        if bus is not None:
            plane = cls(None, bus, own=False)
            plane._receivers = [receiver]
            plane._thread.start()
            return plane
        key = repr(sorted(bus_options.items()))
        with cls._lock:
            plane = cls._shared.get(key)
            if plane is None:
                plane = cls._shared[key] = cls(key, can.Bus(**bus_options), own=True)
                plane._thread.start()
            plane._receivers = [*plane._receivers, receiver]
        return plane

    def leave(self, receiver: Receiver) -> None:
        """``receiver`` is off the bus; the last one out stops the reader (and shuts the bus down if it opened it)."""
        with Backplane._lock:
            self._receivers = [r for r in self._receivers if r is not receiver]
            last = not self._receivers
            if last and self.key is not None and Backplane._shared.get(self.key) is self:
                del Backplane._shared[self.key]
        if last:
            self._stop.set()
            self._thread.join(5)
            if self._own:
                self.bus.shutdown()

    def send(self, sender: Receiver, can_id: int, extended: bool, data: bytes) -> None:
        """A frame from ``sender``'s board: on the bus (CanError if it cannot go), and to every other board here."""
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=extended), timeout=0.1)
        for receiver in self._receivers:
            if receiver is not sender:
                receiver(can_id, extended, data)

    def _read(self) -> None:
        while not self._stop.is_set():
            frame = self.bus.recv(timeout=0.1)
            if frame is None or frame.is_error_frame or frame.is_remote_frame:
                continue
            can_id, extended, data = frame.arbitration_id, frame.is_extended_id, bytes(frame.data)
            for receiver in self._receivers:
                receiver(can_id, extended, data)
