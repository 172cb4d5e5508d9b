"""The robot's commissioning service as a tool reaches it over Zenoh (server/commission_service.py answers).

A robot process owns its CAN bus, so it is the one that finds, wiggles and numbers the modules on it; a studio (or
any tool of the robot's network) asks it with one query on ``asm/<robot>/@robot/commission`` (asm_py.keys), a JSON
request, and gets one JSON reply (docs/protocol.md §10):

- ``{"op": "list"}`` → ``{"modules": [{"serial": HEX, "id": N}, …], "conflicts": {"N": [HEX, …]}}`` (id 0: none);
- ``{"op": "wiggle", "serial": HEX}`` or ``{"op": "wiggle", "id": N}`` (``"degrees"``: 1-30, default 15) → the joint
  moves that far and back, ``{"id": N, "temporary": T|null, "moved": DEGREES}``; a module without an ID is given a
  free temporary one for the wiggle and has none again after it;
- ``{"op": "assign", "serial": HEX, "id": N}`` (N 1..253; 0 erases) → ``{"serial": HEX, "id": N}``.
- ``{"op": "release"}`` → ``{"released": BOOL}``: the service latches on every e-stop of the bus (a module without
  an ID cannot: it runs no node) and refuses wiggles and IDs until this (the studio's E-STOP Release sends it).

A refusal is ``{"error": TEXT}``: an unknown serial, an ID out of range or held by another module, a module that
stops answering, or another commissioning request still running (one at a time: the bus has one scan).
"""

from __future__ import annotations

import json
from typing import Any

import zenoh

from asm_py.keys import RobotKeys

TIMEOUT = 120.0
"""Seconds a request may take: a list of 24 modules, a wiggle of an unconfigured board (two resets) on a slow bus."""
MAX_REQUEST = 1024
"""Bytes a request may have (the service refuses more before parsing it)."""


class CommissionError(RuntimeError):
    """The service refused or failed a request; the text says why."""


def commission(session: zenoh.Session, robot: str, request: dict[str, Any], timeout: float = TIMEOUT) -> dict[str, Any]:
    """Send ``request`` to robot ``robot``'s commissioning service and return its reply; CommissionError for a
    refusal, TimeoutError when no robot answered within ``timeout``."""
    key = RobotKeys(robot).commission()
    for reply in session.get(key, payload=json.dumps(request), timeout=timeout):
        if reply.ok is None:
            raise CommissionError(f"the robot's commissioning service failed: {reply.err}")
        answer = json.loads(reply.ok.payload.to_bytes())
        if not isinstance(answer, dict):
            raise CommissionError(f"the commissioning service answered {answer!r}")
        if "error" in answer:
            raise CommissionError(str(answer["error"]))
        return answer
    raise TimeoutError(f"robot {robot!r} has no commissioning service answering (a simulated or --can robot has one)")
