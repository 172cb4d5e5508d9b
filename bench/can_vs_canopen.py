"""ASM against python canopen on the same bus (issue 31): a remote get and set of a float32 over python-can's
virtual bus, ASM's two nodes against canopen's expedited SDO between a RemoteNode and a LocalNode, in one process,
rounds interleaved so both see the same machine.

    .venv/bin/python bench/can_vs_canopen.py

- ``can_get_vs_canopen_sdo``: ASM remote gets per second over canopen SDO uploads per second (best round of each).
  Target >= 1.5.
- ``can_set_vs_canopen_sdo``: ASM remote sets (a reply wanted, as an SDO download is confirmed) over SDO
  downloads. Target >= 1.5.

Also printed, interleaved in the same rounds: the ceiling of the medium — round trips of bare python-can on the same
kind of bus, a request frame sent and a bare echo thread answering (no protocol at all; bench/can_bus.py's
baseline) — so a reader sees how far above it a target lies.
"""

from __future__ import annotations

import itertools
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import can
import canopen
from canopen.objectdictionary import REAL32, ODVariable

from asm_py import Attribute, Node
from asm_py.transport.can import CanTransport

ROUNDS = 7
CALLS = 600


def rate(call: Callable[[], object]) -> float:
    began = time.perf_counter()
    for _ in range(CALLS):
        call()
    return CALLS / (time.perf_counter() - began)


def main() -> None:
    asm_channel, co_channel = "bench-asm-vs-canopen", "bench-canopen"
    module = Node("m1", CanTransport(1, interface="virtual", channel=asm_channel))
    tool = Node("tool", CanTransport(2, interface="virtual", channel=asm_channel))
    module.register(Attribute("joint.angle", 1.5, codec="float32"))
    angle = tool.lookup("m1", "joint.angle", timeout=5)

    dictionary = canopen.ObjectDictionary()
    variable = ODVariable("angle", 0x2000, 0)
    variable.data_type = REAL32
    variable.access_type = "rw"
    variable.default = 1.5
    dictionary.add_object(variable)
    server_net, client_net = canopen.Network(), canopen.Network()
    server_net.connect(interface="virtual", channel=co_channel)
    client_net.connect(interface="virtual", channel=co_channel)
    server_net.add_node(canopen.LocalNode(1, dictionary))
    remote = canopen.RemoteNode(1, dictionary)
    client_net.add_node(remote)
    sdo = remote.sdo[0x2000]
    values = itertools.cycle([0.25, 0.5])
    echo_client = can.Bus(interface="virtual", channel="bench-can-echo")
    echo_server = can.Bus(interface="virtual", channel="bench-can-echo")
    request = can.Message(arbitration_id=0x0101_0200, data=bytes([0x51, 0x01, 0x11, 0x01]))
    reply = can.Message(arbitration_id=0x0002_0100, data=bytes([0x61, 0x01, 0x00, 0x01, 0, 0, 0xC0, 0x3F]))
    stop = threading.Event()

    def echo() -> None:
        while not stop.is_set():
            if echo_server.recv(timeout=0.05) is not None:
                echo_server.send(reply)

    def raw_round_trip() -> None:
        echo_client.send(request)
        echo_client.recv(timeout=1.0)

    echoer = threading.Thread(target=echo, daemon=True)
    echoer.start()
    try:
        assert angle.get() == 1.5 and sdo.raw == 1.5
        best = {"asm_get": 0.0, "asm_set": 0.0, "sdo_get": 0.0, "sdo_set": 0.0, "raw": 0.0}
        calls: dict[str, Callable[[], object]] = {
            "asm_get": angle.get,
            "sdo_get": lambda: sdo.raw,
            "asm_set": lambda: angle.set(next(values), wait=True),
            "sdo_set": lambda: setattr(sdo, "raw", next(values)),
            "raw": raw_round_trip,
        }
        for _ in range(ROUNDS):
            for name, call in calls.items():
                best[name] = max(best[name], rate(call))
    finally:
        stop.set()
        echoer.join(5)
        echo_client.shutdown()
        echo_server.shutdown()
        client_net.disconnect()
        server_net.disconnect()
        tool.close()
        module.close()
    print("# bench/can_vs_canopen.py: python-can virtual bus, one process, best of "
          f"{ROUNDS} interleaved rounds of {CALLS}")  # fmt: skip
    print(f"gets: ASM {best['asm_get']:,.0f}/s, canopen SDO upload {best['sdo_get']:,.0f}/s")
    print(f"sets: ASM {best['asm_set']:,.0f}/s, canopen SDO download {best['sdo_set']:,.0f}/s")
    ceiling = max(best["sdo_get"], best["sdo_set"]) * 1.5
    print(f"bare python-can echo round trips (no protocol): {best['raw']:,.0f}/s; 1.5 x the faster SDO: "
          f"{ceiling:,.0f}/s")  # fmt: skip
    print(f"ratio can_get_vs_canopen_sdo {best['asm_get'] / best['sdo_get']:.2f} (target >= 1.5)")
    print(f"ratio can_set_vs_canopen_sdo {best['asm_set'] / best['sdo_set']:.2f} (target >= 1.5)", flush=True)


if __name__ == "__main__":
    main()
