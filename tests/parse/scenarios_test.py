"""Scenario path expansion, streaming and the on-demand ScenarioIndex."""

from __future__ import annotations

from pathlib import Path

import pytest

from wosac_eval.parse.errors import (
    DuplicateScenarioError,
    ParseError,
    ScenarioPathError,
    UnknownScenarioError,
)
from wosac_eval.parse.scenarios import (
    ScenarioIndex,
    ScenarioSource,
    expand_scenario_paths,
    iter_scenarios,
    scenario_id_of,
)
from wosac_eval.parse.tfrecord import iter_records, write_records
from wosac_eval.protos import scenario_pb2

from support.paths import SHARED


def small_scenario(scenario_id: str, num_tracks: int = 2) -> scenario_pb2.Scenario:
    """A tiny but well-formed scenario with a few tracks and one map feature."""
    scenario = scenario_pb2.Scenario(scenario_id=scenario_id, current_time_index=1, timestamps_seconds=[0.0, 0.1, 0.2])
    for track_id in range(num_tracks):
        track = scenario.tracks.add(id=track_id, object_type=scenario_pb2.Track.TYPE_VEHICLE)
        for step in range(3):
            track.states.add(center_x=float(step), center_y=float(track_id), valid=True)
    scenario.map_features.add(id=5).road_edge.polyline.add(x=1.0, y=2.0)
    return scenario


def write_shard(path: Path, ids: list[str]) -> Path:
    """Write one TFRecord shard holding a small scenario per id."""
    write_records(path, [small_scenario(i).SerializeToString() for i in ids])
    return path


@pytest.fixture
def shard_folder(tmp_path):
    """A folder with two shards, a README and a hidden file."""
    folder = tmp_path / "scenarios"
    folder.mkdir()
    write_shard(folder / "validation.tfrecord-00001-of-00002", ["c", "d"])
    write_shard(folder / "validation.tfrecord-00000-of-00002", ["a", "b"])
    (folder / "README.md").write_text("not a shard")
    (folder / ".validation.tfrecord.partial").write_bytes(b"junk")
    return folder


def test_folder_expands_to_sorted_shards_only(shard_folder):
    names = [p.name for p in expand_scenario_paths(shard_folder)]
    assert names == ["validation.tfrecord-00000-of-00002", "validation.tfrecord-00001-of-00002"]


def test_files_globs_and_duplicates(shard_folder, tmp_path):
    first = shard_folder / "validation.tfrecord-00000-of-00002"
    expanded = expand_scenario_paths([str(first), str(shard_folder / "*-00001-*"), first])
    assert [p.name for p in expanded] == [first.name, "validation.tfrecord-00001-of-00002"]
    recursive = expand_scenario_paths(str(tmp_path / "**" / "*.tfrecord-*"))
    assert len(recursive) == 2
    # A file given explicitly is taken whatever its name.
    assert expand_scenario_paths(shard_folder / "README.md") == [shard_folder / "README.md"]


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: d / "missing.tfrecord", "no such file or folder"),
        (lambda d: d / "nothing-*.tfrecord", "pattern matches no scenario file"),
        (lambda d: d / "empty", "folder holds no scenario shard"),
    ],
)
def test_paths_that_name_nothing_are_errors(tmp_path, make, message):
    (tmp_path / "empty").mkdir()
    target = make(tmp_path)
    with pytest.raises(ScenarioPathError, match=message) as caught:
        expand_scenario_paths(target)
    assert str(target) in str(caught.value)
    with pytest.raises(ScenarioPathError, match="no scenario path given"):
        expand_scenario_paths([])


def test_iter_scenarios_streams_every_record_with_its_source(shard_folder):
    found = list(iter_scenarios(shard_folder))
    assert [s.scenario.scenario_id for s in found] == ["a", "b", "c", "d"]
    first_shard = shard_folder / "validation.tfrecord-00000-of-00002"
    offsets = [r.offset for r in iter_records(first_shard)]
    assert [s.source for s in found[:2]] == [ScenarioSource(first_shard, o) for o in offsets]
    assert found[1].scenario == small_scenario("b")


def test_undecodable_record_names_file_and_offset(tmp_path):
    path = tmp_path / "bad.tfrecord"
    write_records(path, [small_scenario("ok").SerializeToString(), b"\xff\xff\xff"])
    second_offset = list(iter_records(path))[1].offset
    for action in (lambda: list(iter_scenarios(path)), lambda: ScenarioIndex(path)):
        with pytest.raises(ParseError, match=f"bad.tfrecord \\(record at byte offset {second_offset}\\)"):
            action()


def test_scenario_id_must_be_text(tmp_path):
    path = tmp_path / "bytes-id.tfrecord"
    write_records(path, [b"\x2a\x02\xff\xfe"])  # scenario_id = b"\xff\xfe"
    for action in (lambda: list(iter_scenarios(path)), lambda: ScenarioIndex(path)):
        with pytest.raises(ParseError, match="(?i)bytes-id.tfrecord \\(record at byte offset 0\\).*utf-8"):
            action()


def test_index_loads_single_scenarios_on_demand(shard_folder):
    index = ScenarioIndex(shard_folder)
    assert len(index) == 4 and index.ids() == ["a", "b", "c", "d"] and list(index) == index.ids()
    assert "c" in index and "z" not in index
    assert index.load("c") == small_scenario("c")
    assert index["a"] == small_scenario("a")
    assert index.load_record("b") == small_scenario("b").SerializeToString()  # the bytes, unparsed
    assert index.source("d").path.name == "validation.tfrecord-00001-of-00002"


def test_index_unknown_id_is_a_clear_error(shard_folder):
    index = ScenarioIndex(shard_folder)
    with pytest.raises(UnknownScenarioError, match="scenario 'zzz' is not in the scenario files"):
        index.load("zzz")
    with pytest.raises(KeyError):
        index["zzz"]


def test_duplicate_ids_across_shards_name_both_places(tmp_path):
    first = write_shard(tmp_path / "one.tfrecord", ["x", "dup"])
    second = write_shard(tmp_path / "two.tfrecord", ["dup"])
    with pytest.raises(DuplicateScenarioError) as caught:
        ScenarioIndex([first, second])
    message = str(caught.value)
    assert "'dup' occurs twice" in message
    assert f"{first} (record at byte offset" in message and f"{second} (record at byte offset 0)" in message


def test_index_notices_a_shard_rewritten_after_indexing(tmp_path):
    path = write_shard(tmp_path / "s.tfrecord", ["a", "b"])
    index = ScenarioIndex(path)
    write_shard(path, ["b", "a"])  # same sizes, swapped order
    for load in (index.load, index.load_record):
        with pytest.raises(ParseError, match="expected scenario 'a', found 'b'"):
            load("a")


def test_skimmed_id_matches_a_full_parse():
    scenario = small_scenario("id-with-ünicode", num_tracks=5)
    source = ScenarioSource(Path("mem"), 0)
    assert scenario_id_of(scenario.SerializeToString(), source) == "id-with-ünicode"
    # The last occurrence wins, as protobuf merging does.
    doubled = scenario.SerializeToString() + scenario_pb2.Scenario(scenario_id="z").SerializeToString()
    assert scenario_id_of(doubled, source) == scenario_pb2.Scenario.FromString(doubled).scenario_id
    for bad in (
        b"",
        scenario_pb2.Scenario(current_time_index=3).SerializeToString(),
        b"\x2a\x05ab",
    ):
        with pytest.raises(ParseError, match="mem \\(record at byte offset 0\\): not a valid Scenario"):
            scenario_id_of(bad, source)


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared (real WOMD scenarios) is absent")
def test_real_scenarios_index_and_load():
    paths = sorted((SHARED / "womd").glob("*.tfrecord"))
    if not paths:
        pytest.skip("no ../shared/womd/*.tfrecord files")
    index = ScenarioIndex(paths)
    streamed = {s.scenario.scenario_id: s for s in iter_scenarios(paths)}
    assert set(index.ids()) == set(streamed) >= {"637f20cafde22ff8", "ee519cf571686d19"}
    for scenario_id, item in streamed.items():
        assert index.source(scenario_id) == item.source
        assert index.load(scenario_id) == item.scenario
