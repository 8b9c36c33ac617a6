"""The `wosac-eval` command line.

Each sub-command lives in its own module under `wosac_eval.fronts.commands`
and exposes `NAME` (the module's name), `HELP`, `add_arguments(parser)` and
`run(args) -> int`; a run imports only its own command's module.
The exit-code contract shared by every command: 0 success, 1 the input was
judged bad (invalid submission, failed gate), 2 usage error (or an internal
error, reported in one line; `WOSAC_EVAL_DEBUG=1` shows its traceback),
130 interrupted. Output piped into a reader that stops early (`| head`) ends
the command quietly, as any Unix tool (141).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import sys

from wosac_eval import __version__
from wosac_eval.fronts import commands
from wosac_eval.fronts.usage import UsageError
from wosac_eval.runtime.allocator import keep_freed_memory

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, what a C tool's shell status would be


def command_names() -> list[str]:
    """The sub-commands, one module each, found without importing them."""
    found = pkgutil.iter_modules(commands.__path__)
    return sorted(i.name for i in found if not i.name.startswith("_") and not i.name.endswith("_test"))


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The whole command line; with `only` a command's name, that command's options alone: the others are
    bare names, so that a run imports only its own command's modules (`compare` does not load the scoring
    stack). Any other `only` (an option, a mistyped name) gives the whole command line."""
    parser = argparse.ArgumentParser(
        prog="wosac-eval",
        description="Exact WOSAC realism metrics, without TensorFlow.",
    )
    parser.add_argument(
        "--version", action="version", version=f"wosac-eval {__version__} (metrics of waymo-open-dataset 1.6.7)"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    names = command_names()
    for name in names:
        if only in names and name != only:
            sub.add_parser(name)
            continue
        module = importlib.import_module(f"{commands.__name__}.{name}")
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def _quiet_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's last flush cannot raise again."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    # ValueError: stdout replaced by an object without a descriptor (tests)
    with contextlib.suppress(OSError, ValueError):
        os.dup2(devnull, sys.stdout.fileno())


def main(argv: list[str] | None = None) -> int:
    words = sys.argv[1:] if argv is None else argv
    parser = build_parser(only=words[0] if words else None)
    args = parser.parse_args(words)
    if not hasattr(args, "_run"):
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    keep_freed_memory()
    name = f"wosac-eval {args.command}"
    try:
        code = int(args._run(args) or 0)
        sys.stdout.flush()  # inside the guard: a closed pipe shows up here
        return code
    except UsageError as error:
        print(f"{name}: error: {error}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:
        _quiet_stdout()
        return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:
        print(f"\n{name}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as error:
        if os.environ.get("WOSAC_EVAL_DEBUG"):
            raise
        print(
            f"{name}: internal error: {type(error).__name__}: {error}\n"
            f"  (this is a bug in wosac-eval, not in your input; please report it with the command line. "
            f"WOSAC_EVAL_DEBUG=1 shows the traceback)",
            file=sys.stderr,
        )
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
