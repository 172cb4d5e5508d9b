"""A module's calibration and its module-info, the Python runtime's side (docs/protocol.md §9; the C runtime's is
firmware/src/module.c).

``joint.calibration`` maps the joint's raw angle (what its driver reads and commands) to the module's: the angle
reported is ``direction * (raw - zero)``, the raw angle commanded ``zero + direction * goal``; ``(min, max)`` are
the soft limits joint.limits may be set within, themselves within the hardware's raw range once mapped. A value
that breaks a rule is refused (ValueError: VALUE_ERROR on the wire), never clamped. A Python module keeps it in a
small JSON file (what flash is to a board): :class:`CalibrationFile`.

``module.type`` names the module's type as a gait's robot description names it (gaits/robot.py), so a tool can tell a
robot of other modules than the gait was made for (gaits/compatible.py). ``module.info`` says what a tool cannot
learn otherwise: the firmware version and build, the language, the limits
this module holds (states, modes, the longest message it reassembles) and, for a board, its worst control tick in
target cycles and its stack's high-water mark (0 here: a Python module measures neither).
"""

from __future__ import annotations

import json
import math
import os
import re
import struct
import zlib
from dataclasses import asdict, dataclass
from functools import cache
from pathlib import Path
from typing import Any

from asm_py._contract import MAX_MESSAGE

from ._profile import MAX_MODES, MAX_STATES
from .drivers import JointDriver, JointReading

VERSION = 0x000100
"""The Python module runtime's version, 0xMMmmpp (0.1.0), as firmware/include/asm/version.h is the C runtime's."""
PYTHON, C = 0, 1
"""module.info's ``language``."""


@dataclass(frozen=True)
class Calibration:
    zero: float = 0.0
    """The raw angle that is the module's 0°, degrees."""
    direction: int = 1
    """+1, or -1 for a joint mounted the other way round."""
    min: float = -90.0
    max: float = 90.0
    """The soft limits, degrees in the module's frame."""

    def raw(self, degrees: float) -> float:
        """The raw angle of the module's ``degrees``."""
        return self.zero + self.direction * degrees

    def angle(self, raw: float) -> float:
        """The module's angle of the raw ``raw``."""
        return self.direction * (raw - self.zero)

    def as_record(self) -> dict[str, Any]:
        return asdict(self)


def check_calibration(value: Any, hardware_range: tuple[float, float]) -> Calibration:
    """``value`` (a Calibration or the wire's record) as a Calibration if valid within ``hardware_range``; else
    ValueError saying why (NaN, ±inf, a direction not ±1, min ≥ max, a limit whose raw angle lies outside)."""
    if isinstance(value, Calibration):
        value = value.as_record()
    if not isinstance(value, dict) or set(value) != {"zero", "direction", "min", "max"}:
        raise ValueError(f"joint.calibration is a record of zero, direction, min and max, not {value!r}"[:200])
    try:
        zero, lo, hi = (float(value[k]) for k in ("zero", "min", "max"))
    except (TypeError, ValueError):
        raise ValueError(f"joint.calibration's zero, min and max are numbers, not {value!r}"[:200]) from None
    direction = value["direction"]
    if not all(math.isfinite(v) for v in (zero, lo, hi)):
        raise ValueError(f"joint.calibration's zero, min and max must be finite, not {zero}, {lo}, {hi}")
    if isinstance(direction, bool) or direction not in (1, -1):
        raise ValueError(f"joint.calibration's direction is +1 or -1, not {direction!r}"[:200])
    calibration = Calibration(zero, int(direction), lo, hi)
    hw_lo, hw_hi = hardware_range
    raw = sorted((calibration.raw(lo), calibration.raw(hi)))
    if not (lo < hi and hw_lo <= raw[0] and raw[1] <= hw_hi):
        raise ValueError(f"joint.calibration's limits must satisfy min < max with zero + direction·limit within "
                         f"the hardware's range [{hw_lo}, {hw_hi}], not min {lo}, max {hi}, zero {zero}, "
                         f"direction {direction}")  # fmt: skip
    return calibration


class CalibrationFile:
    """A Python module's stored calibration: JSON in ``path``, replaced atomically (a crash mid-write keeps the old
    one). A file that does not exist holds none; one that is not a valid calibration is refused at load."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)

    def load(self, hardware_range: tuple[float, float]) -> Calibration | None:
        if not self.path.exists():
            return None
        try:
            record = json.loads(self.path.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{self.path}: not a calibration ({exc})") from None
        return check_calibration(record, hardware_range)

    def save(self, calibration: Calibration) -> None:
        temporary = self.path.with_name(self.path.name + ".tmp")
        temporary.write_text(json.dumps(calibration.as_record()) + "\n")
        os.replace(temporary, self.path)


class CalibratedJoint(JointDriver):
    """The runtime's view of its driver: every command and reading goes through the calibration (swapped
    atomically by :meth:`calibrate`). The driver itself stays raw (what tests and simulations inspect)."""

    def __init__(self, driver: JointDriver, calibration: Calibration) -> None:
        self.driver = driver
        self.calibration = calibration

    def calibrate(self, calibration: Calibration) -> None:
        self.calibration = calibration  # one reference swap: a tick sees the old one or the new one

    def command(self, degrees: float) -> None:
        self.driver.command(self.calibration.raw(degrees))

    def read(self) -> JointReading:
        reading, c = self.driver.read(), self.calibration
        return JointReading(c.angle(reading.angle), c.direction * reading.torque, reading.contact)

    def relax(self) -> None:
        self.driver.relax()

    def hold(self) -> float:
        return self.calibration.angle(self.driver.hold())

    def release(self) -> None:
        self.driver.release()


@cache
def build_id() -> int:
    """The CRC-32 of the runtime's sources (asm_module and asm_py, by path and content): two modules report the same
    build exactly when they run the same code, as a board's build is its sources' CRC (firmware_build.build_id)."""
    crc = 0
    for package in (Path(__file__).parent, Path(__file__).parent.parent / "asm_py"):
        for path in sorted(package.rglob("*.py")):
            crc = zlib.crc32(path.relative_to(package.parent).as_posix().encode() + b"\0" + path.read_bytes(), crc)
    return crc


def python_info() -> dict[str, Any]:
    """module.info of a Python module."""
    return {"version": VERSION, "build": build_id(), "language": PYTHON, "max_states": MAX_STATES,
            "max_modes": MAX_MODES, "max_message": MAX_MESSAGE, "tick_cycles": 0, "stack_bytes": 0}  # fmt: skip


TYPE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_+-]{0,31}")
"""A module type's name (module.type; a gait's ``[robot.types.NAME]``, gaits/schema.json's ``type_name``)."""


def check_module_type(name: str) -> str:
    """``name`` if it may be a module's ``module.type``: empty (the module does not say) or a type's name; else
    ValueError saying what a name is."""
    if name and not TYPE_NAME.fullmatch(name):
        raise ValueError(f"a module type's name is 1 to 32 letters, digits, '_', '+' or '-', the first a letter or "
                         f"digit, not {name[:40]!r}")  # fmt: skip
    return name


def version_text(version: int) -> str:
    """0xMMmmpp as ``M.m.p``."""
    return f"{version >> 16 & 0xFF}.{version >> 8 & 0xFF}.{version & 0xFF}"


CALIBRATION_MAGIC, CALIBRATION_TAG = 0x41534D43, 0xCA1B0000
"""A board's calibration record in its settings log (firmware/port/stm32f4_bxcan.c; docs/protocol.md §9)."""


def flash_record(calibration: Calibration) -> bytes:
    """The 24 bytes a board appends to its settings sector for ``calibration``: the magic "ASMC", zero, min, max
    (float32), CALIBRATION_TAG | direction, and the CRC-32 of the four words between, all little-endian words."""
    body = struct.pack("<fffI", calibration.zero, calibration.min, calibration.max,
                       CALIBRATION_TAG | calibration.direction & 0xFF)  # fmt: skip
    return struct.pack("<I", CALIBRATION_MAGIC) + body + struct.pack("<I", zlib.crc32(body))
