"""Looks for a live token through a Zenoh router, on a loaded machine (two busy processes on the two cores).

Zenoh 1.10.2's liveliness get, from a client session that also holds a liveliness subscriber with history on keys
the get overlaps, answers without tokens that are there: a node's name claim missed its holder that way and kept
the name beside it. This measures it in raw Zenoh (fresh client sessions: with such a subscriber, without one, and
with one without history), then what ASM's nodes see: a node's looks at a holder (``ZenohTransport.claimants``) and
its ``peers()``, which add what the node's watch saw to what a query finds. Headline: the share of a node's looks
that missed the live holder (target 0); the raw figures are the baseline that shows the defect was present.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from asm_py import Node
from asm_py.transport import zenoh_claim
from asm_py.transport.zenoh import ZenohTransport
from asm_py.transport.zenoh_config import make_config
from server.child import free_port

LOOKS = 4
"""Looks per fresh session, CLAIM_SETTLE (50 ms) apart, as a claim makes them."""
HOLDER = "asm/a/@alive/m7/9999"


def busy_processes(count: int) -> list[subprocess.Popen[bytes]]:
    """``count`` processes spinning on a core each (stopped by the caller): the load the defect needs."""
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(count)]


def raw_misses(endpoint: str, sessions: int, subscriber: str) -> tuple[int, int]:
    """(sessions with a look that missed the holder, looks that missed it) over ``sessions`` fresh client sessions;
    ``subscriber``: "history", "plain" or "none" — the liveliness subscriber each declares before it looks."""
    missed_sessions = missed_looks = 0
    for _ in range(sessions):
        session = zenoh.open(make_config(mode="client", connect=[endpoint]))
        try:
            if subscriber != "none":
                session.liveliness().declare_subscriber(
                    "asm/a/@alive/*/*", lambda sample: None, history=subscriber == "history"
                )
            missed = 0
            for _ in range(LOOKS):
                time.sleep(0.05)
                found = {str(r.ok.key_expr) for r in session.liveliness().get(HOLDER, timeout=2.0) if r.ok is not None}
                missed += HOLDER not in found
            missed_sessions += missed > 0
            missed_looks += missed
        finally:
            session.close()
    return missed_sessions, missed_looks


def node_misses(endpoint: str, nodes: int) -> tuple[int, int]:
    """Looks of fresh ASM nodes (tools of robot "a") that missed the holder m7, by claimants and by peers(); and
    how many of the node's queries alone (zenoh_claim.tokens, what both add the watch's tokens to) missed it."""
    missed = queries_missed = 0
    for index in range(nodes):
        node = Node(f"looker{index}", ZenohTransport(robot="a", role="tool", mode="client", connect=[endpoint]))
        try:
            transport = node.transport
            assert isinstance(transport, ZenohTransport)
            for _ in range(LOOKS):
                time.sleep(0.05)
                missed += not transport.claimants("m7")
                missed += "m7" not in transport.peers()
                queries_missed += not zenoh_claim.tokens(transport.session, transport.keys.alive("m7"))
        finally:
            node.close()
    return missed, queries_missed


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--sessions", type=int, default=100, help="fresh raw sessions per variant")
    parser.add_argument("--nodes", type=int, default=60, help="fresh ASM nodes")
    args = parser.parse_args()
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router_config = make_config(mode="router", listen=[endpoint])
    router = zenoh.open(router_config)
    holder = Node("m7", ZenohTransport(robot="a", mode="client", connect=[endpoint]))
    raw_holder = zenoh.open(make_config(mode="client", connect=[endpoint]))
    raw_token = raw_holder.liveliness().declare_token(HOLDER)
    load = busy_processes(2)
    began = time.monotonic()
    try:
        time.sleep(0.5)
        results: dict[str, tuple[int, int]] = {}
        measures: list[tuple[str, Callable[[], tuple[int, int]]]] = [
            (kind, lambda kind=kind: raw_misses(endpoint, args.sessions, kind)) for kind in ("history", "none", "plain")
        ]
        for kind, measure in measures:
            results[kind] = measure()
            sessions, looks = results[kind]
            print(f"raw zenoh, subscriber {kind}: {sessions} of {args.sessions} sessions missed the holder in "
                  f"{LOOKS} looks ({looks} of {args.sessions * LOOKS} looks)", flush=True)  # fmt: skip
        missed, queries_missed = node_misses(endpoint, args.nodes)
        looks = args.nodes * LOOKS * 2
        print(f"asm nodes: {missed} of {looks} looks missed the holder (claimants and peers); their queries alone "
              f"missed it {queries_missed} times in {args.nodes * LOOKS}")  # fmt: skip
    finally:
        for process in load:
            process.kill()
            process.wait()
        raw_token.undeclare()
        raw_holder.close()
        holder.close()
        router.close()
    history_sessions, history_looks = results["history"]
    print(json.dumps({"seconds": round(time.monotonic() - began, 1)}))
    share = history_looks / (args.sessions * LOOKS)
    print(f"baseline raw_liveliness_looks_missing_beside_history_subscriber {share:.3f} "
          f"({history_sessions} of {args.sessions} sessions)")  # fmt: skip
    print(f"ratio node_looks_missing_a_live_holder {missed / looks:.3f} (target <= 0)")


if __name__ == "__main__":
    main()
