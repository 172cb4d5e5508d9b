"""Follow the publications of a remote attribute.

python examples/subscribe.py --connect tcp/127.0.0.1:7447 --node m1 --object joint.angle --count 10
"""

from __future__ import annotations

import sys

from _common import open_node, parser

from asm_py import Attribute


def main() -> int:
    cli = parser(__doc__.splitlines()[0])
    cli.add_argument("--node", default="m1")
    cli.add_argument("--object", default="joint.angle")
    cli.add_argument("--count", type=int, default=10, help="publications to print (0: forever)")
    args = cli.parse_args()
    with open_node("example-subscribe", args) as node:
        remote = node.lookup(args.node, args.object, timeout=5)
        copy = Attribute(f"copy.{args.object}", sync_get=True, codec=remote.codec)
        copy.subscribe(remote)
        print(f"READY subscribed to {args.node}/{args.object}", flush=True)
        received = 0
        while args.count == 0 or received < args.count:
            print(f"{args.node}/{args.object} = {copy.get(timeout=10)!r}", flush=True)
            received += 1
        copy.unsubscribe()
    return 0


if __name__ == "__main__":
    sys.exit(main())
