"""A python-can bus wrapper for the bad days: it drops, duplicates, reorders and corrupts frames at given rates.

Wrap any bus — usually python-can's ``virtual`` one — and hand the wrapper to a transport::

    bus = FaultyBus(can.Bus(interface="virtual", channel="x"), drop=0.05, duplicate=0.02, reorder=0.02, seed=1)
    transport = CanTransport(3, bus=bus)

Faults apply to what the wrapped node sends and to what it receives. Corruption flips one bit of the data (or of
the identifier, with ``corrupt_id=True``) — what a real bus's CRC would have caught: it models a controller or
firmware bug, or a gateway that lost integrity. ``unplugged = True`` makes the node deaf and mute until set back.
"""

from __future__ import annotations

import copy
import random
import threading
from collections import deque
from typing import Any

import can


class FaultyBus(can.BusABC):
    """A fault-injecting wrapper around another python-can bus; see the module docstring."""

    def __init__(
        self,
        bus: can.BusABC,
        *,
        drop: float = 0.0,
        duplicate: float = 0.0,
        reorder: float = 0.0,
        corrupt: float = 0.0,
        corrupt_id: bool = False,
        seed: int | None = None,
        **kwargs: Any,
    ) -> None:
        self.inner = bus
        self.drop = drop
        self.duplicate = duplicate
        self.reorder = reorder
        self.corrupt = corrupt
        self.corrupt_id = corrupt_id
        self.unplugged = False
        self.counts = {"dropped": 0, "duplicated": 0, "reordered": 0, "corrupted": 0}
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._pending: deque[can.Message] = deque()
        self._held_tx: can.Message | None = None
        self._held_rx: can.Message | None = None
        self.channel_info = f"faulty {getattr(bus, 'channel_info', bus)}"
        super().__init__(channel=getattr(bus, "channel_info", ""), **kwargs)

    def _roll(self, rate: float) -> bool:
        with self._lock:
            return rate > 0 and self._rng.random() < rate

    def _damage(self, frame: can.Message) -> can.Message:
        damaged = copy.copy(frame)
        with self._lock:
            if self.corrupt_id or not frame.data:
                damaged.arbitration_id ^= 1 << self._rng.randrange(29)
            else:
                data = bytearray(frame.data)
                data[self._rng.randrange(len(data))] ^= 1 << self._rng.randrange(8)
                damaged.data = data
        self.counts["corrupted"] += 1
        return damaged

    def _faults(self, frame: can.Message, held_attr: str) -> list[can.Message]:
        """The frames that actually pass, in order, for one frame offered in one direction."""
        if self.unplugged or self._roll(self.drop):
            if not self.unplugged:
                self.counts["dropped"] += 1
            return []
        if self._roll(self.corrupt):
            frame = self._damage(frame)
        out = [frame]
        if self._roll(self.duplicate):
            self.counts["duplicated"] += 1
            out.append(copy.copy(frame))
        held = getattr(self, held_attr)
        if held is not None:
            setattr(self, held_attr, None)
            out.append(held)  # the held frame overtaken by this one
        elif self._roll(self.reorder):
            self.counts["reordered"] += 1
            setattr(self, held_attr, out.pop(0))
        return out

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        for frame in self._faults(msg, "_held_tx"):
            self.inner.send(frame, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self._pending:
            return self._pending.popleft(), False
        frame = self.inner.recv(timeout)
        if frame is None:
            return None, False
        passed = self._faults(frame, "_held_rx")
        if not passed:
            return None, False
        self._pending.extend(passed[1:])
        return passed[0], False

    def shutdown(self) -> None:
        super().shutdown()
        self.inner.shutdown()
