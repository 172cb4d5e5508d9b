"""Read an attribute of a remote node.

python examples/get.py --connect tcp/127.0.0.1:7447 --node m1 --object joint.angle
"""

from __future__ import annotations

import sys

from _common import open_node, parser


def main() -> int:
    cli = parser(__doc__.splitlines()[0])
    cli.add_argument("--node", default="m1")
    cli.add_argument("--object", default="joint.angle")
    args = cli.parse_args()
    with open_node("example-get", args) as node:
        attribute = node.lookup(args.node, args.object, timeout=5)
        print(f"{args.node}/{args.object} = {attribute.get(timeout=5)!r}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
