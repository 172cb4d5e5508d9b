"""An in-process CAN bus that filters like a CAN controller: python-can interface ``asm_sim``.

python-can's ``virtual`` bus copies every frame into every endpoint's queue and filters in software when the
frame is read, so on a simulated robot every node's receive thread handles every frame of the bus — delivering a
frame costs as much as there are nodes, and a long transfer to one node backs up every other node's queue. A CAN
controller filters in hardware: frames its acceptance filters reject never reach its FIFO. This bus does the same:
``send`` puts a frame only into the queues of the buses whose filters accept it, so a frame costs the same whatever
the module count: the channel indexes its buses' filters by mask (a controller's filters are a few masks, the same on
every module), so finding the receivers of a frame is one dictionary lookup per distinct mask, not one filter test
per bus.

It also models a controller's second receive FIFO: frames of priority 0 (the three top identifier bits clear — the
ASM e-stop) go to an urgent FIFO that ``recv`` empties first, so a stop never waits behind bulk frames that arrived
before it.

    bus = can.Bus(interface="asm_sim", channel="robot")   # registered as a python-can interface plugin

Frames are delivered in the order they were sent (one lock per channel), never to the sending bus itself unless
``receive_own_messages``.

A process hosting many nodes on one channel (a simulated robot's 128 modules) need not read each bus with a thread
of its own: ``bus.push_to(callback)`` has the channel's one dispatch thread (``asm-can-dispatch``) call
``callback(frame)`` for each frame the bus accepts, in the order sent, urgent frames first — python-can's
``Notifier`` with one thread for every bus of the channel instead of one per bus. Callbacks must not block: every
pushed bus of the channel waits behind them.

A thread that sends bursts (a simulated robot's control tick: every module's publications at once) may hold its
frames back for the burst: ``with SimBus.holding(channel): ...`` — they go out together at its end, in order, so
the receivers wake once for the burst (see ``holding``).

A loop that drives every node of a channel (a simulation stepping its modules) can wait until nothing is in flight
with ``SimBus.flush(channel)`` (see there) instead of sleeping for the frames to arrive: the deployment then commands
what the preview does, tick for tick, however loaded the machine is.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, ClassVar

import can

from .._contract import CAN_PRIORITY_MASK, CAN_PRIORITY_SHIFT

log = logging.getLogger("asm_py.canbus.simbus")
_RECEIVED = logging.getLogger("can.bus")
"""python-can's logger of received frames (``BusABC.recv`` logs each at level 9; ``SimBus.recv`` too)."""

URGENT_MASK = CAN_PRIORITY_MASK << CAN_PRIORITY_SHIFT
"""Extended identifiers with these bits clear (priority 0) go to the urgent FIFO."""


_KNOWN_IDS = 4096
"""Identifiers whose receivers a channel remembers (bounded: a bus may send any of 2**29)."""


class _Receivers:
    """Who receives what on one channel: the buses without filters, and per (mask, extended) the buses by masked ID."""

    def __init__(self, buses: list[SimBus]) -> None:
        self.everything = [bus for bus in buses if bus._accept is None]
        self.by_mask: dict[tuple[int, bool | None], dict[int, list[SimBus]]] = {}
        for bus in buses:
            for can_id, mask, extended in bus._accept or ():
                self.by_mask.setdefault((mask, extended), {}).setdefault(can_id & mask, []).append(bus)

        self._known: dict[tuple[int, bool], list[SimBus]] = {}

    def of(self, arbitration_id: int, extended: bool) -> list[SimBus]:
        """The buses that accept a frame; remembered per identifier (a bus's traffic is a few identifiers sent again
        and again; the index is rebuilt, and this forgotten, whenever a bus joins, leaves or changes filters)."""
        key = (arbitration_id, extended)
        known = self._known.get(key)
        if known is not None:
            return known
        found = list(self.everything)
        for (mask, only), table in self.by_mask.items():
            if only is None or only == extended:
                found.extend(table.get(arbitration_id & mask, ()))
        found = list(dict.fromkeys(found)) if len(found) > 1 else found
        if len(self._known) >= _KNOWN_IDS:
            self._known.clear()
        self._known[key] = found
        return found


FrameCallback = Callable[[can.Message], None]


_Item = tuple["SimBus", can.Message, "FrameCallback | None"]
"""A frame for the dispatch thread: the bus it is for, the frame, and the callback the bus had when it was sent (a
bus unhooked and hooked again meanwhile does not get it: the old dispatch thread, still draining, would hand it to
the new callback beside the new thread)."""


class _Mark:
    """Where ``SimBus.flush`` waits in a dispatcher's queue; the count of frames handed on when it was reached."""

    def __init__(self) -> None:
        self.reached = threading.Event()
        self.handed = 0


class _Dispatcher:
    """The thread that hands a channel's frames to its pushed buses (see the module docstring); it runs while the
    channel has pushed buses and ends with the last."""

    def __init__(self, channel: str) -> None:
        self._urgent: queue.SimpleQueue[_Item | None] = queue.SimpleQueue()
        self._normal: queue.SimpleQueue[_Item | _Mark | None] = queue.SimpleQueue()
        self._ready: queue.SimpleQueue[None] = queue.SimpleQueue()  # one token per frame: see SimBus._ready
        self._handed = 0  # frames handed to a pushed bus's callback so far
        self._thread = threading.Thread(target=self._run, name=f"asm-can-dispatch:{channel}", daemon=True)
        self._thread.start()

    def put(self, bus: SimBus, message: can.Message, urgent: bool) -> None:
        (self._urgent if urgent else self._normal).put((bus, message, bus._push))
        self._ready.put(None)

    def close(self) -> None:
        """End the thread after the frames queued so far (called under the channel lock: never joins)."""
        self._normal.put(None)
        self._ready.put(None)

    def mark(self) -> _Mark:
        """A mark reached once every frame queued before it has been handed on (urgent ones go first anyway)."""
        mark = _Mark()
        self._normal.put(mark)
        self._ready.put(None)
        return mark

    def _run(self) -> None:
        while True:
            self._ready.get()
            try:
                item = self._urgent.get_nowait()
            except queue.Empty:
                item = self._normal.get_nowait()
            if item is None:
                return
            if isinstance(item, _Mark):
                item.handed = self._handed
                item.reached.set()
                continue
            bus, message, callback = item
            if callback is None or callback is not bus._push or not bus._open:  # unhooked since, or hooked again
                continue
            try:
                callback(message)
            except Exception:
                log.exception("a pushed frame's handler failed: %s", message)
            self._handed += 1


class SimBus(can.BusABC):
    """One controller on an in-process channel; see the module docstring."""

    _channels: ClassVar[dict[str, list[SimBus]]] = {}
    _receivers: ClassVar[dict[str, _Receivers]] = {}
    _lock: ClassVar[threading.Lock] = threading.Lock()
    _dispatchers: ClassVar[dict[str, _Dispatcher]] = {}
    _held: ClassVar[dict[str, tuple[int, list[tuple[SimBus, can.Message]]]]] = {}
    """Per channel held (``holding``): the holding thread, and the frames it sent meanwhile with their senders."""

    def __init__(self, channel: Any = "asm_sim", receive_own_messages: bool = False, **kwargs: Any) -> None:
        self.channel_info = f"asm_sim channel {channel}"
        self._channel = str(channel)
        self._own = receive_own_messages
        self._accept: tuple[tuple[int, int, bool | None], ...] | None = None  # None: accept everything
        self._urgent: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self._normal: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
        self._ready: queue.SimpleQueue[None] = queue.SimpleQueue()
        """One token per queued frame: a counting semaphore in C (threading.Semaphore is Python over a Condition, and
        releasing it was the largest cost of a frame on an idle 128-module robot; issue 31)."""
        self._open = True
        self._push: FrameCallback | None = None
        super().__init__(channel=channel, **kwargs)
        with SimBus._lock:
            SimBus._channels.setdefault(self._channel, []).append(self)
            self._reindex()

    def _reindex(self) -> None:
        """Index the channel's filters again (under the lock: a bus joined, left or changed its filters)."""
        buses = SimBus._channels.get(self._channel)
        if buses:
            SimBus._receivers[self._channel] = _Receivers(buses)
        else:
            SimBus._receivers.pop(self._channel, None)

    def push_to(self, callback: FrameCallback | None) -> None:
        """Deliver the frames this bus accepts to ``callback`` on the channel's dispatch thread instead of ``recv``
        (None: back to ``recv``); see the module docstring."""
        with SimBus._lock:
            self._push = callback
            self._update_dispatcher()

    def _update_dispatcher(self) -> None:
        """Start the channel's dispatcher with its first pushed bus, end it with its last (under the lock)."""
        pushed = any(bus._push is not None for bus in SimBus._channels.get(self._channel, ()))
        dispatcher = SimBus._dispatchers.get(self._channel)
        if pushed and dispatcher is None:
            SimBus._dispatchers[self._channel] = _Dispatcher(self._channel)
        elif not pushed and dispatcher is not None:
            del SimBus._dispatchers[self._channel]
            dispatcher.close()

    def _apply_filters(self, filters: can.typechecking.CanFilters | None) -> None:
        accept = None
        if filters:
            accept = tuple((f["can_id"], f["can_mask"], f.get("extended")) for f in filters)
        with SimBus._lock:
            self._accept = accept
            if self in SimBus._channels.get(self._channel, ()):
                self._reindex()

    def _accepts(self, message: can.Message) -> bool:
        """Whether this bus's filters pass ``message``: the definition the channel's index agrees with (tests)."""
        accept = self._accept
        if accept is None:
            return True
        arbitration_id = message.arbitration_id
        for can_id, mask, extended in accept:
            if extended is not None and extended != message.is_extended_id:
                continue
            if (arbitration_id ^ can_id) & mask == 0:
                return True
        return False

    @classmethod
    @contextmanager
    def holding(cls, channel: str) -> Iterator[None]:
        """Within the block, the frames this thread sends on ``channel`` wait, in order, and go out together at its
        end, as a controller's transmit queue fills during a burst and then drains: the channel's receivers (a
        bridge's reader, the dispatch thread) wake once for the burst instead of once a frame (a 128-module robot's
        control tick sends ~150 frames; issue 31). Nothing is reordered: a frame sent meanwhile by another thread, or
        an urgent one, sends what waits before it. One thread holds a channel at a time."""
        held = (threading.get_ident(), [])
        with cls._lock:
            if channel in cls._held:
                raise RuntimeError(f"asm_sim channel {channel!r} is already held by another thread")
            cls._held[channel] = held
        try:
            yield
        finally:
            with cls._lock:
                del cls._held[channel]
                cls._release(channel, held[1])

    @classmethod
    def flush(cls, channel: str, timeout: float = 10.0) -> int:
        """Block until every frame sent on ``channel`` so far has been handed to its pushed buses' callbacks and they
        returned; return how many frames the channel's dispatch thread had handed on by then (0 without pushed
        buses). A caller that drives every node of the channel (a simulation stepping its modules in lockstep) calls
        it until the count stops growing: then nothing is in flight, whatever the machine's load — frames a callback
        sent meanwhile are queued behind the mark and counted by the next call. Not waited for: frames read by
        ``recv``, and frames another thread holds (``holding``: they are sent at its block's end). The count is the
        dispatch thread's: it starts again when the channel's last pushed bus leaves and another joins.
        ``TimeoutError`` after ``timeout`` real seconds (a callback blocked); ``RuntimeError`` from the thread that
        holds the channel or from a callback (both would wait for themselves)."""
        with cls._lock:
            dispatcher = cls._dispatchers.get(channel)
            held = cls._held.get(channel)
            if held is not None and held[0] == threading.get_ident():
                raise RuntimeError(f"asm_sim channel {channel!r} is held by this thread: its frames wait for the end")
            if dispatcher is None:
                return 0
            if threading.current_thread() is dispatcher._thread:
                raise RuntimeError(f"asm_sim channel {channel!r}: a flush from a frame's callback waits for itself")
            mark = dispatcher.mark()
        if not mark.reached.wait(timeout):
            raise TimeoutError(f"asm_sim channel {channel!r}: frames still in flight after {timeout} s")
        return mark.handed

    @classmethod
    def _release(cls, channel: str, frames: list[tuple[SimBus, can.Message]]) -> None:
        """Deliver the frames held on ``channel`` (under the lock), and forget them."""
        for sender, message in frames:
            sender._deliver(message, False)
        frames.clear()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._open:
            raise can.CanOperationError("the bus is shut down")
        if getattr(type(msg), "owned_by_bus", False):  # its sender lets it go (asm_py.transport.can_send.Frame)
            msg.timestamp = time.time()
            msg.channel = self._channel
        else:  # the receivers get a copy of their own, as from a wire
            msg = can.Message(timestamp=time.time(), arbitration_id=msg.arbitration_id,
                              is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame,
                              is_error_frame=msg.is_error_frame, dlc=msg.dlc, data=bytes(msg.data), is_fd=msg.is_fd,
                              bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
                              channel=self._channel)  # fmt: skip
        urgent = bool(msg.is_extended_id and not msg.arbitration_id & URGENT_MASK)
        with SimBus._lock:  # one order of frames on the channel, as on a wire
            held = SimBus._held.get(self._channel)
            if held is not None:
                if held[0] == threading.get_ident() and not urgent:
                    held[1].append((self, msg))
                    return
                SimBus._release(self._channel, held[1])  # what waits was sent first
            self._deliver(msg, urgent)

    def _deliver(self, msg: can.Message, urgent: bool) -> None:
        """Put a frame this bus sent into its receivers' queues (under the lock)."""
        receivers = SimBus._receivers.get(self._channel)
        dispatcher = SimBus._dispatchers.get(self._channel)
        for bus in receivers.of(msg.arbitration_id, msg.is_extended_id) if receivers else ():
            if bus is not self or self._own:
                if bus._push is not None and dispatcher is not None:
                    dispatcher.put(bus, msg, urgent)
                else:
                    (bus._urgent if urgent else bus._normal).put(msg)
                    bus._ready.put(None)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """python-can's ``recv`` without its loop: every frame queued here passed the filters already, so the first
        one is the answer (a bridge reads ~7,500 a second from a running 128-module robot; issue 31)."""
        message, _ = self._recv_internal(timeout)
        if message is not None and _RECEIVED.isEnabledFor(self.RECV_LOGGING_LEVEL):
            _RECEIVED.log(self.RECV_LOGGING_LEVEL, "Received: %s", message)
        return message

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            self._ready.get(timeout=None if timeout is None else max(0.0, timeout))
        except queue.Empty:
            return None, True
        urgent = self._urgent  # one reader per bus: a frame behind the token is in one of the two, urgent first
        return (self._normal if urgent.empty() else urgent).get_nowait(), True

    def shutdown(self) -> None:
        with SimBus._lock:
            buses = SimBus._channels.get(self._channel, [])
            if self in buses:
                buses.remove(self)
            if not buses:
                SimBus._channels.pop(self._channel, None)
            self._reindex()
            self._push = None
            self._update_dispatcher()
        self._open = False
        super().shutdown()
