"""The journal of a scoring run: finished scenarios' rows, so that an interrupted run resumes.

A whole validation set takes tens of minutes; a Ctrl-C, an OOM kill or a lost node
near the end must not cost the run. `score_submission(..., journal=PATH)` appends
each finished scenario's row to PATH as one JSON line, flushed as it is scored. A
later run with the same inputs skips those scenarios and assembles the same result
document (rows are journaled before the set-wide analysis completes them, and JSON
keeps every float exactly: `repr` round-trips).

    {"journal": "wosac-eval scoring", "version": 1, "run": {<what the rows depend on>}}
    {"scenario_id": "...", <the scenario's row>}
    ...

With per-object values (`score_submission(per_object=True)`), each row carries its scenario's
`objects` in the journal: they are not kept in memory (a validation set has about a million), only
where each row's line starts, and `objects_of` reads one scenario's back when the side file is written
(`scoring.objects`), for the rows of this run and of an earlier one alike.

The first line names the run: the challenge, the config (its bytes' digest), the
options that change rows, the package version, and the size and modification time
of every input file. A journal of another run is set aside (its rows would not
belong to this one) and the run starts afresh, saying why. A line cut short by a
kill is dropped; so is everything after a line that does not parse.

Validation is kept too (PATH.validated: the report and where each scenario lies in
the submission, written once validation has passed): a resumed run does not check
a 20 GB submission again, which would cost a quarter of the whole run. It is our
own pickle, next to the journal and trusted as the journal is, and used only under
the same run identity.

An archive's last members are kept too (PATH.members: as many bytes as the archive
itself, less if the disk is short): the stages after validation read them from
their files, and a run resumed late decompresses the archive only up to them
(a gzip stream cannot be entered midway: it would otherwise decompress all that
was scored before the interruption again).
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import pickle
import shutil
import time
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

from wosac_eval import __version__

if TYPE_CHECKING:  # what `submission` passes in; imported here they would load the parse, validate and scoring rooms
    from wosac_eval.parse.shard_walk import ShardRef
    from wosac_eval.scoring.evaluation import Evaluation
    from wosac_eval.validate.findings import ValidationReport

MAGIC = "wosac-eval scoring"
VERSION = 1
FSYNC_EVERY_S = 2.0  # a kill loses nothing flushed; a power cut at most this much
log = logging.getLogger(__name__)


def _file_stats(path: Path) -> list:
    """[relative name, size, mtime_ns] of a file, or of every file under a folder (sorted)."""
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.is_file())
        return [[str(p.relative_to(path)), *_size_mtime(p)] for p in files]
    return [[path.name, *_size_mtime(path)]]


def _size_mtime(path: Path) -> list[int]:
    stat = path.stat()
    return [stat.st_size, stat.st_mtime_ns]


def run_identity(
    evaluation: Evaluation, submission_path: os.PathLike | str, scenario_paths: Iterable[os.PathLike]
) -> dict:
    """What a run's rows depend on: equal identities give equal rows (the JSON-ready dict)."""
    return {
        # Rows with their objects (absent: as before). Where the objects are written is not the rows' matter.
        **({"per_object": True} if evaluation.options.per_object else {}),
        "package": __version__,
        "challenge": evaluation.challenge.value,
        "config": evaluation.config_name,
        "config_sha256": hashlib.sha256(evaluation.config.SerializeToString(deterministic=True)).hexdigest(),
        "analysis": evaluation.options.analysis,
        "select": evaluation.options.select,
        "allow_partial": evaluation.options.allow_partial,
        "metadata_checks": evaluation.options.metadata_checks,
        "submission": [str(Path(submission_path).resolve()), _file_stats(Path(submission_path))],
        "scenarios": [[str(Path(p).resolve()), *_size_mtime(Path(p))] for p in scenario_paths],
    }


class JournalDamaged(ValueError):
    """A journal of this run holding a record that is no scored scenario's row of it: damaged or altered."""


def _checked_row(row: object, path: Path, number: int, keys: frozenset | None) -> dict:
    """`row`, the record on line `number`, once it is a scored scenario's row like the run's others (a
    scenario id, a meta-metric, the same fields as the first); else JournalDamaged saying what to do."""
    why = None
    if not isinstance(row, dict):
        why = f"a {type(row).__name__}, not a row"
    elif not isinstance(row.get("scenario_id"), str):
        why = "no scenario_id"
    elif not isinstance(row.get("metametric"), (int, float)) or isinstance(row.get("metametric"), bool):
        why = f"scenario {row['scenario_id']!r} without a meta-metric"
    elif keys is not None and frozenset(row) != keys:
        why = f"scenario {row['scenario_id']!r} with other fields than the rows before it"
    if why is None:
        return row  # type: ignore[return-value]  # a dict, checked above
    raise JournalDamaged(
        f"the journal {path} holds a record that is not a scored scenario of this run (line {number}: {why}): "
        "it was damaged or altered since the run wrote it. Run the same command with --restart to score "
        "everything again (or delete the journal)"
    )


def _read(path: Path, identity: dict, offsets: dict[str, int]) -> tuple[dict[str, dict], int, str | None]:
    """(rows by scenario id, bytes of the file that hold them, why the journal was not used or None).

    A row's `objects` are left in the file: `offsets` gets where its line starts. JournalDamaged for a
    record of this run's journal that is not one of its rows."""
    rows: dict[str, dict] = {}
    good = 0
    with open(path, "rb") as f:
        header = f.readline()
        try:
            head = json.loads(header) if header.endswith(b"\n") else None
        except ValueError:
            head = None
        if not isinstance(head, dict) or head.get("journal") != MAGIC:
            return {}, 0, "it is not a scoring journal"
        if head.get("version") != VERSION or head.get("run") != identity:
            return {}, 0, "it was written by another run (other inputs, config, options or version)"
        good = len(header)
        keys = None
        for number, line in enumerate(f, start=2):
            if not line.endswith(b"\n"):
                break  # cut short by a kill
            try:
                record = json.loads(line)
            except ValueError:
                break
            objects = record.pop("objects", None) if isinstance(record, dict) else None
            row = _checked_row(record, path, number, keys)
            keys = frozenset(row)
            if objects is not None:
                offsets[row["scenario_id"]] = good
            rows[row["scenario_id"]] = row
            good += len(line)
    return rows, good, None


class ScoringJournal:
    """An open journal: the rows it already held (`done`), and `record` for new ones.

    Args:
      path: the journal file (created if missing).
      identity: `run_identity(...)` of this run.
    Attributes:
      done: scenario_id -> row of the scenarios a previous run finished.
        (without their `objects`: `objects_of` reads them).
      set_aside: where a journal of another run was moved (None if none was).
      reason: why it was set aside.
    """

    def __init__(self, path: os.PathLike | str, identity: dict) -> None:
        self.path = Path(path)
        self.identity = identity
        self.done: dict[str, dict] = {}
        self.set_aside: Path | None = None
        self.reason: str | None = None
        self._offsets: dict[str, int] = {}  # scenario id -> where its row's line starts (rows with objects)
        self._reader: BinaryIO | None = None
        good = 0
        if self.path.exists():
            self.done, good, self.reason = _read(self.path, identity, self._offsets)
            if self.reason is not None:
                self._offsets.clear()
                self.set_aside = self.path.with_name(self.path.name + ".old")
                os.replace(self.path, self.set_aside)
                log.warning(
                    "%s was set aside as %s and the run starts afresh: %s", self.path, self.set_aside, self.reason
                )
        if not good:  # a validation kept beside rows that are gone (or of another run) is not this run's
            validated_path(self.path).unlink(missing_ok=True)
        self._file = open(self.path, "r+b" if good else "wb")  # noqa: SIM115 - closed by close()
        if good:
            self._file.truncate(good)  # drop a torn last line before appending after it
            self._file.seek(good)
        else:
            header = {"journal": MAGIC, "version": VERSION, "run": identity}
            self._file.write(json.dumps(header).encode() + b"\n")
            self._sync()
        self._synced_at = time.monotonic()

    def record(self, rows: Iterable[dict]) -> None:
        """Append finished scenarios' rows (each a result row with its `scenario_id`, and its `objects`
        with per-object values)."""
        at = self._file.tell()
        lines = []
        for row in rows:
            line = json.dumps(row).encode() + b"\n"
            if "objects" in row:
                self._offsets[row["scenario_id"]] = at
            at += len(line)
            lines.append(line)
        self._file.write(b"".join(lines))
        self._file.flush()  # in the kernel now: a killed process loses none of it
        if time.monotonic() - self._synced_at > FSYNC_EVERY_S:
            self._sync()

    def objects_of(self, scenario_id: str) -> list[dict] | None:
        """The `objects` of a recorded row (read back from the file), or None if it has none."""
        at = self._offsets.get(scenario_id)
        if at is None:
            return None
        if self._reader is None:
            self._file.flush()
            self._reader = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        self._reader.seek(at)
        return json.loads(self._reader.readline())["objects"]

    def validation(self) -> tuple | None:
        """(report, submission records) an earlier run of this identity kept (`keep_validation`), or None."""
        try:
            with open(validated_path(self.path), "rb") as f:
                kept = pickle.load(f)
        except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError, TypeError, ValueError):
            return None  # none, cut short, or of another version: validate again
        if not isinstance(kept, dict) or kept.get("run") != self.identity:
            return None
        return kept["report"], kept["records"]

    def keep_validation(
        self, report: ValidationReport, records: list[tuple[ShardRef, list[tuple[str, tuple[int, int]]]]]
    ) -> None:
        """Keep a passed validation (its report and `SubmissionSource.records()`) for a resumed run."""
        path = validated_path(self.path)
        temp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(temp, "wb") as f:
            pickle.dump(
                {"run": self.identity, "report": report, "records": records}, f, protocol=pickle.HIGHEST_PROTOCOL
            )
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, path)

    def _sync(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())
        self._synced_at = time.monotonic()

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None
        if not self._file.closed:
            self._sync()
            self._file.close()

    def remove(self) -> None:
        """The run finished and its result is written: the journal is no longer needed."""
        self.close()
        remove_journal(self.path)

    def __enter__(self) -> ScoringJournal:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def validated_path(journal: os.PathLike | str) -> Path:
    """Where a journal keeps its run's validation."""
    return Path(journal).with_name(Path(journal).name + ".validated")


def members_path(journal: os.PathLike | str) -> Path:
    """Where a journal keeps its run's last archive members (`SubmissionSource(tail_dir=...)`)."""
    return Path(journal).with_name(Path(journal).name + ".members")


def members_budget(submission: os.PathLike | str, journal: os.PathLike | str) -> int:
    """How many bytes of an archive's last members a journal keeps: the archive's own size (about the last
    40% of a gzip-compressed submission), at most half the free space beside the journal."""
    folder = Path(journal).resolve().parent
    try:
        size = os.path.getsize(submission) if Path(submission).is_file() else 0
        free = shutil.disk_usage(folder).free
    except OSError:
        return 0
    return min(size, free // 2)


def remove_journal(journal: os.PathLike | str) -> None:
    """Remove a journal and what it keeps beside it (its validation and archive members, a journal of
    another run set aside)."""
    journal = Path(journal)
    # The journal goes last: its absence then means nothing of the run is left beside it (a reader that waits
    # for it to go sees the folder clean), and a crash midway leaves a journal that resumes, never files
    # without their journal.
    for path in (validated_path(journal), journal.with_name(journal.name + ".old")):
        path.unlink(missing_ok=True)
    shutil.rmtree(members_path(journal), ignore_errors=True)
    journal.unlink(missing_ok=True)
