"""Modules that run the C runtime (firmware/) on a python-can bus, beside Python modules.

The firmware is what a module's microcontroller would run; built as a shared library for this machine, the same
code answers on any python-can bus — a virtual one in tests, the simulated robot's, a real interface — so a tool
cannot tell a C module from a Python one except by how fast it answers. :class:`CModule` owns the C module's
memory (one buffer of ``asm_host_size()`` bytes: the firmware allocates nothing), gives it frames from the bus and
a control tick, and lends it a :class:`~asm_module.runtime.JointDriver` as its joint.

The library is built by asm_module.firmware_build when it is missing or older than its sources.
"""

from __future__ import annotations

import ctypes
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import can

from asm_py.canbus.ids import CanId, Dest, FrameType, Priority, SystemCode, dest_filter, priority_filter, source_filter
from asm_py.clock import Clock
from asm_py.event import Event
from asm_py.protocol import Kind, Method, Status, first_byte

from ._profile import CLASSES
from .calibration import check_module_type
from .drivers import FakeDriver, JointDriver
from .firmware_build import build_library
from .firmware_calls import FirmwareCalls
from .neighbours import LocalNeighbours

log = logging.getLogger("asm_module.c_module")
_SEND = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_void_p, ctypes.c_uint8)
_COMMAND = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_float)
_RELAX = ctypes.CFUNCTYPE(None, ctypes.c_void_p)
_READ = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.POINTER(ctypes.c_float), ctypes.POINTER(ctypes.c_float),
                         ctypes.POINTER(ctypes.c_uint8))  # fmt: skip
_lock = threading.Lock()
_library: ctypes.CDLL | None = None


def library() -> ctypes.CDLL:
    """The host library, built and loaded once per process."""
    global _library
    with _lock:
        if _library is None:
            # PyDLL: a call keeps the interpreter lock. Every call takes microseconds, and releasing the lock for
            # it (CDLL) only to take it back for the send callback let other threads cut in on every frame.
            lib = ctypes.PyDLL(str(build_library()))
            lib.asm_host_size.restype = ctypes.c_size_t
            lib.asm_host_init.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_uint8, _SEND, _COMMAND, _RELAX,
                                          _READ, ctypes.c_float, ctypes.c_float, ctypes.c_uint32]  # fmt: skip
            lib.asm_host_frame.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_char_p, ctypes.c_uint8,
                                           ctypes.c_uint32]  # fmt: skip
            lib.asm_host_watch_changed.argtypes = [ctypes.c_void_p]
            lib.asm_host_watched.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
            lib.asm_host_watched.restype = ctypes.c_int
            lib.asm_host_local.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint32]
            lib.asm_host_local.restype = ctypes.c_int
            lib.asm_host_tick.argtypes = [ctypes.c_void_p, ctypes.c_uint32]
            lib.asm_host_leave.argtypes = [ctypes.c_void_p]
            for name in (
                "asm_host_done",
                "asm_host_gait_running",
                "asm_host_latched",
                "asm_host_served",
                "asm_host_dropped",
                "asm_host_gait_started_ms",
            ):
                getattr(lib, name).argtypes = [ctypes.c_void_p]
                getattr(lib, name).restype = ctypes.c_uint32
            lib.asm_host_object_id.argtypes = [ctypes.c_void_p, ctypes.c_char_p]
            lib.asm_host_object_id.restype = ctypes.c_int
            lib.asm_host_angle.argtypes = [ctypes.c_void_p]
            lib.asm_host_angle.restype = ctypes.c_float
            lib.asm_host_goal.argtypes = [ctypes.c_void_p]
            lib.asm_host_goal.restype = ctypes.c_float
            lib.asm_module_set_type.argtypes = [ctypes.c_void_p, ctypes.c_char_p]
            lib.asm_module_set_type.restype = ctypes.c_int
            _library = lib
        return _library


class CModule(FirmwareCalls):
    """One C module on a python-can bus (given, or opened from ``bus_options`` like python-can's ``can.Bus``).

    On its own it ticks every 1/``control_rate`` s of the wall clock. Given a ``clock`` and a ``tick`` event (a
    simulation's), it reads time from that clock and runs its control tick at every firing, in the firing thread,
    as a Python module runtime with ``inline=True`` does: the same ticks, so a deployed C module and a preview agree.
    Ticked so, on a bus that hands frames over itself (``asm_sim``'s ``push_to``), it has no thread of its own: the
    channel's dispatch thread gives it its frames, as it does the Python modules of a simulated robot (issue 31), and
    a simulation's ``settle`` waits for them.

    Given a ``hub`` instead of a bus (a preview: modules of one process without a bus), its frames go nowhere but
    the two the hub carries — its ``gait.state`` publications and the signals it broadcasts — and what the hub says
    of its neighbours and of signals reaches it as the frames a bus would carry, stamped with the time they were
    said and handed over at its next tick (a neighbour's news counts from the tick after it arrived either way).
    """

    def __init__(
        self,
        name: str,
        node_id: int,
        *,
        bus: can.BusABC | None = None,
        driver: JointDriver | None = None,
        control_rate: float = 50.0,
        hardware_range: tuple[float, float] = (-90.0, 90.0),
        clock: Clock | None = None,
        tick: Event | None = None,
        hub: LocalNeighbours | None = None,
        module_type: str = "",
        **bus_options: Any,
    ) -> None:
        check_module_type(module_type)  # before anything is opened
        self.name = name
        self.node_id = node_id
        self.driver = driver if driver is not None else FakeDriver()
        self.period = 1.0 / control_rate
        self.clock = clock
        self.hub = hub
        self._own_bus = bus is None and hub is None
        self.bus = bus if bus is not None or hub is not None else can.Bus(**bus_options)
        self._inbox: deque[tuple[int, int, bytes]] = deque()  # from the hub: (ms, CAN ID, data), for the next tick
        self._watching: list[Callable[[], None]] = []  # the hub's watches of neighbours
        self._listening: Callable[[], None] | None = None  # the hub's signals
        self._lib = library()
        self._memory = ctypes.create_string_buffer(self._lib.asm_host_size())
        self._name = name.encode("utf-8")  # the firmware keeps a pointer to it: it lives as long as this object
        self._t0 = time.monotonic()
        self._callbacks = (_SEND(self._send), _COMMAND(lambda _, d: self.driver.command(float(d))),
                           _RELAX(lambda _: self.driver.relax()), _READ(self._read))  # fmt: skip
        self._call_lock = threading.Lock()  # the firmware is single-threaded: one caller at a time
        self.send_errors = 0
        with self._call_lock:
            self._lib.asm_host_init(self._memory, self._name, node_id, *self._callbacks, *map(float, hardware_range),
                                    self._now_ms())  # fmt: skip
            self._lib.asm_module_set_type(self._memory, module_type.encode())  # what a board's port sets: a constant
        self._filter([])
        self._stop = threading.Event()
        self._unlisten = tick.on_change(lambda _: self.tick()) if tick is not None else None
        self._thread = threading.Thread(target=self._run, name=f"c-module:{name}", daemon=True)
        self._push_to: Callable[[Callable[[can.Message], None] | None], None] | None = (
            getattr(self.bus, "push_to", None) if tick is not None and hub is None else None
        )  # ticked by the simulation on asm_sim: the channel's dispatch thread hands it its frames
        if hub is not None:
            self._listening = hub.listen(self._heard_signal)
        elif self._push_to is not None:
            self._push_to(self._on_frame)
        else:
            self._thread.start()

    def _filter(self, neighbours: list[int]) -> None:
        """What a module's CAN controller passes (docs/protocol.md §7): its ID, broadcast requests, the e-stop, and
        the publications of the neighbours its program waits on (their gait.state), as a board's port would."""
        if self.hub is not None:
            for remove in self._watching:
                remove()
            self._watching = []
            state_object = self._lib.asm_host_object_id(self._memory, b"gait.state")
            for n in neighbours:

                def heard(state: int, n: int = n) -> None:
                    data = bytes((first_byte(Kind.PUBLICATION, Method.PUBLISH), 0, CLASSES["gait.state"],
                                  state_object)) + struct.pack("<H", state)  # fmt: skip
                    can_id = CanId(Priority.PUBLICATION, Dest.BROADCAST, 0, n, FrameType.SINGLE).pack()
                    self._inbox.append((self._now_ms(), can_id, data))

                self._watching.append(self.hub.watch(n, heard))
            return
        assert self.bus is not None
        self.bus.set_filters([dest_filter(Dest.NODE, self.node_id),
                              priority_filter(Priority.REQUEST, Dest.BROADCAST, 0),
                              priority_filter(Priority.BULK, Dest.BROADCAST, 0),
                              dest_filter(Dest.SYSTEM, SystemCode.ESTOP),
                              *(source_filter(Priority.PUBLICATION, Dest.BROADCAST, 0, n)
                                for n in neighbours)])  # fmt: skip

    def _refilter(self) -> None:
        """After a frame or a local request: if the program now waits on other neighbours, pass their frames."""
        if self._lib.asm_host_watch_changed(self._memory):
            ids = (ctypes.c_uint8 * 254)()  # room for every node ID, whatever ASM_MAX_NEIGHBOURS the build has
            self._filter(list(ids[: self._lib.asm_host_watched(self._memory, ids)]))

    def _now_ms(self) -> int:
        seconds = self.clock.now() if self.clock is not None else time.monotonic() - self._t0
        return round(seconds * 1000) & 0xFFFFFFFF

    def local(self, method: int, name: str, data: bytes = b"") -> None:
        """A request of the module's own (as its application would make): ``method`` on well-known object ``name``,
        with every check a remote request gets and no reply on the bus; ValueError naming the refusal."""
        message = bytes((first_byte(Kind.REQUEST, method), 0, CLASSES[name], 0)) + data
        with self._call_lock:
            status = self._lib.asm_host_local(self._memory, message, len(message), self._now_ms())
            self._refilter()
        if status != Status.OK:
            raise ValueError(f"{self.name}: {Method(method).name} of {name} refused: {Status(status).name}")

    def _heard_signal(self, number: int) -> None:
        message = bytes((first_byte(Kind.REQUEST, Method.SET), 0, CLASSES["gait.signal"], 0, number))
        can_id = CanId(Priority.REQUEST, Dest.BROADCAST, 0, self.node_id, FrameType.SINGLE).pack()
        self._inbox.append((self._now_ms(), can_id, message))

    def _hub_send(self, can_id: int, payload: bytes) -> None:
        """What a hub carries of a frame this module sends: its gait.state publications and its signals."""
        cid, hub = CanId.unpack(can_id), self.hub
        if hub is None:
            return
        if cid.dest_kind != Dest.BROADCAST or cid.frame != FrameType.SINGLE or len(payload) < 5:
            return
        if payload[0] == first_byte(Kind.PUBLICATION, Method.PUBLISH) and payload[2] == CLASSES[
                "gait.state"] and len(payload) == 6:  # fmt: skip
            hub.announce(self.node_id, struct.unpack_from("<H", payload, 4)[0])
        elif payload[0] == first_byte(Kind.REQUEST, Method.SET) and payload[2] == CLASSES["gait.signal"]:
            hub.broadcast(payload[4])

    def tick(self) -> None:
        """One control tick now (the firmware's asm_module_tick), after what the hub said since the last one."""
        with self._call_lock:
            while self._inbox:
                ms, can_id, data = self._inbox.popleft()
                self._lib.asm_host_frame(self._memory, can_id, data, len(data), ms)
            self._lib.asm_host_tick(self._memory, self._now_ms())

    def _send(self, _: object, can_id: int, data: int | None, dlc: int) -> int:
        payload = ctypes.string_at(data, dlc) if dlc and data is not None else b""  # one copy, not a list of ints
        if self.bus is None:
            self._hub_send(can_id, payload)
            return 0
        try:
            self.bus.send(can.Message(arbitration_id=can_id, data=payload, is_extended_id=True, is_fd=dlc > 8),
                          timeout=0.1)  # fmt: skip
            return 0
        except can.CanError:
            self.send_errors += 1
            return 1

    def _read(self, _: object, angle: Any, torque: Any, contact: Any) -> None:
        reading = self.driver.read()
        angle[0], torque[0], contact[0] = reading.angle, reading.torque, int(reading.contact)

    def _run(self) -> None:
        ticking = self._unlisten is None  # else the simulation's tick event drives it
        next_tick = time.monotonic()
        bus = self.bus
        assert bus is not None, "a module on a hub has no receive thread"
        while not self._stop.is_set():
            frame = bus.recv(timeout=max(0.0, next_tick - time.monotonic()) if ticking else 0.1)
            if frame is not None:
                self._on_frame(frame)
            if ticking and time.monotonic() >= next_tick:
                next_tick += self.period
                self.tick()

    def _on_frame(self, frame: can.Message) -> None:
        """A frame from the bus: to the firmware, as its CAN controller's interrupt would hand it over."""
        if frame.is_extended_id and not frame.is_error_frame:
            with self._call_lock:
                if self._stop.is_set():  # under the lock: close() may have left the bus while this call waited for it
                    return
                self._lib.asm_host_frame(self._memory, frame.arbitration_id, bytes(frame.data), frame.dlc,
                                         self._now_ms())  # fmt: skip
                self._refilter()

    def done(self) -> int:
        """gait.done's last firing (1 finished, 2 a state timed out with stop), 0 if it never fired."""
        return int(self._lib.asm_host_done(self._memory))

    def gait_running(self) -> bool:
        """gait.service runs."""
        return bool(self._lib.asm_host_gait_running(self._memory))

    @property
    def latched(self) -> bool:
        """The firmware's e-stop is latched."""
        return bool(self._lib.asm_host_latched(self._memory))

    @property
    def angle(self) -> float:
        """joint.angle as the firmware last read it (degrees)."""
        return float(self._lib.asm_host_angle(self._memory))

    @property
    def goal(self) -> float:
        """What the firmware commands the joint to (degrees)."""
        return float(self._lib.asm_host_goal(self._memory))

    # -- the in-process interface every module has (asm_module.module.Module; the requests in FirmwareCalls) -----

    def gait_started(self) -> float:
        """When the gait last started (its 1 s ramp began), in seconds of this module's clock (a wall clock's:
        time.monotonic())."""
        with self._call_lock:
            ms = self._lib.asm_host_gait_started_ms(self._memory)
        return ms / 1000 if self.clock is not None else self._t0 + ms / 1000

    def counters(self) -> dict[str, int]:
        """Requests served and frames or messages dropped by the firmware."""
        with self._call_lock:
            return {"served": self._lib.asm_host_served(self._memory),
                    "dropped": self._lib.asm_host_dropped(self._memory)}  # fmt: skip

    def close(self) -> None:
        """Leave the bus in order and stop; the bus is shut down if this module opened it."""
        if self._stop.is_set():
            return
        if self._unlisten is not None:
            self._unlisten()
        for remove in [*self._watching, *([self._listening] if self._listening else [])]:
            remove()
        self._stop.set()
        if self._push_to is not None:
            self._push_to(None)
        if self._thread.is_alive():
            self._thread.join(5)
        with self._call_lock:
            self._lib.asm_host_leave(self._memory)
        if self._own_bus and self.bus is not None:
            self.bus.shutdown()

    def __enter__(self) -> CModule:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
