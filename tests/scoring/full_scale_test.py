"""`benchmarks/full_scale.py` at a small size: the validation-size workload's builder and the paths
that need no Ray cluster (validate, `wosac-eval score`, with `--per-object`, the service, an interrupted
and resumed score), each in its own processes, must agree on the result document.

A second case builds the Scenario Generation workload (`--challenge scenario_gen`: 91 steps of every
object valid at step 10, with box sizes, validity and types) and runs validate and score on it.

The workload is built from the real scenes of ../shared (skipped without it) and synthetic ones,
with the gzip stream stitched from pre-deflated pieces: the archive is also read back here with the
standard library (tarfile, gzip) and its shards parsed, so a fault of the stitching cannot hide
behind a reader of this project.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tarfile

import pytest

from support.paths import REPO, require_shared
from wosac_eval.parse.tfrecord import iter_records
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2 as sub_pb2

SCENES, SHARDS, SYNTHETIC = 48, 3, 4  # 6 base scenes: the 2 real ones and 4 synthetic
REQUIRED_METADATA = (
    "account_name",
    "unique_method_name",
    "affiliation",
    "description",
    "method_link",
    "num_model_parameters",
)


def _bench(tmp_path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            sys.executable,
            str(REPO / "benchmarks" / "full_scale.py"),
            "--scenes",
            str(SCENES),
            "--shards",
            str(SHARDS),
            "--synthetic",
            str(SYNTHETIC),
            "--workdir",
            str(tmp_path / "work"),
            "--workers",
            "2",
            *args,
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )


def _check_workload(build) -> None:
    """The scenario set and the submission, read with the standard library: official names, every id
    distinct and the same on both sides, shard k covering scenario shard k, complete metadata."""
    scenario_ids = []
    for k in range(SHARDS):
        path = build / "scenarios" / f"validation.tfrecord-{k:05d}-of-{SHARDS:05d}"
        ids = [scenario_pb2.Scenario.FromString(r.data).scenario_id for r in iter_records(path)]  # CRCs checked
        scenario_ids.append(ids)
    flat = [sid for ids in scenario_ids for sid in ids]
    assert len(flat) == SCENES and len(set(flat)) == SCENES
    assert all(re.fullmatch(r"[0-9a-f]{16}", sid) for sid in flat)
    with tarfile.open(build / "submission.tar.gz", "r:gz") as tar:  # gzip CRC and length checked at its end
        members = tar.getmembers()
        assert [m.name for m in members] == [f"submission.binproto-{k:05d}-of-{SHARDS:05d}" for k in range(SHARDS)]
        for k, member in enumerate(members):
            shard = sub_pb2.SimAgentsChallengeSubmission.FromString(tar.extractfile(member).read())
            assert [r.scenario_id for r in shard.scenario_rollouts] == scenario_ids[k]
            assert all(len(r.joint_scenes) == 32 for r in shard.scenario_rollouts)
            for field in REQUIRED_METADATA:
                assert getattr(shard, field), field
            assert shard.authors and shard.acknowledge_complies_with_closed_loop_requirement
            assert shard.submission_type == sub_pb2.SimAgentsChallengeSubmission.SIM_AGENTS_SUBMISSION
            for flag in ("uses_lidar_data", "uses_camera_data", "uses_public_model_pretraining"):
                assert shard.HasField(flag), flag


@pytest.mark.ci  # among the longest outside Ray, browser and JAX (--durations): the CI tier's
def test_every_path_gives_the_same_result(tmp_path):
    require_shared("womd")
    require_shared("golden")
    paths = ["validate", "cli", "cli-again", "core", "cli-objects", "service", "interrupt"]
    try:
        import wosac_server  # noqa: F401
    except ImportError:
        paths.remove("service")  # the service's own distribution (pip install ./server) is not installed
    summary = tmp_path / "summary.json"
    # Killed at half the scenarios: well before the last chunks, which two workers may finish together.
    done = _bench(tmp_path, "--paths", ",".join(paths), "--interrupt-at", "0.5", "--json", str(summary))
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    data = json.loads(summary.read_text())
    build = data["build"]
    assert build["scenes"] == SCENES and build["shards"] == SHARDS and not build["reused"]
    _check_workload(tmp_path / "work" / "build")

    rows = {row["path"]: row for row in data["rows"]}
    assert set(rows) == set(paths)
    assert rows["validate"]["ok"], rows["validate"]["note"]
    assert "valid, 0 error(s), 0 warning(s)" in rows["validate"]["note"]
    scored = [row for row in rows.values() if "digest" in row]
    assert rows["cli"]["same"] == "reference"
    assert {p for p, row in rows.items() if "skipped" not in row} - {"validate", "core"} == {r["path"] for r in scored}
    # The scoring core, one copy of each of the 6 base scenes on one core, and the cli path's CPU over it.
    core = rows["core"]
    assert core["ok"] and len(core["base_medians_s"]) == 6 and all(m > 0 for m in core["base_medians_s"])
    assert min(core["base_medians_s"]) <= core["core_s_per_scene"] <= max(core["base_medians_s"])
    assert core["cli_s_per_scene"] == pytest.approx(rows["cli"]["cpu_s"] / SCENES, abs=0.05 / SCENES)  # cpu_s: 0.1 s
    assert core["cli_over_core"] == pytest.approx(core["cli_s_per_scene"] / core["core_s_per_scene"], rel=1e-12)
    # Again, each scene's criticality read from the cache the cli path filled (the workload's own file).
    assert "criticality kept" in rows["cli-again"]["what"]
    assert core["cli_again_s_per_scene"] == pytest.approx(rows["cli-again"]["cpu_s"] / SCENES, abs=0.05 / SCENES)
    for row in scored:
        assert row["ok"] and row["same"] in ("reference", "yes"), (row["path"], row["same"], row["note"])
        assert row["digest"]["num_scenarios"] == SCENES and row["digest"]["copies_alike"]
        assert row["peak_rss"] and all(role["max_mib"] > 0 for role in row["peak_rss"].values())
    # The real base scene's copies score as the official implementation scored it (golden).
    golden = json.loads(
        (require_shared("golden") / "golden" / "637f20cafde22ff8__official_test_submission.json").read_text()
    )
    assert abs(rows["cli"]["digest"]["base_metametric"]["0"] - golden["metrics"]["2025"]["metametric"]) < 1e-5
    # --per-object: the same scores, a side file of every evaluated object, its cost against the cli path's.
    objects = rows["cli-objects"]
    assert objects["num_objects"] > 0 and objects["objects_bytes"] > 0 and "vs_cli_wall" in objects, objects["note"]
    if "service" in rows:
        service = rows["service"]["service"]
        assert service["state"] == "done" and service["published"]
        assert service["data_dir_peak_bytes"] >= service["upload_bytes"]
    interrupt = rows["interrupt"]
    if "skipped" not in interrupt:  # the journal of `wosac-eval score -o` resumes the killed run
        assert interrupt["interrupt"]["resumed"] and SCENES // 2 <= interrupt["interrupt"]["journaled"] < SCENES

    again = _bench(tmp_path, "--paths", "none", "--json", str(summary))  # the cached workload is reused
    assert again.returncode == 0, again.stderr[-2000:]
    assert json.loads(summary.read_text())["build"]["reused"]


SG_SCENES, SG_SHARDS, SG_SYNTHETIC = 24, 2, 2  # 7 base scenes: 3 golden, 2 real, 2 synthetic


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_scenario_gen_workload_validates_and_scores_as_the_golden(tmp_path):
    """`--challenge scenario_gen`: each copy a full-scene SG submission (all 91 steps of every object valid
    at step 10, with box sizes and types), valid under the challenge's rules, scored by `wosac-eval score
    --challenge scenario_gen`, with the golden scenes' copies scoring as the official implementation did."""
    require_shared("womd")
    shared = require_shared("golden/scenario_gen/scenes")
    summary = tmp_path / "summary.json"
    done = subprocess.run(
        [
            sys.executable,
            str(REPO / "benchmarks" / "full_scale.py"),
            "--challenge",
            "scenario_gen",
            "--scenes",
            str(SG_SCENES),
            "--shards",
            str(SG_SHARDS),
            "--synthetic",
            str(SG_SYNTHETIC),
            "--workdir",
            str(tmp_path / "work"),
            "--workers",
            "2",
            "--paths",
            "validate,cli",
            "--json",
            str(summary),
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    data = json.loads(summary.read_text())
    build = data["build"]
    assert build["key"]["challenge"] == "scenario_gen" and build["scenes"] == SG_SCENES
    bases = build["bases"]
    assert [b["source"] for b in bases].count("golden") == 3 and [b["source"] for b in bases].count("womd") == 2
    assert len(bases) == 3 + 2 + SG_SYNTHETIC

    # The archive, read with the standard library: every object valid at step 10, 91 steps, boxes and types.
    work = tmp_path / "work" / "build"
    scenarios = {}
    for k in range(SG_SHARDS):
        for record in iter_records(work / "scenarios" / f"validation.tfrecord-{k:05d}-of-{SG_SHARDS:05d}"):
            scenario = scenario_pb2.Scenario.FromString(record.data)
            scenarios[scenario.scenario_id] = scenario
    assert len(scenarios) == SG_SCENES and all(re.fullmatch(r"[0-9a-f]{16}", sid) for sid in scenarios)
    seen = []
    with tarfile.open(work / "submission.tar.gz", "r:gz") as tar:
        for k, member in enumerate(tar.getmembers()):
            assert member.name == f"submission.binproto-{k:05d}-of-{SG_SHARDS:05d}"
            shard = sub_pb2.SimAgentsChallengeSubmission.FromString(tar.extractfile(member).read())
            assert shard.unique_method_name and shard.account_name and shard.description
            for rollouts in shard.scenario_rollouts:
                seen.append(rollouts.scenario_id)
                scenario = scenarios[rollouts.scenario_id]
                valid_now = sorted(t.id for t in scenario.tracks if t.states[10].valid)
                assert len(rollouts.joint_scenes) == 32
                for scene in rollouts.joint_scenes[:2]:
                    assert sorted(t.object_id for t in scene.simulated_trajectories) == valid_now
                    for t in scene.simulated_trajectories:
                        assert len(t.center_x) == len(t.length) == len(t.width) == len(t.height) == len(t.valid) == 91
                        assert t.HasField("object_type") and all(t.valid)
    assert sorted(seen) == sorted(scenarios)

    rows = {row["path"]: row for row in data["rows"]}
    assert rows["validate"]["ok"], rows["validate"]["note"]
    assert "--challenge scenario_gen" in rows["validate"]["what"]
    assert "valid, 0 error(s), 0 warning(s)" in rows["validate"]["note"]
    cli = rows["cli"]
    assert cli["ok"] and cli["same"] == "reference", cli["note"]
    digest = cli["digest"]
    assert digest["num_scenarios"] == SG_SCENES and digest["copies_alike"]
    # The golden scenes' copies score as the official implementation scored them (scenario_gen_2025).
    for b, base in enumerate(bases):
        if base.get("golden"):
            golden = json.loads((shared / "golden" / "scenario_gen" / f"{base['golden']}.json").read_text())
            official = golden["metrics"]["scenario_gen_2025"]["metametric"]
            assert abs(digest["base_metametric"][str(b)] - official) < 1e-5, (base["name"], official)
