"""Stored results: how a scored job's result document is kept on disk, and read back without
holding its per-scenario rows in memory.

A validation-size submission (44,097 scenarios) has a result document of about 150 MB, nearly all of
it the rows of `"scenarios": [...]` (~3.2 kB each). It is stored in two files of `results/`:

    <id>.rows.jsonl     one row per line, each `json.dumps(row)` (the text `json.dump` gives it inside
                        the whole document), in the document's order
    <id>.summary.json   {"format": "wosac-result/2", "rows": N, "rows_bytes": B, "row_offsets": [...],
                         "csv_fields": [...], "scenarios_at": i, "document": {everything but the rows}}

`row_offsets` holds the byte offset of every ROW_STRIDE-th row (a page seeks to its rows),
`csv_fields` the CSV columns (computed once, from every row), `scenarios_at` where the rows sit
among the document's keys (so the document is rebuilt in its own key order). The rows file is
written first, each file atomically (temp file, fsync, rename, fsync of the folder): the summary is
the commit, and a summary whose rows file is missing or of another size is a damaged result.

So the summary is read cheaply (the status and leaderboard never read either: they read the job
row), the whole document is streamed from the summary and the rows (`json.dump` text of the
document, byte for byte), the CSV row by row, and a page of rows by seeking.

Why two files rather than the one document streamed: the JSON alone could be sent from one file,
but the summary would cost a parse of the whole file (1.2-1.4 s for 44,097 rows), the CSV a pass
for its columns before its first byte, and a page a parse of every row before it. Writing the rows
one by one (`json.dumps` of each) is also faster than `json.dump` of the document (3.1 s against
5-7 s for 44,097 rows): `json.dump` encodes in Python, `json.dumps` in C.

Results stored before this format (one `<id>.json`, the whole document) are still served: the
document as stored, and its summary, pages and CSV by walking the file with the standard JSON
decoder one value at a time (`_JsonStream`), so their memory is bounded too (a pass over the file
per request).
"""

from __future__ import annotations

import codecs
import csv
import io
import json
import os
import re
from collections.abc import Iterable, Iterator
from itertools import islice
from pathlib import Path

from .jobs import fsync_dir

FORMAT = "wosac-result/2"
ROW_STRIDE = 1000  # row_offsets: the byte offset of every ROW_STRIDE-th row
MAX_PAGE = 1000  # rows in one page of /results/scenarios
CHUNK = 1 << 18  # bytes per piece of a streamed CSV answer, and of a single-file result's reads
# Bytes read per piece of the whole JSON: each reader holds a few pieces at once (the block read, its rows
# joined, the transport's copy), so ten readers of any result hold well under 1 MB more than one does
# (10.8 MiB for ten readers of a 1.1 MB result in pieces of 256 KiB; 2.6-3.1 MiB in all with 16 KiB).
JSON_PIECE = 1 << 14
MAX_VALUE_CHARS = 64 << 20  # the longest value (a row, `skipped`...) read from a single-file result


class ResultDamaged(Exception):
    """A stored result that cannot be read as written (a file missing, truncated or replaced)."""


def summary_path(results_dir: Path, job_id: str) -> Path:
    return results_dir / f"{job_id}.summary.json"


def rows_path(results_dir: Path, job_id: str) -> Path:
    return results_dir / f"{job_id}.rows.jsonl"


def legacy_path(results_dir: Path, job_id: str) -> Path:
    """The single-file result of a service before format 2 (the whole document)."""
    return results_dir / f"{job_id}.json"


# -- CSV: the per-scenario rows, `scenario_id` then every scalar field --------------------------
def csv_fields(rows: Iterable[dict]) -> list[str]:
    """The CSV columns after `scenario_id`: every field with a scalar value in some row, in the order
    they first appear."""
    fields: list[str] = []
    seen: set[str] = set()
    for s in rows:
        for k in s:
            if k not in seen and not isinstance(s[k], (dict, list)):
                fields.append(k)
                seen.add(k)
    if "scenario_id" in seen:
        fields.remove("scenario_id")
    return fields


def _csv_row(s: dict, fields: list[str]) -> list:
    return [s.get("scenario_id"), *(repr(s[k]) if isinstance(s.get(k), float) else s.get(k, "") for k in fields)]


def csv_chunks(fields: list[str], rows: Iterable[dict], size: int = CHUNK) -> Iterator[bytes]:
    """The CSV text of `rows` in pieces of about `size` bytes (the same text as `result_csv`)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["scenario_id", *fields])
    for s in rows:
        writer.writerow(_csv_row(s, fields))
        if out.tell() >= size:
            yield out.getvalue().encode()
            out.seek(0)
            out.truncate()
    if out.tell():
        yield out.getvalue().encode()


def result_csv(result: dict) -> str:
    """The CSV of a whole result document in memory (the service's CSV before streaming; kept for
    small documents and as the reference the streamed CSV is tested against)."""
    scenarios = result.get("scenarios") or []
    fields: list[str] = []
    for s in scenarios:
        for k in s:
            if k not in fields and not isinstance(s[k], (dict, list)):
                fields.append(k)
    if "scenario_id" in fields:
        fields.remove("scenario_id")
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["scenario_id", *fields])
    for s in scenarios:
        writer.writerow(
            [s.get("scenario_id"), *(repr(s[k]) if isinstance(s.get(k), float) else s.get(k, "") for k in fields)]
        )
    return out.getvalue()


# -- writing ----------------------------------------------------------------------------------
def _dumps(value) -> str:
    return json.dumps(value, allow_nan=True)  # what json.dump(..., allow_nan=True) writes of it


def _replace_atomically(tmp: Path, path: Path) -> None:
    os.replace(tmp, path)
    fsync_dir(path.parent)


def write_result(results_dir: Path, job_id: str, result: dict) -> None:
    """Store a result document: its rows (one a line), then its summary, each atomically."""
    rows = result.get("scenarios")
    if not isinstance(rows, list):  # no rows to keep apart: the whole document is the summary
        rows, at = [], None
    else:
        at = list(result).index("scenarios")
    rows_file, tmp_suffix = rows_path(results_dir, job_id), f".{os.getpid()}.tmp"
    tmp = rows_file.with_name(rows_file.name + tmp_suffix)
    offsets: list[int] = []
    written = 0
    try:
        with open(tmp, "wb") as f:
            for i, row in enumerate(rows):
                if i % ROW_STRIDE == 0:
                    offsets.append(written)
                line = (_dumps(row) + "\n").encode()
                f.write(line)
                written += len(line)
            f.flush()
            os.fsync(f.fileno())
        _replace_atomically(tmp, rows_file)
    finally:
        tmp.unlink(missing_ok=True)
    summary = {
        "format": FORMAT,
        "rows": len(rows),
        "rows_bytes": written,
        "row_offsets": offsets,
        "csv_fields": csv_fields(rows),
        "scenarios_at": at,
        "document": {k: v for k, v in result.items() if at is None or k != "scenarios"},
    }
    path = summary_path(results_dir, job_id)
    tmp = path.with_name(path.name + tmp_suffix)
    try:
        with open(tmp, "w") as f:
            json.dump(summary, f, allow_nan=True)
            f.flush()
            os.fsync(f.fileno())
        _replace_atomically(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    legacy_path(results_dir, job_id).unlink(missing_ok=True)  # an earlier attempt's, by a service before format 2


# -- reading ----------------------------------------------------------------------------------
_SUMMARY_KEYS = {"rows", "rows_bytes", "row_offsets", "csv_fields", "scenarios_at", "document"}


def open_result(results_dir: Path, job_id: str) -> StoredResult | None:
    """The stored result of a job (format 2, else the single file of earlier services), opened: its
    files stay readable through the returned object whatever happens to their names. None when
    there is none; ResultDamaged when it cannot be read as written."""
    try:
        summary_file = open(summary_path(results_dir, job_id), "rb")  # noqa: SIM115 - closed by the `with` below
    except FileNotFoundError:
        try:
            return LegacyResult(open(legacy_path(results_dir, job_id), "rb"))
        except FileNotFoundError:
            return None
    with summary_file:
        try:
            summary = json.load(summary_file)
        except ValueError as exc:
            raise ResultDamaged(f"unreadable summary ({exc})") from None
    if not isinstance(summary, dict) or summary.get("format") != FORMAT:
        raise ResultDamaged(f"unknown result format {summary.get('format') if isinstance(summary, dict) else None!r}")
    if not set(summary) >= _SUMMARY_KEYS:
        raise ResultDamaged(f"its summary lacks {sorted(_SUMMARY_KEYS - set(summary))}")
    try:
        rows_file = open(rows_path(results_dir, job_id), "rb")  # noqa: SIM115 - kept open by the returned result
    except FileNotFoundError:
        raise ResultDamaged("its rows file is missing") from None
    size = os.fstat(rows_file.fileno()).st_size
    if size != summary["rows_bytes"]:
        rows_file.close()
        raise ResultDamaged(f"its rows file holds {size} bytes, not the {summary['rows_bytes']} written")
    return SplitResult(summary, rows_file)


class StoredResult:
    """A stored result, opened. Every method reads the files afresh, in bounded memory."""

    def summary(self) -> dict:
        """The document without its rows, its keys in their order."""
        raise NotImplementedError

    def json_size(self) -> int | None:
        """The length of `json_chunks()`'s text, when known beforehand."""
        return None

    def json_chunks(self) -> Iterator[bytes]:
        """The whole document's JSON text, in pieces."""
        raise NotImplementedError

    def page(self, offset: int, limit: int) -> tuple[int, list[str]]:
        """(the number of rows, the JSON text of rows offset .. offset+limit-1)."""
        raise NotImplementedError

    def csv(self) -> Iterator[bytes]:
        """The CSV, in pieces; call it before answering: a result found damaged raises here."""
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class SplitResult(StoredResult):
    """Format 2: the summary (read) and the rows file (open)."""

    def __init__(self, meta: dict, rows_file):
        self.meta, self.rows_file = meta, rows_file

    def summary(self) -> dict:
        return self.meta["document"]

    def _around_rows(self) -> tuple[bytes, bytes]:
        """The document's text before its first row and after its last."""
        items = [f"{_dumps(k)}: {_dumps(v)}" for k, v in self.meta["document"].items()]
        at = self.meta["scenarios_at"]
        if at is None:
            return ("{" + ", ".join(items) + "}").encode(), b""
        head = "{" + "".join(item + ", " for item in items[:at]) + '"scenarios": ['
        tail = "]" + "".join(", " + item for item in items[at:]) + "}"
        return head.encode(), tail.encode()

    def json_size(self) -> int:
        head, tail = self._around_rows()
        n = self.meta["rows"]
        # each row's newline goes, and ", " stands between rows
        return len(head) + self.meta["rows_bytes"] - n + 2 * max(n - 1, 0) + len(tail)

    def json_chunks(self) -> Iterator[bytes]:
        head, tail = self._around_rows()
        yield head
        f, rest, first = self.rows_file, b"", True
        f.seek(0)
        while block := f.read(JSON_PIECE):
            block = rest + block
            cut = block.rfind(b"\n") + 1
            block, rest = block[:cut], block[cut:]
            if block:
                yield (b"" if first else b", ") + block[:-1].replace(b"\n", b", ")
                first = False
        if rest:
            raise ResultDamaged("its rows file ends inside a row")
        yield tail

    def _lines(self, offset: int) -> Iterator[bytes]:
        """The rows' lines from row `offset` on (each with its newline)."""
        n = self.meta["rows"]
        if offset >= n:
            return
        f = self.rows_file
        f.seek(self.meta["row_offsets"][offset // ROW_STRIDE])
        for _ in range(offset % ROW_STRIDE):
            f.readline()
        for _ in range(n - offset):
            line = f.readline()
            if not line.endswith(b"\n"):
                raise ResultDamaged("its rows file ends early")
            yield line

    def rows(self, offset: int = 0) -> Iterator[dict]:
        return (json.loads(line) for line in self._lines(offset))

    def page(self, offset: int, limit: int) -> tuple[int, list[str]]:
        return self.meta["rows"], [line[:-1].decode() for line in islice(self._lines(offset), limit)]

    def csv(self) -> Iterator[bytes]:
        return csv_chunks(self.meta["csv_fields"], self.rows())

    def close(self) -> None:
        self.rows_file.close()


class LegacyResult(StoredResult):
    """The single `<id>.json` of earlier services: served as it is; its summary, pages and CSV walk it."""

    def __init__(self, file):
        self.file = file

    def _walk(self) -> Iterator[tuple[str, object]]:
        self.file.seek(0)
        return _walk_document(_JsonStream(self.file))

    def summary(self) -> dict:
        return {key: value for key, value in self._walk() if not isinstance(value, _Rows)}  # rows skipped

    def json_size(self) -> int:
        return os.fstat(self.file.fileno()).st_size

    def json_chunks(self) -> Iterator[bytes]:
        self.file.seek(0)
        while block := self.file.read(CHUNK):
            yield block

    def page(self, offset: int, limit: int) -> tuple[int, list[str]]:
        total = None
        for key, value in self._walk():
            if key == "num_scenarios" and type(value) is int:
                total = value  # result_document's len(scenarios), written before them: no count needed
            if isinstance(value, _Rows):
                page = [_dumps(row) for row in islice(value, offset, offset + limit)]
                if total is None:
                    for _ in value:
                        pass
                    total = value.count
                return total, page
        return 0, []

    def csv(self) -> Iterator[bytes]:
        fields = csv_fields(self._rows())  # a first pass for the columns (a damaged file raises here)
        return csv_chunks(fields, self._rows())

    def _rows(self) -> Iterator[dict]:
        for _, value in self._walk():
            if isinstance(value, _Rows):
                yield from value
                return

    def close(self) -> None:
        self.file.close()


# -- one JSON document read one value at a time ---------------------------------------------------
_SPACE = re.compile(r"[ \t\n\r]*")


class _JsonStream:
    """A JSON text read from a binary file in chunks; each value is decoded whole by the standard
    decoder (exactly as `json.load` would: NaN and Infinity included), so memory holds one value and
    a chunk, not the document."""

    def __init__(self, file, chunk: int = CHUNK):
        self.file, self.chunk = file, chunk
        self.text, self.pos, self.eof = "", 0, False
        self.utf8 = codecs.getincrementaldecoder("utf-8")()
        self.decoder = json.JSONDecoder()

    def _more(self, at_least: int = 0) -> bool:
        if self.eof:
            return False
        data = self.file.read(max(self.chunk, at_least))
        self.text = self.text[self.pos :] + self.utf8.decode(data, final=not data)
        self.pos = 0
        self.eof = not data
        return bool(data)

    def peek(self) -> str:
        """The next character that is not white space ('' at the end)."""
        while True:
            space = _SPACE.match(self.text, self.pos)
            assert space is not None  # `*`: it matches, if only the empty string
            self.pos = space.end()
            if self.pos < len(self.text):
                return self.text[self.pos]
            if not self._more():
                return ""

    def take(self, expected: str) -> str:
        got = self.peek()
        if got not in expected or not got:
            raise ResultDamaged(f"expected one of {expected!r} in the result file, found {got!r}")
        self.pos += 1
        return got

    def value(self):
        self.peek()
        while True:
            try:
                value, end = self.decoder.raw_decode(self.text, self.pos)
            except json.JSONDecodeError as exc:
                # Mostly a value that goes on in the next chunk: read at least as much again (so a long
                # value costs a few decodes, not one per chunk).
                pending = len(self.text) - self.pos
                if pending <= MAX_VALUE_CHARS and self._more(pending):
                    continue
                raise ResultDamaged(f"the result file is not JSON ({exc.msg})") from None
            if end == len(self.text) and self._more():
                continue  # a number may go on in the next chunk
            self.pos = end
            return value


class _Rows:
    """The items of the `scenarios` array, read one by one as they are asked for."""

    def __init__(self, stream: _JsonStream):
        self.stream, self.count, self.done = stream, 0, False
        stream.take("[")
        if stream.peek() == "]":
            stream.take("]")
            self.done = True

    def __iter__(self):
        return self

    def __next__(self):
        if self.done:
            raise StopIteration
        row = self.stream.value()
        self.count += 1
        if self.stream.take(",]") == "]":
            self.done = True
        return row


def _walk_document(stream: _JsonStream) -> Iterator[tuple[str, object]]:
    """(key, value) of the top-level object in order; the value of `scenarios` (an array) is a `_Rows`,
    whose rest is skipped when the walk goes on."""
    stream.take("{")
    if stream.peek() == "}":
        return
    while True:
        key = stream.value()
        stream.take(":")
        if key == "scenarios" and stream.peek() == "[":
            rows = _Rows(stream)
            yield key, rows
            for _ in rows:
                pass
        else:
            yield key, stream.value()
        if stream.take(",}") == "}":
            return
