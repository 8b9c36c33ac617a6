"""Find, stream and index WOMD `Scenario` records in TFRecord shards.

Scenario inputs are given as files, folders or glob patterns
(`expand_scenario_paths`). `iter_scenarios` streams every scenario with where
it came from; `ScenarioIndex` makes one cheap pass to map scenario_id ->
(file, byte offset) and then loads single scenarios on demand, so scoring a
large submission never holds every scenario in memory.
"""

from __future__ import annotations

import glob
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import NamedTuple, Union

import numpy as np
from google.protobuf.message import DecodeError

from wosac_eval.parse import wire_walks
from wosac_eval.parse.decode import decode_message
from wosac_eval.parse.errors import (
    DuplicateScenarioError,
    ParseError,
    ScenarioPathError,
    UnknownScenarioError,
)
from wosac_eval.parse.tfrecord import iter_records, read_record_at
from wosac_eval.protos import scenario_pb2

PathLike = Union[str, "os.PathLike[str]"]

# Folder entries taken as scenario shards: WOMD names them
# `<split>.tfrecord-00000-of-00150`; plain `x.tfrecord` and `x.tfrecord.gz` match too.
SHARD_NAME_MARKER = ".tfrecord"

_GLOB_CHARS = frozenset("*?[")
_SCENARIO_ID_FIELD = scenario_pb2.Scenario.DESCRIPTOR.fields_by_name["scenario_id"].number


class ScenarioSource(NamedTuple):
    """Where one scenario record lives: the shard file and its header's byte offset."""

    path: Path
    offset: int

    def __str__(self) -> str:
        return f"{self.path} (record at byte offset {self.offset})"


class SourcedScenario(NamedTuple):
    """A parsed scenario and where it was read from."""

    scenario: scenario_pb2.Scenario
    source: ScenarioSource


def _as_list(paths: PathLike | Iterable[PathLike]) -> list[PathLike]:
    """Accept one path or an iterable of paths."""
    if isinstance(paths, (str, os.PathLike)):
        return [paths]
    return list(paths)


def _shards_in_folder(folder: Path) -> list[Path]:
    """The visible shard files directly inside folder, sorted by name."""
    return sorted(
        entry
        for entry in folder.iterdir()
        if entry.is_file() and not entry.name.startswith(".") and SHARD_NAME_MARKER in entry.name
    )


def _expand_one(entry: PathLike) -> list[Path]:
    """The shard files one path, folder or glob stands for (never empty)."""
    path = Path(entry)
    if path.is_file():
        return [path]
    if path.is_dir():
        shards = _shards_in_folder(path)
        if not shards:
            raise ScenarioPathError(
                f"{path}: folder holds no scenario shard (no file name containing {SHARD_NAME_MARKER!r})"
            )
        return shards
    if _GLOB_CHARS & set(str(entry)):
        matches = [Path(m) for m in sorted(glob.glob(str(entry), recursive=True))]
        files = [m for m in matches if m.is_file()]
        files += [s for m in matches if m.is_dir() for s in _shards_in_folder(m)]
        if not files:
            raise ScenarioPathError(f"{entry}: pattern matches no scenario file")
        return files
    raise ScenarioPathError(f"{entry}: no such file or folder")


def expand_scenario_paths(paths: PathLike | Iterable[PathLike]) -> list[Path]:
    """Turn files, folders and glob patterns into the list of shard files to read.

    A file is taken as is; a folder contributes its visible files whose name
    contains ".tfrecord" (not recursive), sorted; a pattern with * ? or [ is
    globbed (`**` recurses). Order follows the arguments; a file named twice
    is kept once. Raises ScenarioPathError for an argument that yields no file.
    """
    entries = _as_list(paths)
    if not entries:
        raise ScenarioPathError("no scenario path given")
    seen: set[Path] = set()
    expanded: list[Path] = []
    for entry in entries:
        for path in _expand_one(entry):
            key = path.resolve()
            if key not in seen:
                seen.add(key)
                expanded.append(path)
    return expanded


def parse_scenario(data: bytes, source: ScenarioSource | str) -> scenario_pb2.Scenario:
    """Parse one record as a Scenario, naming the source when it is not one."""
    try:
        scenario = decode_message(scenario_pb2.Scenario, data)
    except DecodeError as error:
        raise ParseError(f"{source}: not a valid Scenario message: {error}") from error
    # proto2 strings are not UTF-8-checked on parse; the runtime returns bytes then.
    if not isinstance(scenario.scenario_id, str):
        raise ParseError(f"{source}: scenario_id is not valid UTF-8 text")
    return scenario


def iter_scenarios(paths: PathLike | Iterable[PathLike]) -> Iterator[SourcedScenario]:
    """Yield (scenario, source) for every record of every shard, streaming.

    Paths are expanded with expand_scenario_paths. Corrupt framing raises
    CorruptRecordError, undecodable records ParseError, both naming file and offset.
    """
    for path in expand_scenario_paths(paths):
        for record in iter_records(path):
            source = ScenarioSource(path, record.offset)
            yield SourcedScenario(parse_scenario(record.data, source), source)


def read_scenarios(paths: PathLike | Iterable[PathLike]) -> Iterator[scenario_pb2.Scenario]:
    """Every `Scenario` of the TFRecord files, folders or globs, streamed (see `iter_scenarios`)."""
    for scenario, _ in iter_scenarios(paths):
        yield scenario


def scenario_id_of(data: bytes, source: ScenarioSource | str) -> str:
    """The scenario_id of a serialized Scenario, found by skimming its top-level fields.

    Much cheaper than a full parse (tracks and map are skipped, not decoded; a compiled walk,
    `wire_walks.message_spans`), which is what makes indexing many shards fast. The last
    occurrence wins, as in a full parse.
    """
    try:
        wire = np.frombuffer(data, np.uint8)
        starts, ends, _ = wire_walks.message_spans(wire, *wire_walks.whole(wire), _SCENARIO_ID_FIELD)
        found = data[starts[-1] : ends[-1]] if len(starts) else b""
        if not found:
            raise ValueError("no scenario_id")
        return found.decode("utf-8")
    except (ValueError, UnicodeDecodeError) as error:
        raise ParseError(f"{source}: not a valid Scenario message: {error}") from error


class ScenarioIndex:
    """scenario_id -> ScenarioSource for a set of shards, loading scenarios on demand.

    Building it reads every record once (CRC-checked) but decodes only each
    scenario_id; memory holds one small entry per scenario.
    """

    def __init__(self, paths: PathLike | Iterable[PathLike]) -> None:
        """Index every scenario in the shards that paths expand to.

        Raises DuplicateScenarioError naming both locations when a scenario_id
        occurs twice, and ParseError for unreadable records.
        """
        self._sources: dict[str, ScenarioSource] = {}
        self.paths = expand_scenario_paths(paths)
        for path in self.paths:
            for record in iter_records(path):
                source = ScenarioSource(path, record.offset)
                self._add(scenario_id_of(record.data, source), source)

    def _add(self, scenario_id: str, source: ScenarioSource) -> None:
        """Record where scenario_id lives, refusing a second location."""
        earlier = self._sources.get(scenario_id)
        if earlier is not None:
            raise DuplicateScenarioError(f"scenario {scenario_id!r} occurs twice: in {earlier} and in {source}")
        self._sources[scenario_id] = source

    def __len__(self) -> int:
        return len(self._sources)

    def __contains__(self, scenario_id: object) -> bool:
        return scenario_id in self._sources

    def __iter__(self) -> Iterator[str]:
        """Scenario ids in shard order."""
        return iter(self._sources)

    def ids(self) -> list[str]:
        """Scenario ids in shard order."""
        return list(self._sources)

    def source(self, scenario_id: str) -> ScenarioSource:
        """Where scenario_id lives; UnknownScenarioError if it is not indexed."""
        try:
            return self._sources[scenario_id]
        except KeyError:
            raise UnknownScenarioError(
                f"scenario {scenario_id!r} is not in the scenario files "
                f"({len(self.paths)} shard(s), {len(self)} scenario(s))"
            ) from None

    def load(self, scenario_id: str) -> scenario_pb2.Scenario:
        """Read and parse the one scenario with this id from its shard."""
        return self.load_with_bytes(scenario_id)[0]

    def load_with_bytes(self, scenario_id: str) -> tuple[scenario_pb2.Scenario, bytes]:
        """`load`, and the record's bytes the scenario was parsed from (`arrays.scenario.scenario_arrays`
        reads them instead of serialising the message again)."""
        data = self.load_record(scenario_id)
        return parse_scenario(data, self.source(scenario_id)), data

    def load_record(self, scenario_id: str) -> bytes:
        """The serialized scenario with this id, unparsed (`arrays.scenario.record_arrays` reads it)."""
        source = self.source(scenario_id)
        data = read_record_at(source.path, source.offset)
        found = scenario_id_of(data, source)
        if found != scenario_id:  # the shard changed since indexing
            raise ParseError(
                f"{source}: expected scenario {scenario_id!r}, found {found!r} (was the file modified after indexing?)"
            )
        return data

    __getitem__ = load
