"""The `wosac-eval` command line.

Each sub-command lives in its own module under `wosac_eval.fronts.commands`
and exposes `NAME`, `HELP`, `add_arguments(parser)` and `run(args) -> int`.
The exit-code contract shared by every command: 0 success, 1 the input was
judged bad (invalid submission, failed gate), 2 usage error.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from wosac_eval.runtime.allocator import keep_freed_memory
from wosac_eval.fronts import commands


def _command_modules():
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda i: i.name):
        if not info.name.startswith("_") and not info.name.endswith("_test"):
            yield importlib.import_module(f"{commands.__name__}.{info.name}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="wosac-eval",
        description="Exact WOSAC realism metrics, without TensorFlow.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in _command_modules():
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not hasattr(args, "_run"):
        parser.print_help(sys.stderr)
        return 2
    keep_freed_memory()
    return int(args._run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
