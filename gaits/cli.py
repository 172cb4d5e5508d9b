"""The ``gaits`` command: validate a gait file, or print its expanded control table.

gaits validate FILE...        exit 1 and list every problem (with its line) if a file is bad
gaits expand FILE [--samples 16]
"""

from __future__ import annotations

import argparse
import sys

from .model import GaitError, load
from .table import format_table


def main(argv: list[str] | None = None) -> int:
    cli = argparse.ArgumentParser(prog="gaits", description=__doc__.splitlines()[0])
    commands = cli.add_subparsers(dest="command", required=True)
    validate = commands.add_parser("validate", help="check gait files")
    validate.add_argument("files", nargs="+")
    expand = commands.add_parser("expand", help="print the module x time table")
    expand.add_argument("file")
    expand.add_argument("--samples", type=int, default=16, help="samples per period (default 16)")
    args = cli.parse_args(argv)
    if args.command == "validate":
        failed = 0
        for path in args.files:
            try:
                gait = load(path)
            except (GaitError, OSError) as exc:
                failed += 1
                problems = getattr(exc, "problems", None) or [exc]
                print(f"{path}: INVALID", file=sys.stderr)
                for problem in problems:
                    print(f"  {problem}", file=sys.stderr)
                continue
            print(f"{path}: ok ({gait.name}: {gait.robot.modules} modules, {len(gait.automata)} automata)")
        return 1 if failed else 0
    try:
        gait = load(args.file)
        print(format_table(gait, samples=args.samples))
    except (GaitError, OSError, ValueError) as exc:
        print(f"{args.file}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
