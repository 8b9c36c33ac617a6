"""What every command shares before its work starts: its common options, usage errors and output paths
checked up front.

The options several commands take (`--challenge`, `--scenarios`, `--workers`, `--engine` and
`--ray-address`, the input limits `--max-bytes` and `--max-shard-bytes`) are declared here once, each with
the one type that checks its value: a bad value is refused by the parser, in one line naming the option,
before the command runs, and a choice becomes its enum member there (`Challenge`, `Engine`), which the
command passes on.

A usage error is the user's to fix (a missing folder, an output that cannot be
written, swapped arguments); the command line prints it as one line and exits 2
before any long work, so an hour of scoring is never lost to a typo in `-o`.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
from collections.abc import Sequence
from pathlib import Path

from wosac_eval.challenges import CHALLENGE_NAMES, Challenge, as_challenge
from wosac_eval.options import Engine

# Kept light: every command imports this module, `compare` and `report` included (they load no scoring).
_SIZE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([KMGT]i?B?|B)?\s*$", re.IGNORECASE)
_UNITS = {"": 1, "B": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


class UsageError(ValueError):
    """A mistake in the command line or its paths; the message names the option and the likely cause."""


def check_output_file(path: str | os.PathLike | None, option: str) -> None:
    """Refuse, before any work, an output file that could not be written at the end.

    Raises:
      UsageError: the path is a folder, its folder does not exist or is not a
        folder, or the file or its folder is not writable.
    """
    if path is None or str(path) == "-":
        return
    target = Path(path)
    parent = target.parent if str(target.parent) else Path(".")
    if target.is_dir():
        raise UsageError(f"{option} {path}: cannot write: is a folder; give a file name, e.g. {target / 'result.json'}")
    if not parent.exists():
        raise UsageError(
            f"{option} {path}: cannot write: the folder {parent} does not exist; create it first (mkdir -p {parent})"
        )
    if not parent.is_dir():
        raise UsageError(f"{option} {path}: cannot write: {parent} is a file, not a folder")
    if target.exists() and not os.access(target, os.W_OK):
        raise UsageError(f"{option} {path}: cannot write: the file exists and is not writable")
    if not target.exists() and not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: cannot write: the folder {parent} is not writable")
    if not target.exists():
        _probe_create(target, path, option)


def _probe_create(target: Path, path: str | os.PathLike, option: str) -> None:
    """Create and remove the file, for folders whose permissions tell nothing (e.g. /proc, a read-only mount)."""
    try:
        fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:  # made in the meantime: writing it is the caller's business
        return
    except OSError as error:
        folder = target.parent if str(target.parent) else Path(".")
        raise UsageError(
            f"{option} {path}: cannot write: cannot create a file in {folder} ({error.strerror or error})"
        ) from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(target)


def check_output_folder(path: str | os.PathLike | None, option: str) -> None:
    """Refuse, before any work, an output folder that cannot be created or written.

    Raises:
      UsageError: the path is a file, or the nearest existing folder above it is not writable.
    """
    if path is None:
        return
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise UsageError(f"{option} {path}: cannot write: is a file; give a folder")
    existing = target
    while not existing.exists():
        existing = existing.parent if existing != existing.parent else Path(".")
        if str(existing) in ("", "."):
            existing = Path(".")
            break
    if not existing.is_dir() or not os.access(existing, os.W_OK | os.X_OK):
        raise UsageError(f"{option} {path}: cannot write: cannot create or write in {existing}")


def check_input(path: str | os.PathLike, option: str, what: str = "input") -> None:
    """Refuse a missing input file or folder, naming the option.

    Raises:
      UsageError: nothing exists at the path (globs are the caller's to expand).
    """
    if not Path(path).exists():
        raise UsageError(f"{option} {path}: no such {what} file or folder")


_SUBMISSION_SUFFIXES = (".binproto", ".tar", ".tar.gz", ".tgz")


def _looks_like_submission(path: Path) -> bool:
    if path.is_dir():
        return any(p.name.endswith(".binproto") for p in path.iterdir())
    return path.name.endswith(_SUBMISSION_SUFFIXES)


def scenario_set_hint(scenario_paths: Sequence[str | os.PathLike], submission: str | os.PathLike) -> str:
    """' (...swapped?)' when the scenario paths look like a submission and the submission like scenarios."""
    # Here, not at the top: `compare` and `report` import this module and never read a TFRecord file.
    from wosac_eval.parse.tfrecord import looks_like_tfrecord

    suspicious = [str(p) for p in scenario_paths if Path(p).exists() and _looks_like_submission(Path(p))]
    sub = Path(submission)
    sub_is_tfrecord = False
    if sub.is_file() and not sub.name.endswith(".gz"):
        with sub.open("rb") as stream:
            sub_is_tfrecord = looks_like_tfrecord(stream.read(12))
    if suspicious or sub_is_tfrecord:
        return (
            f" (--scenarios {' '.join(suspicious) or ' '.join(map(str, scenario_paths))} looks like a submission"
            f"{' and --submission like scenarios' if sub_is_tfrecord else ''}: "
            "are --scenarios and --submission swapped?)"
        )
    return ""


# --------------------------------------------------------------------------- the shared options


def worker_count(text: str) -> int:
    """`--workers N`: a whole number of processes, at least 1 (argparse's type: it names the option)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of processes (e.g. 4)") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give at least 1 process")
    return value


def size_in_bytes(text: str) -> int:
    """'4096', '512M', '40G', '1.5TiB' -> bytes (binary multiples), positive."""
    match = _SIZE.match(text)
    if not match:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size (e.g. 40G, 512M, 1048576)")
    unit = (match.group(2) or "").upper()[:1]
    value = int(float(match.group(1)) * _UNITS[unit])
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r}: the size must be positive")
    return value


def challenge_named(text: str) -> Challenge:
    """`--challenge NAME`: the `Challenge` it names (argparse's type: a bad name is refused naming the option)."""
    try:
        return as_challenge(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_challenge(parser: argparse.ArgumentParser, help_text: str, *, choices: tuple[str, ...] = ()) -> None:
    """`--challenge sim_agents|scenario_gen` (default sim_agents), a `Challenge` member once parsed;
    `choices`: more names the command takes beside the challenges' (kept as given, e.g. "both")."""
    parser.add_argument(
        "--challenge",
        type=(lambda text: text if text in choices else challenge_named(text)) if choices else challenge_named,
        default=choices[0] if choices else Challenge.SIM_AGENTS,
        metavar="|".join(choices + CHALLENGE_NAMES),
        help=help_text,
    )


def add_scenarios(parser: argparse.ArgumentParser, purpose: str = "", *, required: bool = True) -> None:
    """`--scenarios PATH...`: the scenario set (TFRecord files, folders or globs); `purpose` ends its help."""
    parser.add_argument(
        "--scenarios",
        nargs="+",
        required=required,
        metavar="PATH",
        help="scenario TFRecord files, folders or globs" + (f": {purpose}" if purpose else ""),
    )


def add_workers(parser: argparse.ArgumentParser, what: str, *, per_core: bool = False) -> None:
    """`--workers N` (at least 1): `what` the N processes of this machine do; by default 1, or with
    `per_core` this machine's cores, at most 4 (the commands that simulate)."""
    default = min(os.cpu_count() or 1, 4) if per_core else 1
    said = f"this machine's cores, at most 4: {default} here" if per_core else str(default)
    parser.add_argument(
        "--workers",
        type=worker_count,
        default=default,
        metavar="N",
        help=f"{what} (default {said}); the same results for any N",
    )


def add_engine(parser: argparse.ArgumentParser, ray_work: str) -> None:
    """`--engine local|ray` and `--ray-address`: where the work runs; `ray_work` says what a Ray task does."""
    parser.add_argument(
        "--engine",
        choices=Engine.names(),
        default=Engine.LOCAL.value,
        help=f"local (this machine, --workers processes; default) or ray (a Ray cluster: {ray_work}; needs "
        "`pip install 'wosac-eval[ray]'`); the same results",
    )
    parser.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="with --engine ray: the cluster to join (host:port or ray://host:10001; default $RAY_ADDRESS, "
        "else a local Ray is started)",
    )


def add_input_limits(parser: argparse.ArgumentParser, max_total_bytes: int, max_member_bytes: int) -> None:
    """`--max-bytes` and `--max-shard-bytes`: how far a submission may decompress (`parse.limits.InputLimits`,
    whose defaults the caller passes: this module does not load the parser's limits)."""
    parser.add_argument(
        "--max-bytes",
        type=size_in_bytes,
        default=max_total_bytes,
        metavar="SIZE",
        help=f"refuse a submission that decompresses past SIZE in total (default {_shown(max_total_bytes)})",
    )
    parser.add_argument(
        "--max-shard-bytes",
        type=size_in_bytes,
        default=max_member_bytes,
        metavar="SIZE",
        help=f"refuse a shard that decompresses past SIZE (default {_shown(max_member_bytes)})",
    )


def _shown(size: int) -> str:
    """A size as the options take it: 64G, 4G, 512M (bytes when it is no whole multiple)."""
    for unit in "TGMK":
        if size % _UNITS[unit] == 0:
            return f"{size // _UNITS[unit]}{unit}"
    return str(size)
