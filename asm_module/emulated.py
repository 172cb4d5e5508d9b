"""Modules that run the board image itself: the STM32F4 port's ELF (firmware/port/stm32f4_bxcan.c with the runtime,
built by Debian's arm-none-eabi-gcc), instruction by instruction in Unicorn (asm_module/emulator.py), its bxCAN
controller bridged to a python-can bus.

A :class:`~asm_module.c_module.CModule` runs the same C sources compiled for this machine; an
:class:`EmulatedModule` runs what would be flashed — its startup code, clock set-up, CAN driver and acceptance
filters, its PWM and encoder — so what only the board build does wrong (a register address, an unenabled FPU, a
filter that drops a needed frame, a stack that runs into the data) shows up here, with the cycles each control
tick costs and the stack it needs.

The in-process calls of the :class:`~asm_module.module.Module` interface are the module application's own requests
(asm_node_local), called inside the image through the debug map the port exports (``asm_probe``) at an idle point
of its main loop, as a debugger would call them.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from typing import Any

import can

from asm_py.clock import Clock
from asm_py.event import Event
from asm_py.protocol import Kind, Method, Status, first_byte

from ._profile import CLASSES
from .backplane import Backplane
from .bxcan import BxCan
from .drivers import FakeDriver, JointDriver
from .elf import Image, read_image
from .emulator import BoardReset, Cortex, FirmwareFault, Joint, TickStats, register_image
from .firmware_build import build_board_image
from .firmware_calls import FirmwareCalls
from .flash import Settings

log = logging.getLogger("asm_module.emulated")
CONTROL_MS = 20
CATCH_UP_MS = 200
"""The most emulated milliseconds run in one hold of a board's lock."""
IDLE_WAIT, FRAMES_WAIT, SIM_WAIT = 0.1, 0.001, 0.05
"""Seconds a board's thread waits for a frame at most: on its own, before running its clock on (less if its next
interrupt comes sooner: it wakes for that); while frames wait for room in its receive FIFO; on a simulation's
clock, whose ticks run it (the thread only serves frames)."""
_image_lock = threading.Lock()
_image: Image | None = None


def board_image() -> Image:
    """The board image, built (when missing or stale) and parsed once per process."""
    global _image
    with _image_lock:
        if _image is None:
            _image = read_image(build_board_image())
            register_image(_image)
        return _image


def versioned_image(version: int) -> Image:
    """The board image's sources built as version ``version`` (0xMMmmpp), known to the emulator (its symbols for a
    board that boots it after an update): what a test or a bench updates boards to."""
    image = read_image(build_board_image(version))
    register_image(image)
    return image


def board_config(node_id: int, name: str, hardware_range: tuple[float, float]) -> bytes:
    """The port's ``board_config`` (node ID, name, the joint's hardware range) as it is flashed."""
    encoded = name.encode("utf-8")
    if len(encoded) > 14:
        raise ValueError(f"{name!r}: a board's name has at most 14 bytes")
    return struct.pack("<B15sff", node_id, encoded, *hardware_range)


class EmulatedModule(FirmwareCalls):
    """One board image in the emulator on a python-can bus (given, or opened from ``bus_options``).

    On its own its clock follows the wall clock. Given a ``clock`` and a ``tick`` event (a simulation's), its
    milliseconds are that clock's since it was made and it is run up to the clock's time at every firing, in the
    firing thread: its own 20 ms control tick, counted from its boot, falls in the simulation's ticks. A bus thread
    carries frames both ways either way.

    ``serial`` is the board's unique ID (12 bytes; zeros if not given) and ``settings`` its settings flash sector
    (asm_module/flash.py), where a commissioned node ID is kept: a new EmulatedModule on the same settings is the
    board power-cycled. ``node_id`` 0 flashes no ID: the board boots unconfigured unless its settings hold one."""

    def __init__(
        self,
        name: str,
        node_id: int,
        *,
        bus: can.BusABC | None = None,
        driver: JointDriver | None = None,
        hardware_range: tuple[float, float] = (-90.0, 90.0),
        clock: Clock | None = None,
        tick: Event | None = None,
        serial: bytes | None = None,
        settings: Settings | None = None,
        **bus_options: Any,
    ) -> None:
        self.name = name
        self.node_id = node_id
        self.driver = driver if driver is not None else FakeDriver()
        self.serial = serial if serial is not None else bytes(12)
        self.settings = settings if settings is not None else Settings()
        self.clock = clock
        image = board_image()  # before the bus is opened: a build or a name that fails leaves nothing open
        self._image = image
        config = board_config(node_id, name, hardware_range)
        self.can = BxCan(self._transmit)  # frames before the first boot: dropped with it (_boot makes the board's)
        self._wake = threading.Event()  # a frame kept by its controller, or close()
        self._receiver = self._receive  # one bound method: the backplane knows the sender by it
        self._plane = Backplane.join(self._receiver, bus, **bus_options)
        self.bus = self._plane.bus
        self.send_errors = 0
        self.fault: FirmwareFault | None = None
        self._lock = threading.RLock()  # the core is single-threaded: one runner at a time
        self._t0 = clock.now() if clock is not None else time.monotonic()
        self.resets: list[str] = []  # why the board reset itself (watchdog, an installed update), in order
        with self._lock:
            self._boot(config)
        self._stop = threading.Event()
        self._unlisten = tick.on_change(lambda _: self.advance()) if tick is not None else None
        self._thread = threading.Thread(target=self._run, name=f"asm-emulated:{name}", daemon=True)
        self._thread.start()

    def _boot(self, config: bytes | None = None) -> None:
        """Power on (or reset): a new core on the board's flash; the bootloader starts what the flash holds."""
        if hasattr(self, "core"):
            self.core.release()
        self.can = BxCan(self._transmit)
        joint = Joint(self.driver.command, self.driver.relax, self._read_joint)
        self.core = Cortex(self._image, self.can, joint, config, settings=self.settings, serial=self.serial)
        app = self.core.app
        if app is None:
            raise RuntimeError(f"{self.name}: the board runs an image the emulator cannot read: no ELF of it, and "
                               "not laid out as firmware/port/stm32f4.ld lays out an image")  # fmt: skip
        self._probe = struct.unpack("<15I", self.core.uc.mem_read(app.symbol("asm_probe"), 60))
        if self._probe[0] != 3:
            raise RuntimeError(f"the board image's asm_probe is version {self._probe[0]}, not 3")

    @property
    def firmware_version(self) -> int:
        """The running image's version (0xMMmmpp), from its header in RAM."""
        with self._lock:
            return self.core.read_word(0x20000000 + 12)

    # -- the bridge ----------------------------------------------------------------------------------------------

    def _now_ms(self) -> int:
        seconds = (self.clock.now() if self.clock is not None else time.monotonic()) - self._t0
        return max(0, int(seconds * 1000))

    def advance(self) -> None:
        """Run the image up to now (its clock's): frames received so far reach it, its ticks due run. A board far
        behind (a loaded machine) catches up CATCH_UP_MS at a time, the core free between them: close() and the
        host's calls never wait for a whole backlog."""
        target = self._now_ms()
        while True:
            with self._lock:
                if self.fault is not None or self._stop.is_set():
                    return
                core = self.core
                step = min(target, core.now_ms + CATCH_UP_MS)
                self._run_to(step)
                if step >= target or not core.idle or self.core is not core:  # done, busy, or reset (a new clock)
                    return

    def _run_to(self, milliseconds: int) -> None:
        try:
            self.core.run(milliseconds)
        except BoardReset as reset:
            self.resets.append(str(reset))
            log.info("%s: the board resets: %s", self.name, reset)
            self._t0 = self.clock.now() if self.clock is not None else time.monotonic()
            try:
                self._boot()
            except (FirmwareFault, RuntimeError) as exc:
                self.fault = FirmwareFault(f"after a reset: {exc}")
                log.error("%s: the emulated board stopped after a reset: %s", self.name, exc)
        except FirmwareFault as exc:
            self.fault = exc
            log.error("%s: the emulated board stopped: %s", self.name, exc)

    def _transmit(self, can_id: int, extended: bool, data: bytes) -> None:
        try:
            self._plane.send(self._receiver, can_id, extended, data)
        except can.CanError:
            self.send_errors += 1

    def _receive(self, can_id: int, extended: bool, data: bytes) -> None:
        """A frame on the bus (the backplane's reader, or another board's thread): to the controller, which keeps
        it only if its acceptance filters pass it; the board's thread woken only then."""
        if self.can.deliver(can_id, extended, data):
            self._wake.set()

    def _read_joint(self) -> tuple[float, bool]:
        reading = self.driver.read()
        return reading.angle, reading.contact

    def _run(self) -> None:
        # a frame the controller kept ends the wait at once; without one, on its own the board sleeps until its next
        # interrupt is due (a SysTick every 20 ms: 50 wakes a second, each on time), and on a simulation's clock its
        # ticks run it: this thread only serves frames
        while not self._stop.is_set():
            self._wake.wait(self._wait())
            self._wake.clear()
            if self.clock is None or self.can.pending():
                self.advance()

    def _wait(self) -> float:
        if self.can.pending():
            return FRAMES_WAIT
        if self.clock is not None:
            return SIM_WAIT
        with self._lock:
            due = self._t0 + self.core.wake_ms / 1000  # when its next interrupt is due, on this module's clock
        return min(IDLE_WAIT, max(FRAMES_WAIT, due - time.monotonic()))

    # -- what a debugger reads and calls -------------------------------------------------------------------------

    def _byte(self, at: int) -> int:
        return self.core.uc.mem_read(at, 1)[0]

    def _float(self, at: int) -> float:
        return struct.unpack("<f", self.core.uc.mem_read(at, 4))[0]

    def local(self, method: int, name: str, data: bytes = b"") -> None:
        """A request of the module's own: ``method`` on well-known object ``name`` through the image's
        asm_node_local, with every check a remote request gets; ValueError naming the refusal."""
        message = bytes((first_byte(Kind.REQUEST, method), 0, CLASSES[name], 0)) + data
        _, node, local, _, now_ms, *_ = self._probe
        with self._lock:
            if self.fault is not None:
                raise RuntimeError(f"{self.name}: the emulated board stopped: {self.fault}")
            self.core.uc.mem_write(now_ms, struct.pack("<I", self.core.call(self._probe[14])))  # the port's clock
            status = self.core.call(local, node, message, len(message))
        if status != Status.OK:
            raise ValueError(f"{self.name}: {Method(method).name} of {name} refused: {Status(status).name}")

    @property
    def configured(self) -> bool:
        """The board runs its node (it has a node ID); else it answers only commissioning."""
        with self._lock:
            return bool(self._byte(self._probe[12]))

    def commissioned_id(self) -> int:
        """The node ID the board runs under (0: none), as its commissioning state holds it."""
        with self._lock:
            return self._byte(self._probe[13] + 12)

    @property
    def latched(self) -> bool:
        """The firmware's e-stop is latched."""
        with self._lock:
            return bool(self._byte(self._probe[5]))

    @property
    def goal(self) -> float:
        """What the firmware commands the joint to (degrees): joint.goal's value in its memory."""
        with self._lock:
            return self._float(self._probe[6])

    @property
    def angle(self) -> float:
        """joint.angle as the firmware last read it from its encoder (degrees)."""
        with self._lock:
            return self._float(self._probe[7])

    def gait_running(self) -> bool:
        """gait.service runs."""
        with self._lock:
            return bool(self._byte(self._probe[8]))

    def milliseconds(self) -> int:
        """The board's millisecond count (its SysTick interrupts)."""
        with self._lock:
            return self.core.read_word(self._probe[9])

    def tick_cycles(self) -> TickStats:
        """Instructions per control tick (asm_module_tick) so far: count, sum, worst — cycles at one per
        instruction, a lower bound of the board's (loads, branches and divisions take more)."""
        with self._lock:
            return TickStats(self.core.ticks.ticks, self.core.ticks.total, self.core.ticks.worst)

    def worst_period_cycles(self) -> int:
        """The most instructions executed in one 20 ms control period so far: the tick, the frames received and
        sent, the interrupts — what the core did while not idle."""
        with self._lock:
            return self.core.worst_period

    def stack_used(self) -> int:
        """The stack's high-water mark in bytes (the paint the emulator laid at boot, overwritten)."""
        with self._lock:
            return self.core.stack_used()

    # -- the in-process interface every module has (asm_module.module.Module; the requests in FirmwareCalls) -----

    def gait_started(self) -> float:
        """When the gait last started (its 1 s ramp began), in seconds of this module's clock (a wall clock's:
        time.monotonic())."""
        with self._lock:
            return self._t0 + self.core.read_word(self._probe[10]) / 1000

    def done(self) -> int:
        """gait.done's last firing (1 finished, 2 a state timed out with stop), 0 if it never fired."""
        with self._lock:
            return self._byte(self._probe[11])

    def close(self) -> None:
        """Leave the bus in order (asm_node_leave in the image) and stop; a bus opened for this module's options is
        shut down with the last module on it (asm_module/backplane.py), a given one is left open."""
        if self._stop.is_set():
            return
        if self._unlisten is not None:
            self._unlisten()
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(5)
        with self._lock:
            if self.fault is None and self._byte(self._probe[12]):  # a board without a node ID has none to leave
                try:
                    self.core.call(self._probe[3], self._probe[1])
                except (FirmwareFault, RuntimeError) as exc:  # faulted while leaving, or too busy to be called
                    log.error("%s: leaving the bus: %s", self.name, exc)
        self._plane.leave(self._receiver)

    def __enter__(self) -> EmulatedModule:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
