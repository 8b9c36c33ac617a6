"""The `wosac-server` command: `serve` (API + workers), `keys` (API keys), `worker` (one scoring worker).

Exit codes: 0 ok, 1 nothing to do (name taken, unknown key), 2 usage or configuration error.
"""

from __future__ import annotations

import argparse
import sys

from . import keys, methods, serve


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="wosac-server", description="The WOSAC scoring service.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in (serve, keys, methods):
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    worker = sub.add_parser(
        "worker", help="Run one scoring worker (for hosts that only score; WOSAC_* environment like serve)."
    )
    worker.set_defaults(_run=lambda args: __import__("wosac_server.worker", fromlist=["main"]).main())
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "_run"):
        parser.print_help(sys.stderr)
        return 2
    return int(args._run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
