"""Per-object output of a scoring run: the side file beside the result (`score --per-object`).

A validation-size submission has about 44,097 scenes and a million evaluated objects: their values
are never held together. Each scored row carries its scenario's `objects` (`scoring.scenario.
object_records`) only while in flight; the scoring loop records the row in the run's journal
(`scoring.journal`, a temporary one when the run has none) and keeps the row without them. Once
every scenario is scored, `write_objects` streams them, scenario by scenario in the result's order,
from the journal into the side file:

- `R.objects.jsonl`: one JSON object per line, per evaluated object (`object_records`' keys);
- `R.objects.parquet`: the same columns (needs `pyarrow`), written in row groups.

An interrupted run resumes from its journal, which holds the objects of the rows it finished: the
side file is then the one an uninterrupted run writes, byte for byte. The result document says where
it is: `"per_object": {"objects": "R.objects.jsonl", "format": "jsonl", "num_objects": N}` (a file name,
beside the result). `read_objects` reads either format back, one record at a time.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from wosac_eval.metrics.per_object import EVENTS
from wosac_eval.metrics.registry import LIKELIHOOD_FIELDS

FORMATS = {".jsonl": "jsonl", ".parquet": "parquet"}
PARQUET_ROWS = 65_536  # objects per Parquet row group (bounded memory)


def objects_path_for(result_path: os.PathLike | str, fmt: str = "jsonl") -> Path:
    """The side file of a result: `R.objects.jsonl` (or `.parquet`) beside `R.json`."""
    result_path = Path(result_path)
    stem = result_path.name[: -len(result_path.suffix)] if result_path.suffix else result_path.name
    return result_path.with_name(f"{stem}.objects.{fmt}")


def format_of(path: os.PathLike | str) -> str:
    """ "jsonl" or "parquet", from the suffix; ValueError for another one."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"{path}: the per-object file's suffix chooses its format: {', '.join(FORMATS)}")
    return FORMATS[suffix]


def count_column(field: str) -> str:
    return field.removesuffix("_likelihood") + "_count"


def columns() -> dict[str, str]:
    """Column -> type ("string", "int", "float") of a per-object record, in record order."""
    out = {"scenario_id": "string", "object_id": "int", "object_type": "string"}
    for field in LIKELIHOOD_FIELDS:
        out[field] = "float"
        out[count_column(field)] = "int"
    out["num_rollouts"] = "int"
    for event in EVENTS:
        out[f"{event}_rollouts"] = "int"
        out[f"{event}_first_step"] = "int"
    return out


def _parquet_schema() -> Any:
    import pyarrow

    kinds = {"string": pyarrow.string(), "int": pyarrow.int64(), "float": pyarrow.float64()}
    return pyarrow.schema([(name, kinds[kind]) for name, kind in columns().items()])


def write_objects(scenarios: Iterable[list[dict] | None], path: os.PathLike | str) -> int:
    """Streams every scenario's objects (None: a scenario without) into `path` (its suffix chooses the
    format), through a temporary file renamed over it; returns the number of objects written."""
    path = Path(path)
    fmt = format_of(path)
    temp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    written = 0
    try:
        if fmt == "jsonl":
            with open(temp, "wb") as f:
                for objects in scenarios:
                    if objects:
                        f.write(b"".join(json.dumps(o).encode() + b"\n" for o in objects))
                        written += len(objects)
                f.flush()
                os.fsync(f.fileno())
        else:
            import pyarrow
            import pyarrow.parquet

            schema = _parquet_schema()
            batch: list[dict] = []
            with pyarrow.parquet.ParquetWriter(temp, schema) as writer:
                for objects in scenarios:
                    batch.extend(objects or ())
                    if len(batch) >= PARQUET_ROWS:
                        writer.write_table(pyarrow.Table.from_pylist(batch, schema=schema))
                        written += len(batch)
                        batch = []
                if batch or not written:
                    writer.write_table(pyarrow.Table.from_pylist(batch, schema=schema))
                    written += len(batch)
        os.replace(temp, path)
    finally:
        temp.unlink(missing_ok=True)
    return written


def read_objects(path: os.PathLike | str) -> Iterator[dict]:
    """The records of a per-object file (`.jsonl` or `.parquet`), one at a time, in file order."""
    fmt = format_of(path)
    if fmt == "jsonl":
        with open(path, "rb") as f:
            for line in f:
                if line.strip():
                    yield json.loads(line)
        return
    import pyarrow.parquet

    parquet = pyarrow.parquet.ParquetFile(path)
    for group in range(parquet.num_row_groups):
        yield from parquet.read_row_group(group).to_pylist()


def objects_file_of(result: dict, result_path: os.PathLike | str) -> Path | None:
    """The per-object file a result document refers to (beside the result), or None if it has none."""
    entry = result.get("per_object") if isinstance(result, dict) else None
    if not isinstance(entry, dict) or not isinstance(entry.get("objects"), str):
        return None
    return Path(result_path).parent / entry["objects"]
