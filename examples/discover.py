"""List the live nodes, then report nodes joining and leaving for a while.

python examples/discover.py --connect tcp/127.0.0.1:7447 --seconds 10
"""

from __future__ import annotations

import sys
import time

from _common import open_node, parser


def main() -> int:
    cli = parser(__doc__.splitlines()[0])
    cli.add_argument("--seconds", type=float, default=0.0, help="how long to watch (0: just list)")
    args = cli.parse_args()
    with open_node("example-discover", args) as node:
        node.on_discovery(lambda name, alive: print(f"{'joined' if alive else 'left'}: {name}", flush=True))
        time.sleep(0.5)  # let the session meet its peers before listing
        print("live:", " ".join(name for name in node.discover() if name != "example-discover"), flush=True)
        time.sleep(args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
