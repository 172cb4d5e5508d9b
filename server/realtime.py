"""Process settings for the programs that control a robot (the studio, the bridge, a module).

CPython hands its interpreter lock to a waiting thread only after the running one has held it for the switch
interval (5 ms by default). A control process has many threads — a CAN receive thread per node, Zenoh callbacks, a
tick — and an e-stop crosses several of them: with the default interval each hand-off may wait 5 ms behind a busy
thread. One millisecond costs a little throughput and bounds that wait.
"""

from __future__ import annotations

import sys

SWITCH_INTERVAL = 0.001


def prefer_latency() -> None:
    """Favour short waits for the interpreter lock over throughput (see the module docstring)."""
    sys.setswitchinterval(SWITCH_INTERVAL)
