"""What a module runs: the module runtime (its ASM objects, its gait, its e-stop), its side of a deployment, and
the byte layouts of its gait table and staged record. Imported by the robot process, the preview simulation and
``asm-module`` alike: the same program in all three."""

from .drivers import FakeDriver, JointDriver, JointReading
from .names import module_name
from .neighbours import BusNeighbours, LocalNeighbours
from .program import Mode, ModeState, Program, Until
from .runtime import ModuleRuntime
from .staging import Staging
from .wire import (
    Staged,
    checksum,
    decode_program,
    decode_staged,
    decode_table,
    encode_program,
    encode_staged,
    encode_table,
)

__all__ = ["BusNeighbours", "FakeDriver", "JointDriver", "JointReading", "LocalNeighbours", "Mode", "ModeState",
           "ModuleRuntime", "Program", "Staged", "Staging", "Until", "checksum", "decode_program", "decode_staged",
           "decode_table", "encode_program", "encode_staged", "encode_table", "module_name"]  # fmt: skip
