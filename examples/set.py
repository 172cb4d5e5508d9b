"""Write an attribute of a remote node, and wait until it is written.

python examples/set.py --connect tcp/127.0.0.1:7447 --node m1 --object joint.goal --value 0.5
"""

from __future__ import annotations

import json
import sys

from _common import open_node, parser


def main() -> int:
    cli = parser(__doc__.splitlines()[0])
    cli.add_argument("--node", default="m1")
    cli.add_argument("--object", default="joint.goal")
    cli.add_argument("--value", required=True, help='the value, as JSON (0.5, true, [1, 2], "text")')
    args = cli.parse_args()
    with open_node("example-set", args) as node:
        attribute = node.lookup(args.node, args.object, timeout=5)
        attribute.set(json.loads(args.value), timeout=5)
        print(f"{args.node}/{args.object} <- {args.value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
