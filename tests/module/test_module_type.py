"""module.type (issue 30 part 2) on the Python module runtime: a module reports the name of its type — the one its
command line gives it (a simulated robot's: its gait's description, tests/gaits/test_module_types.py; a C module's:
tests/firmware/test_calibration.py) — read-only, "" when it is not said, and a name that is no type's is refused."""

from __future__ import annotations

import pytest

from asm_module import FakeDriver, ModuleRuntime
from asm_py import Node
from asm_py.errors import ReadOnlyError
from asm_py.transport import MemoryNetwork, MemoryTransport
from server.module import main

pytestmark = pytest.mark.timeout(120)
HOSTILE = ["a b", "x" * 33, "é", "-lead", "nul\0", "semi;colon", "dot.ted"]


def test_a_python_module_reports_its_type_read_only() -> None:
    network = MemoryNetwork()
    nodes = [Node(name, MemoryTransport(network)) for name in ("m1", "m2", "tool")]
    runtimes = [ModuleRuntime(FakeDriver(), node=nodes[0], module_type="servo_v2"),
                ModuleRuntime(FakeDriver(), node=nodes[1], module_id=2)]  # fmt: skip
    try:
        remote = nodes[2].lookup("m1", "module.type", timeout=2)
        assert remote.get(timeout=2) == "servo_v2" and remote.info.read_only and remote.info.class_id == 0x42
        with pytest.raises(ReadOnlyError):
            remote.set("servo_v3", wait=True)
        with pytest.raises(ReadOnlyError):
            remote.reset(wait=True)
        assert remote.get(timeout=2) == "servo_v2"
        assert nodes[2].lookup("m2", "module.type", timeout=2).get(timeout=2) == "", "not said"
    finally:
        for runtime in runtimes:
            runtime.close()
        for node in nodes:
            node.close()


@pytest.mark.parametrize("name", HOSTILE)
def test_a_name_that_is_no_types_is_refused(name: str) -> None:
    with pytest.raises(ValueError, match="a module type's name is 1 to 32 letters"):
        ModuleRuntime(FakeDriver(), module_type=name)
    with pytest.raises(SystemExit) as exit_:  # asm-module --type: a usage error before any bus is opened
        main(["--can", "virtual:nowhere", "--node-id", "1", "--type", name])
    assert exit_.value.code == 2
