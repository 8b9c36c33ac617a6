"""A scene's objects out of a job's per-object file, without reading the whole file.

The worker scores with `per_object=True`: the library writes `results/<id>.objects.jsonl`, one record a
line per evaluated object, grouped by scene in the result's order (`wosac_eval.scoring.objects`; a
validation-size one holds about a million objects). After scoring, one pass over it writes
`results/<id>.objects.idx`: N+1 little-endian uint64 byte offsets, row i's objects being the bytes
[offset[i], offset[i+1]) (empty for a scene without evaluated objects). A scene page then reads 16
bytes of the index and its scene's few lines; its worst objects come from
`wosac_eval.results.worst_objects.scene_worst_objects`.
"""

from __future__ import annotations

import json
import os
import struct
import sys
from array import array
from pathlib import Path

_PREFIX = b'{"scenario_id": '
_DECODER = json.JSONDecoder()


def _scenario_of(line: bytes) -> str:
    """The record's scenario id: the library writes it first, so only that string is decoded."""
    if line.startswith(_PREFIX):
        text = line[len(_PREFIX) : len(_PREFIX) + 512].decode("utf-8", "replace")
        value, _ = _DECODER.raw_decode(text)
        return value
    return json.loads(line)["scenario_id"]


def write_index(objects: Path, scenario_ids: list[str], index: Path) -> None:
    """Index `objects` by the result's rows (`scenario_ids`, in the result's order); atomically.

    Raises ValueError when the file is not grouped by scene in that order.
    """
    offsets = array("Q")
    row, position = 0, 0
    current = None
    with open(objects, "rb") as f:
        for line in f:
            sid = _scenario_of(line) if line.strip() else current
            if sid != current:
                # Rows before this scene's without objects start (and end) here.
                while row < len(scenario_ids) and scenario_ids[row] != sid:
                    offsets.append(position)
                    row += 1
                if row == len(scenario_ids):
                    raise ValueError(f"{objects.name}: scenario {sid!r} is not a row of the result, or out of order")
                offsets.append(position)
                row += 1
                current = sid
            position += len(line)
    while len(offsets) < len(scenario_ids) + 1:
        offsets.append(position)
    if offsets.itemsize != 8:  # pragma: no cover (array 'Q' is 8 bytes on every platform we run on)
        raise RuntimeError("array('Q') is not 8 bytes here")
    if sys.byteorder != "little":  # pragma: no cover
        offsets.byteswap()
    temp = index.with_name(f"{index.name}.{os.getpid()}.tmp")
    try:
        with open(temp, "wb") as f:
            offsets.tofile(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(temp, index)
    finally:
        temp.unlink(missing_ok=True)


def scene_records(objects: Path, index: Path, row: int) -> list[dict] | None:
    """The per-object records of result row `row`; None when the job has no per-object files (scored by
    an earlier version) or the row is past the index."""
    try:
        with open(index, "rb") as f:
            f.seek(8 * row)
            pair = f.read(16)
        if len(pair) != 16:
            return None
        start, end = struct.unpack("<QQ", pair)
        with open(objects, "rb") as f:
            f.seek(start)
            chunk = f.read(max(0, end - start))
    except FileNotFoundError:
        return None
    return [json.loads(line) for line in chunk.splitlines() if line.strip()]
