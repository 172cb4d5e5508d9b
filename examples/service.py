"""Start, suspend, resume or stop a service of a remote node, and print its state.

python examples/service.py --connect tcp/127.0.0.1:7447 --node m1 --object servo.service --do stop
"""

from __future__ import annotations

import sys

from _common import open_node, parser


def main() -> int:
    cli = parser(__doc__.splitlines()[0])
    cli.add_argument("--node", default="m1")
    cli.add_argument("--object", default="servo.service")
    cli.add_argument("--do", choices=["start", "stop", "suspend", "resume", "status"], default="status")
    args = cli.parse_args()
    with open_node("example-service", args) as node:
        service = node.lookup(args.node, args.object, timeout=5)
        if args.do == "stop":
            service.stop(timeout=5, wait=True)
        elif args.do != "status":
            getattr(service, args.do)(wait=True)
        print(f"{args.node}/{args.object}: started={service.started} running={service.running}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
