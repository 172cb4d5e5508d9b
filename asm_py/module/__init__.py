"""What a module runs: the module runtime (its ASM objects, its gait, its e-stop), its side of a deployment, and
the byte layouts of its gait table and staged record. Imported by the robot process, the preview simulation and
``asm-module`` alike: the same program in all three."""

from .runtime import FakeDriver, JointDriver, JointReading, ModuleRuntime
from .staging import Staging
from .wire import Staged, checksum, decode_staged, decode_table, encode_staged, encode_table

__all__ = ["FakeDriver", "JointDriver", "JointReading", "ModuleRuntime", "Staged", "Staging", "checksum",
           "decode_staged", "decode_table", "encode_staged", "encode_table"]  # fmt: skip
