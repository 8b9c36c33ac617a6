"""What every command shares before its work starts: usage errors and output paths checked up front.

A usage error is the user's to fix (a missing folder, an output that cannot be
written, swapped arguments); the command line prints it as one line and exits 2
before any long work, so an hour of scoring is never lost to a typo in `-o`.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path


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


def _probe_create(target: Path, path, option: str) -> None:
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


def scenario_set_hint(scenario_paths, submission: str | os.PathLike) -> str:
    """' (...swapped?)' when the scenario paths look like a submission and the submission like scenarios."""
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
