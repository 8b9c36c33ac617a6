"""Builders of real submission bytes for the validation tests and benchmark.

They start from the golden submissions in `../shared/golden/` (real
`SimAgentsChallengeSubmission` binprotos) and the real WOMD scenarios in
`../shared/womd/`, mutate the parsed messages in code and serialize them again,
so every test feeds real protobuf bytes through the real parsers.
"""

from __future__ import annotations

import io
import tarfile
from collections.abc import Iterable
from pathlib import Path

from wosac_eval.parse.tfrecord import iter_records, write_records
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2

from support.paths import REPO as REPO_ROOT, SHARED

GOLDEN = SHARED / "golden"
WOMD = SHARED / "womd"

SCENARIO_FILES = {
    "637f20cafde22ff8": "motion_data_one_scenario.tfrecord",
    "ee519cf571686d19": "womd_scenario_input.tfrecord",
}


def require_shared() -> None:
    """Skip the calling test when ../shared (golden submissions, WOMD scenarios) is absent."""
    if not (GOLDEN.is_dir() and WOMD.is_dir()):
        import pytest  # only tests call this; the benchmark checks the folders itself

        pytest.skip(f"reference data {SHARED} is absent (golden/ and womd/ are needed)")


def golden_submission(
    case: str = "637f20cafde22ff8__logreplay",
) -> sim_agents_submission_pb2.SimAgentsChallengeSubmission:
    require_shared()
    return sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString((GOLDEN / f"{case}.binproto").read_bytes())


def scenario_path(scenario_id: str = "637f20cafde22ff8") -> Path:
    require_shared()
    return WOMD / SCENARIO_FILES[scenario_id]


def load_scenario(scenario_id: str = "637f20cafde22ff8") -> scenario_pb2.Scenario:
    record = next(iter(iter_records(scenario_path(scenario_id))))
    return scenario_pb2.Scenario.FromString(record.data)


def write_scenarios(path: Path, scenarios: Iterable[scenario_pb2.Scenario]) -> Path:
    """A TFRecord file of Scenario messages."""
    write_records(path, (s.SerializeToString() for s in scenarios))
    return path


def renamed_scenario_bytes(scenario: scenario_pb2.Scenario, scenario_id: str) -> bytes:
    copy = scenario_pb2.Scenario()
    copy.CopyFrom(scenario)
    copy.scenario_id = scenario_id
    return copy.SerializeToString()


def with_rollouts(
    template: sim_agents_submission_pb2.SimAgentsChallengeSubmission,
    rollouts: Iterable[sim_agents_submission_pb2.ScenarioRollouts],
) -> sim_agents_submission_pb2.SimAgentsChallengeSubmission:
    """A shard with template's metadata and the given ScenarioRollouts."""
    shard = sim_agents_submission_pb2.SimAgentsChallengeSubmission()
    shard.CopyFrom(template)
    del shard.scenario_rollouts[:]
    for r in rollouts:
        shard.scenario_rollouts.add().CopyFrom(r)
    return shard


def tar_bytes(members: dict[str, bytes], *, gzip: bool = True) -> bytes:
    """A real .tar(.gz) holding the given members as regular files (fast gzip level: tests pack a lot)."""
    buffer = io.BytesIO()
    options = {"compresslevel": 1} if gzip else {}
    with tarfile.open(fileobj=buffer, mode="w:gz" if gzip else "w", **options) as tar:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return buffer.getvalue()


def replicated_submission(
    folder: Path,
    n_scenarios: int,
    per_shard: int = 10,
    case: str = "637f20cafde22ff8__official_test_submission",
    layout: str = "tar.gz",
) -> tuple[Path, Path]:
    """A benchmark workload: `n_scenarios` renamed copies of a golden case's scenario and rollouts.

    Writes `scenarios-N.tfrecord` and the submission (shards of `per_shard`
    scenarios in the official `<method>.binproto-0000k-of-0000n` layout, the
    golden shard's metadata) into `folder`, as `submission-N.tar.gz` or, with
    `layout="folder"`, as the folder `submission-N/`; returns both paths.
    """
    import io
    import tarfile

    template = golden_submission(case)
    rollouts = template.scenario_rollouts[0]
    scenario = load_scenario(rollouts.scenario_id)
    ids = [f"{rollouts.scenario_id}-{i:05d}" for i in range(n_scenarios)]
    scenarios = folder / f"scenarios-{n_scenarios}.tfrecord"
    write_records(scenarios, (renamed_scenario_bytes(scenario, sid) for sid in ids))
    shards = -(-n_scenarios // per_shard)

    def shard_bytes(s: int) -> bytes:
        shard = with_rollouts(template, [])
        for sid in ids[s * per_shard : (s + 1) * per_shard]:
            r = shard.scenario_rollouts.add()
            r.CopyFrom(rollouts)
            r.scenario_id = sid
        return shard.SerializeToString()

    if layout == "folder":
        submission = folder / f"submission-{n_scenarios}"
        submission.mkdir(parents=True, exist_ok=True)
        for s in range(shards):
            (submission / f"bench.binproto-{s:05d}-of-{shards:05d}").write_bytes(shard_bytes(s))
        return scenarios, submission
    submission = folder / f"submission-{n_scenarios}.tar.gz"
    with tarfile.open(submission, "w:gz") as tar:
        for s in range(shards):
            data = shard_bytes(s)
            info = tarfile.TarInfo(f"submission/bench.binproto-{s:05d}-of-{shards:05d}")
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return scenarios, submission
