"""End to end: faulty submissions (real protobuf bytes in real archives) through `wosac-eval validate`.

Every test checks the exit code and that the report names the fault precisely.
"""

from __future__ import annotations

import io
import json
import math
import sys
import tarfile
from pathlib import Path

import pytest

from wosac_eval.fronts.cli import main
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.validate import validate_submission
from support.runs import WOSAC_EVAL
from support.submissions import (
    golden_submission,
    load_scenario,
    renamed_scenario_bytes,
    tar_bytes,
    with_rollouts,
    write_scenarios,
)
from wosac_eval.parse.tfrecord import write_records

A, B = "637f20cafde22ff8", "ee519cf571686d19"


# -- building blocks ------------------------------------------------------------


@pytest.fixture(scope="module")
def template():
    """Golden shard for scenario A: the metadata every test shard shares."""
    return golden_submission(f"{A}__logreplay")


@pytest.fixture(scope="module")
def rollouts_a(template):
    return template.scenario_rollouts[0]


@pytest.fixture(scope="module")
def rollouts_b():
    return golden_submission(f"{B}__constvel_noise").scenario_rollouts[0]


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory):
    return write_scenarios(tmp_path_factory.mktemp("scenarios") / "set.tfrecord", [load_scenario(A), load_scenario(B)])


@pytest.fixture(scope="module")
def good_shards(template, rollouts_a, rollouts_b):
    """Two valid shards, one scenario each, same metadata."""
    return {
        "sub/a.binproto": with_rollouts(template, [rollouts_a]).SerializeToString(),
        "sub/b.binproto": with_rollouts(template, [rollouts_b]).SerializeToString(),
    }


def copy(message):
    clone = type(message)()
    clone.CopyFrom(message)
    return clone


def write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def validate(capsys, scenarios, submission, *extra):
    """Run the CLI; return (exit code, stdout text)."""
    code = main(["validate", "--scenarios", *map(str, scenarios), "--submission", str(submission), *extra])
    return code, capsys.readouterr().out


def validate_json(capsys, scenarios, submission, *extra):
    code, out = validate(capsys, scenarios, submission, "--json", *extra)
    return code, json.loads(out)


def group(report: dict, code: str) -> dict:
    for g in report["groups"]:
        if g["code"] == code:
            return g
    raise AssertionError(f"no {code} group in {[g['code'] for g in report['groups']]}")


# -- valid containers -------------------------------------------------------------


def test_valid_tar_gz_exits_0(tmp_path, capsys, scenario_file, good_shards):
    path = write(tmp_path / "submission.tar.gz", tar_bytes(good_shards))
    code, out = validate(capsys, [scenario_file], path)
    assert code == 0, out
    assert "VALID sim_agents submission — 0 error(s), 0 warning(s)" in out
    assert "2 shard(s), 2 scenario(s) submitted, 2 valid, 0 missing of 2 expected" in out


def test_valid_folder_and_single_binproto_exit_0(
    tmp_path, capsys, scenario_file, good_shards, template, rollouts_a, rollouts_b
):
    folder = tmp_path / "shards"
    for name, data in good_shards.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)
    (folder / "README.md").write_text("notes")  # documentation is allowed beside shards
    assert validate(capsys, [scenario_file], folder)[0] == 0
    single = write(tmp_path / "all.binproto", with_rollouts(template, [rollouts_a, rollouts_b]).SerializeToString())
    assert validate(capsys, [scenario_file], single)[0] == 0


def test_plain_tar_is_valid_with_a_warning(tmp_path, capsys, scenario_file, good_shards):
    path = write(tmp_path / "submission.tar", tar_bytes(good_shards, gzip=False))
    code, report = validate_json(capsys, [scenario_file], path)
    assert code == 0 and report["valid"] and report["warnings"] == 1
    assert "expects a gzip-compressed tar" in group(report, "container.not_gzipped")["listed"][0]["message"]


def test_tar_named_tar_gz_is_read_and_flagged(tmp_path, capsys, scenario_file, good_shards):
    path = write(tmp_path / "submission.tar.gz", tar_bytes(good_shards, gzip=False))
    code, report = validate_json(capsys, [scenario_file], path)
    assert code == 0
    message = group(report, "container.misnamed")["listed"][0]["message"]
    assert "submission.tar.gz" in message and "uncompressed tar" in message


def test_scenario_index_works_like_paths(tmp_path, scenario_file, good_shards):
    path = write(tmp_path / "s.tar.gz", tar_bytes(good_shards))
    report = validate_submission(ScenarioIndex([scenario_file]), path)
    assert report.ok and report.stats.scenarios_valid == 2


# -- hostile and broken containers ------------------------------------------------


def test_truncated_gzip_is_named_and_later_scenarios_missing(tmp_path, capsys, scenario_file, good_shards):
    data = tar_bytes(good_shards)
    path = write(tmp_path / "cut.tar.gz", data[: len(data) * 3 // 4])
    code, report = validate_json(capsys, [scenario_file], path)
    assert code == 1
    message = group(report, "container.unreadable")["listed"][0]["message"]
    assert "cut.tar.gz" in message and ("truncated" in message or "corrupt" in message)
    # the first shard was read and checked; the cut one's scenario is missing, never silently skipped
    assert report["stats"]["scenarios_missing"] >= 1


def test_not_a_tar_named_tar_gz(tmp_path, capsys, scenario_file):
    path = write(tmp_path / "submission.tar.gz", b"this is not an archive at all" * 40)
    code, report = validate_json(capsys, [scenario_file], path)
    assert code == 1
    assert (
        "named like a compressed tar archive but is neither tar nor gzip"
        in group(report, "container.unreadable")["listed"][0]["message"]
    )
    assert group(report, "coverage.missing_scenario")["count"] == 2


def _tar_with(info: tarfile.TarInfo, data: bytes = b"", gz: bool = True) -> bytes:
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz" if gz else "w") as tar:
        tar.addfile(info, io.BytesIO(data) if data else None)
    return buffer.getvalue()


@pytest.mark.parametrize(
    "name,kind,fragment",
    [
        ("../../etc/evil.binproto", tarfile.REGTYPE, "has a '..' component"),
        ("/tmp/abs.binproto", tarfile.REGTYPE, "has an absolute path"),
        ("link.binproto", tarfile.SYMTYPE, "is a symbolic link"),
        ("hard.binproto", tarfile.LNKTYPE, "is a hard link"),
        ("dev.binproto", tarfile.CHRTYPE, "is a device file"),
        ("fifo.binproto", tarfile.FIFOTYPE, "is a FIFO"),
    ],
)
def test_unsafe_members_are_refused_by_name(tmp_path, capsys, scenario_file, good_shards, name, kind, fragment):
    info = tarfile.TarInfo(name)
    info.type = kind
    data = good_shards["sub/a.binproto"] if kind == tarfile.REGTYPE else b""
    if kind == tarfile.REGTYPE:
        info.size = len(data)
    else:
        info.linkname = "/etc/passwd"
    path = write(tmp_path / "hostile.tar.gz", _tar_with(info, data))
    code, report = validate_json(capsys, [scenario_file], path)
    assert code == 1
    message = group(report, "container.unsafe_member")["listed"][0]["message"]
    assert fragment in message and "hostile.tar.gz" in message
    assert not (tmp_path.parent.parent / "etc" / "evil.binproto").exists()


def test_size_limit(tmp_path, capsys, scenario_file, good_shards):
    path = write(tmp_path / "big.tar.gz", tar_bytes(good_shards))
    code, report = validate_json(capsys, [scenario_file], path, "--max-bytes", "1M")
    assert code == 1
    assert (
        f"more than the total limit of {1 << 20} bytes" in group(report, "container.size_limit")["listed"][0]["message"]
    )
    code, report = validate_json(capsys, [scenario_file], path, "--max-shard-bytes", "100K")
    assert code == 1
    assert "over the per-member limit of 102400 bytes" in group(report, "container.size_limit")["listed"][0]["message"]


def test_folder_stray_file_reported_and_scan_goes_on(
    tmp_path, capsys, scenario_file, good_shards, template, rollouts_b
):
    folder = tmp_path / "shards"
    folder.mkdir()
    (folder / "a.binproto").write_bytes(good_shards["sub/a.binproto"])
    (folder / "results.json").write_text("{}")
    bad = copy(rollouts_b)
    del bad.joint_scenes[0]
    (folder / "b.binproto").write_bytes(with_rollouts(template, [bad]).SerializeToString())
    code, report = validate_json(capsys, [scenario_file], folder)
    assert code == 1
    assert (
        "'results.json' is neither a submission shard" in group(report, "container.not_a_shard")["listed"][0]["message"]
    )
    # the shard after the stray file is still checked
    assert group(report, "rollouts.wrong_count")["listed"][0]["message"] == (
        f"b.binproto: scenario {B}: found 31 joint scenes, expected 32; the official validator refuses it"
    )


def test_empty_folder(tmp_path, capsys, scenario_file):
    (tmp_path / "empty").mkdir()
    code, report = validate_json(capsys, [scenario_file], tmp_path / "empty")
    assert code == 1 and "holds no submission shard" in group(report, "container.unreadable")["listed"][0]["message"]


# -- shards ---------------------------------------------------------------------------


def test_unparseable_shard_named_and_others_still_checked(tmp_path, capsys, scenario_file, good_shards):
    members = {"sub/a.binproto": b"\xff\xff\xff garbage", "sub/b.binproto": good_shards["sub/b.binproto"]}
    path = write(tmp_path / "s.tar.gz", tar_bytes(members))
    code, report = validate_json(capsys, [scenario_file], path)
    assert code == 1
    finding = group(report, "shard.unparseable")["listed"][0]
    assert finding["shard"] == "sub/a.binproto"
    assert "shard sub/a.binproto: not a valid SimAgentsChallengeSubmission" in finding["message"]
    assert report["stats"]["scenarios_valid"] == 1
    assert group(report, "coverage.missing_scenario")["listed"][0]["scenario_id"] == A


def test_shard_without_scenario(tmp_path, capsys, scenario_file, good_shards, template):
    members = dict(good_shards)
    members["sub/c.binproto"] = with_rollouts(template, []).SerializeToString()
    path = write(tmp_path / "s.tar.gz", tar_bytes(members))
    code, out = validate(capsys, [scenario_file], path)
    assert code == 1
    assert "ERROR shard.empty — Shard holds no scenario: 1" in out
    assert "  - sub/c.binproto: holds no scenario_rollouts" in out


# -- metadata -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "field,fragment",
    [
        ("submission_type", "submission_type is not set"),
        ("account_name", "account_name is empty"),
        ("unique_method_name", "unique_method_name is empty"),
        ("authors", "authors is empty"),
        ("affiliation", "affiliation is empty"),
        ("description", "description is empty"),
        ("uses_lidar_data", "uses_lidar_data is not set"),
        ("uses_camera_data", "uses_camera_data is not set"),
        ("uses_public_model_pretraining", "uses_public_model_pretraining is not set"),
        ("num_model_parameters", "num_model_parameters is empty"),
        (
            "acknowledge_complies_with_closed_loop_requirement",
            "acknowledge_complies_with_closed_loop_requirement is not set",
        ),
    ],
)
def test_missing_metadata_through_cli(
    tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b, field, fragment
):
    shard = with_rollouts(template, [rollouts_a, rollouts_b])
    shard.ClearField(field)
    path = write(tmp_path / "one.binproto", shard.SerializeToString())
    code, report = validate_json(capsys, [scenario_file], path)
    assert code == 1 and report["errors"] == 1
    (finding,) = group(report, "metadata.missing")["listed"]
    assert finding == {
        "code": "metadata.missing",
        "message": f"one.binproto: {finding['message'].split(': ', 1)[1]}",
        "shard": "one.binproto",
        "field": field,
        "severity": "error",
    }
    assert finding["message"].startswith(f"one.binproto: {fragment}")


def test_metadata_fault_shared_by_all_shards_is_one_finding(
    tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b
):
    meta = copy(template)
    meta.ClearField("affiliation")
    members = {
        f"s{i}.binproto": with_rollouts(meta, [r]).SerializeToString() for i, r in enumerate([rollouts_a, rollouts_b])
    }
    code, report = validate_json(capsys, [scenario_file], write(tmp_path / "s.tar.gz", tar_bytes(members)))
    assert code == 1 and report["errors"] == 1
    assert group(report, "metadata.missing")["listed"][0]["message"] == "s0.binproto: affiliation is empty"


def test_metadata_inconsistent_between_shards(tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b):
    other = copy(template)
    other.account_name = "someone.else@example.com"
    members = {
        "s0.binproto": with_rollouts(template, [rollouts_a]).SerializeToString(),
        "s1.binproto": with_rollouts(other, [rollouts_b]).SerializeToString(),
    }
    code, report = validate_json(capsys, [scenario_file], write(tmp_path / "s.tar.gz", tar_bytes(members)))
    assert code == 1
    assert group(report, "metadata.inconsistent")["listed"][0]["message"] == (
        f"s1.binproto: account_name is 'someone.else@example.com' but '{template.account_name}' in s0.binproto"
    )


# -- coverage -------------------------------------------------------------------------


@pytest.fixture(scope="module")
def many(tmp_path_factory, template, rollouts_a):
    """A scenario set of 12 renamed copies of scenario A, and its ScenarioRollouts per id."""
    ids = [f"scenario{i:03d}" for i in range(12)]
    scenario = load_scenario(A)
    path = tmp_path_factory.mktemp("many") / "set.tfrecord"
    write_records(path, (renamed_scenario_bytes(scenario, sid) for sid in ids))
    rollouts = {}
    for sid in ids:
        r = copy(rollouts_a)
        r.scenario_id = sid
        rollouts[sid] = r
    return ids, path, rollouts


def test_missing_scenarios_counted_and_first_listed(tmp_path, capsys, template, many):
    ids, scenario_path, rollouts = many
    shard = with_rollouts(template, [rollouts[sid] for sid in ids[:5]])
    path = write(tmp_path / "s.binproto", shard.SerializeToString())
    code, out = validate(capsys, [scenario_path], path, "--max-listed", "3")
    assert code == 1
    assert "ERROR coverage.missing_scenario — Scenario of the scenario set missing from the submission: 7" in out
    assert "  - scenario scenario005: missing from the submission (7 scenario(s) of the set are missing)" in out
    assert "scenario008" not in out  # only the first 3 in full
    assert "  ... and 4 more (raise --max-listed to see them)" in out


def test_unknown_duplicate_and_id_less_scenarios(tmp_path, capsys, template, many):
    ids, scenario_path, rollouts = many
    stranger = copy(rollouts[ids[0]])
    stranger.scenario_id = "not-in-the-set"
    anonymous = copy(rollouts[ids[0]])
    anonymous.ClearField("scenario_id")
    members = {
        "s0.binproto": with_rollouts(template, [rollouts[sid] for sid in ids[:8]]).SerializeToString(),
        "s1.binproto": with_rollouts(
            template, [rollouts[sid] for sid in ids[6:]] + [stranger, anonymous]
        ).SerializeToString(),
    }
    code, report = validate_json(capsys, [scenario_path], write(tmp_path / "s.tar", tar_bytes(members, gzip=False)))
    assert code == 1
    assert group(report, "coverage.unknown_scenario")["listed"][0]["message"] == (
        "s1.binproto: scenario not-in-the-set: not in the scenario set (scenario_rollouts[6])"
    )
    dups = group(report, "coverage.duplicate_scenario")
    assert dups["count"] == 2
    assert dups["listed"][0]["message"] == (
        "s1.binproto: scenario scenario006: submitted again at scenario_rollouts[0]; first in s0.binproto at scenario_rollouts[6]"
    )
    assert group(report, "coverage.missing_scenario_id")["listed"][0]["message"].startswith(
        "s1.binproto: scenario_rollouts[7] has no scenario_id"
    )
    assert "coverage.missing_scenario" not in [g["code"] for g in report["groups"]]
    assert report["stats"]["scenarios_valid"] == 10  # the two duplicated ones cannot be scored


# -- per scenario ---------------------------------------------------------------------


def _faulty_submission(tmp_path, template, rollouts_a, rollouts_b, mutate):
    bad = copy(rollouts_a)
    mutate(bad)
    members = {
        "sub/a.binproto": with_rollouts(template, [bad]).SerializeToString(),
        "sub/b.binproto": with_rollouts(template, [rollouts_b]).SerializeToString(),
    }
    return write(tmp_path / "s.tar.gz", tar_bytes(members))


def test_wrong_rollout_count_through_cli(tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b):
    path = _faulty_submission(tmp_path, template, rollouts_a, rollouts_b, lambda r: r.joint_scenes.pop())
    code, out = validate(capsys, [scenario_file], path)
    assert code == 1
    assert f"  - sub/a.binproto: scenario {A}: found 31 joint scenes, expected 32" in out


def test_missing_sim_agents_through_cli(tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b):
    gone = sorted(t.object_id for t in list(rollouts_a.joint_scenes[3].simulated_trajectories)[:2])

    def drop_two(r):
        del r.joint_scenes[3].simulated_trajectories[:2]

    code, report = validate_json(
        capsys, [scenario_file], _faulty_submission(tmp_path, template, rollouts_a, rollouts_b, drop_two)
    )
    assert code == 1
    (finding,) = group(report, "rollouts.missing_sim_agents")["listed"]
    assert (finding["scenario_id"], finding["rollout"], finding["shard"]) == (A, 3, "sub/a.binproto")
    assert f"rollout 3: missing sim agents [{gone[0]}, {gone[1]}]" in finding["message"]


def test_extra_and_duplicate_objects_through_cli(tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b):
    def add_objects(r):
        scene = r.joint_scenes[7]
        scene.simulated_trajectories.add().CopyFrom(scene.simulated_trajectories[0])
        stranger = scene.simulated_trajectories.add()
        stranger.CopyFrom(scene.simulated_trajectories[1])
        stranger.object_id = 424242

    dup_id = rollouts_a.joint_scenes[7].simulated_trajectories[0].object_id
    code, report = validate_json(
        capsys, [scenario_file], _faulty_submission(tmp_path, template, rollouts_a, rollouts_b, add_objects)
    )
    assert code == 1
    assert (
        f"rollout 7: object ids simulated more than once: {dup_id} (2 times)"
        in group(report, "rollouts.duplicate_objects")["listed"][0]["message"]
    )
    assert (
        "rollout 7: objects [424242] are not sim agents"
        in group(report, "rollouts.extra_objects")["listed"][0]["message"]
    )


def test_wrong_length_and_nan_through_cli(tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b):
    target = rollouts_a.joint_scenes[5].simulated_trajectories[9].object_id

    def corrupt(r):
        t = r.joint_scenes[5].simulated_trajectories[9]
        del t.center_x[-1]
        t.center_y[17] = math.nan

    code, report = validate_json(
        capsys, [scenario_file], _faulty_submission(tmp_path, template, rollouts_a, rollouts_b, corrupt)
    )
    assert code == 1
    length = group(report, "rollouts.wrong_length")["listed"][0]
    assert (
        length["message"]
        == f"sub/a.binproto: scenario {A} rollout 5 object {target}: field center_x has 79 values, expected 80; the official validator refuses it"
    )
    assert (length["object_id"], length["field"], length["rollout"]) == (target, "center_x", 5)
    nan = group(report, "rollouts.non_finite")["listed"][0]
    assert nan["message"] == (
        f"sub/a.binproto: scenario {A} rollout 5 object {target}: center_y[17] is NaN; the "
        "official evaluator scores it as given, NaN spreading into its features (so does wosac-eval)"
    )


def test_all_errors_reported_with_counts_not_just_first(
    tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b
):
    def everywhere(r):
        for scene in r.joint_scenes:
            for t in scene.simulated_trajectories:
                t.heading[0] = math.inf

    code, report = validate_json(
        capsys,
        [scenario_file],
        _faulty_submission(tmp_path, template, rollouts_a, rollouts_b, everywhere),
        "--max-listed",
        "5",
    )
    n_objects = len(rollouts_a.joint_scenes[0].simulated_trajectories)
    g = group(report, "rollouts.non_finite")
    # Warnings (the official scores non-finite values): valid, every finding counted, 5 listed.
    assert code == 0 and g["count"] == 32 * n_objects and len(g["listed"]) == 5
    assert report["warnings"] == 32 * n_objects and report["errors"] == 0


# -- report and usage -------------------------------------------------------------------


def test_report_lists_scenarios_a_partial_scorer_skips(tmp_path, scenario_file, template, rollouts_a):
    bad = copy(rollouts_a)
    bad.joint_scenes.pop()
    path = write(tmp_path / "s.binproto", with_rollouts(template, [bad]).SerializeToString())
    report = validate_submission([scenario_file], path)
    assert not report.ok
    assert report.skipped_scenarios == {
        A: f"s.binproto: scenario {A}: found 31 joint scenes, expected 32; the official validator refuses it",
        B: f"scenario {B}: missing from the submission (1 scenario(s) of the set are missing)",
    }
    assert not report.is_scenario_valid(A) and not report.is_scenario_valid(B)


@pytest.mark.parametrize(
    "argv_tail,fragment",
    [
        (["--submission", "/no/such/file.tar.gz"], "no such submission file or folder"),
        (["--submission", "X", "--max-listed", "-1"], "--max-listed must be >= 0"),
    ],
)
def test_usage_errors_exit_2(capsys, scenario_file, argv_tail, fragment):
    code = main(["validate", "--scenarios", str(scenario_file), *argv_tail])
    assert code == 2
    assert fragment in capsys.readouterr().err


def test_unreadable_scenario_set_exits_2(tmp_path, capsys, good_shards):
    sub = write(tmp_path / "a.binproto", good_shards["sub/a.binproto"])
    assert main(["validate", "--scenarios", str(tmp_path / "nope.tfrecord"), "--submission", str(sub)]) == 2
    assert "cannot read the scenario set" in capsys.readouterr().err
    broken = write(tmp_path / "broken.tfrecord", b"\x00" * 7)
    assert main(["validate", "--scenarios", str(broken), "--submission", str(sub)]) == 2
    assert "broken.tfrecord" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv",
    [
        ["validate"],
        ["validate", "--scenarios", "x"],
        ["validate", "--scenarios", "x", "--submission", "y", "--max-bytes", "lots"],
        ["validate", "--scenarios", "x", "--submission", "y", "--workers", "0"],
    ],
)
def test_argparse_usage_errors_exit_2(argv):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2


def test_progress_bar_only_on_a_terminal(tmp_path, capsys, monkeypatch, scenario_file, good_shards):
    path = write(tmp_path / "s.tar.gz", tar_bytes(good_shards))
    assert validate(capsys, [scenario_file], path)[0] == 0
    assert "scenario" not in capsys.readouterr().err  # not a TTY: no bar
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    code = main(["validate", "--scenarios", str(scenario_file), "--submission", str(path)])
    assert code == 0
    err = capsys.readouterr().err
    assert "/2 [" in err and "scenario/s" in err  # a bar over the 2 expected scenarios, on stderr


def test_json_report_is_machine_readable(tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b):
    path = _faulty_submission(tmp_path, template, rollouts_a, rollouts_b, lambda r: r.joint_scenes.pop())
    code, report = validate_json(capsys, [scenario_file], path)
    assert code == 1
    assert set(report) == {"submission", "challenge", "valid", "errors", "warnings", "stats", "groups", "max_listed"}
    assert report["challenge"] == "sim_agents"
    assert report["valid"] is False and report["errors"] == 1
    assert report["stats"]["scenarios_submitted"] == 2 and report["stats"]["shards"] == 2
    g = group(report, "rollouts.wrong_count")
    assert g["title"] == "Wrong number of joint scenes (rollouts)" and g["severity"] == "error" and g["count"] == 1


def test_report_can_list_every_skipped_scenario_for_partial_scoring(tmp_path, scenario_file, template, rollouts_a):
    path = write(tmp_path / "s.binproto", with_rollouts(template, [rollouts_a]).SerializeToString())
    data = validate_submission([scenario_file], path).to_dict(include_skipped=True)
    assert list(data["skipped_scenarios"]) == [B]
    json.dumps(data)


def test_wrong_split_is_called_out(tmp_path, capsys, template, many, rollouts_a, rollouts_b):
    _, other_split, _ = many  # a scenario set that shares no id with the submission
    path = write(tmp_path / "s.binproto", with_rollouts(template, [rollouts_a, rollouts_b]).SerializeToString())
    code, report = validate_json(capsys, [other_split], path)
    assert code == 1
    message = group(report, "coverage.no_overlap")["listed"][0]["message"]
    assert "none of the 2 submitted scenario(s) is in the scenario set of 12" in message and "split" in message


def test_scenario_set_with_a_scenario_twice_is_a_usage_error(tmp_path, capsys, good_shards):
    twice = write_scenarios(tmp_path / "twice.tfrecord", [load_scenario(A), load_scenario(A)])
    sub = write(tmp_path / "a.binproto", good_shards["sub/a.binproto"])
    assert main(["validate", "--scenarios", str(twice), "--submission", str(sub)]) == 2
    err = capsys.readouterr().err
    assert f"scenario '{A}' occurs twice" in err and "twice.tfrecord" in err


def test_zero_byte_shard_is_called_empty(tmp_path, capsys, scenario_file, good_shards):
    members = {**good_shards, "sub/zero.binproto": b""}
    code, report = validate_json(capsys, [scenario_file], write(tmp_path / "s.tar.gz", tar_bytes(members)))
    assert code == 1
    assert (
        group(report, "shard.empty")["listed"][0]["message"]
        == "sub/zero.binproto: holds no scenario_rollouts (the shard is 0 bytes)"
    )


@pytest.mark.parametrize(
    "mutate,field,fragment",
    [
        (
            lambda s: setattr(s, "submission_type", 0),
            "submission_type",
            "submission_type is UNKNOWN, expected SIM_AGENTS_SUBMISSION",
        ),
        (lambda s: setattr(s, "account_name", "jdoe"), "account_name", "account_name 'jdoe' is not an email address"),
        (lambda s: s.authors.append(""), "authors", "authors[1] is empty"),
        (
            lambda s: setattr(s, "num_model_parameters", "big"),
            "num_model_parameters",
            "num_model_parameters 'big' is not a number",
        ),
        (
            lambda s: setattr(s, "acknowledge_complies_with_closed_loop_requirement", False),
            "acknowledge_complies_with_closed_loop_requirement",
            "is false; it must be true",
        ),
    ],
)
def test_invalid_metadata_through_cli(
    tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b, mutate, field, fragment
):
    shard = with_rollouts(template, [rollouts_a, rollouts_b])
    mutate(shard)
    code, report = validate_json(capsys, [scenario_file], write(tmp_path / "one.binproto", shard.SerializeToString()))
    assert code == 1 and report["errors"] == 1
    (finding,) = group(report, "metadata.invalid")["listed"]
    assert (
        finding["field"] == field and finding["message"].startswith("one.binproto: ") and fragment in finding["message"]
    )


def test_pretraining_without_model_names_through_cli(tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b):
    shard = with_rollouts(template, [rollouts_a, rollouts_b])
    shard.uses_public_model_pretraining = True
    code, report = validate_json(capsys, [scenario_file], write(tmp_path / "one.binproto", shard.SerializeToString()))
    assert code == 1
    (finding,) = group(report, "metadata.missing")["listed"]
    assert finding["field"] == "public_model_names" and "uses_public_model_pretraining is true" in finding["message"]


def test_missing_method_link_is_a_warning_only(tmp_path, capsys, scenario_file, template, rollouts_a, rollouts_b):
    shard = with_rollouts(template, [rollouts_a, rollouts_b])
    shard.ClearField("method_link")
    code, out = validate(capsys, [scenario_file], write(tmp_path / "one.binproto", shard.SerializeToString()))
    assert code == 0
    assert "WARNING metadata.recommended — Recommended metadata field missing: 1" in out
    assert "  - one.binproto: method_link is empty" in out


def test_workers_give_the_same_report(tmp_path, capsys, template, many):
    ids, scenario_path, rollouts = many
    broken = copy(rollouts[ids[3]])
    broken.joint_scenes[2].simulated_trajectories[0].heading[5] = math.nan
    del broken.joint_scenes[4].simulated_trajectories[1]
    stranger = copy(rollouts[ids[0]])
    stranger.scenario_id = "stranger"
    other = copy(template)
    other.unique_method_name = "other"
    members = {
        "s0.binproto": with_rollouts(template, [rollouts[ids[0]], broken]).SerializeToString(),
        "s1.binproto": b"not a shard",
        "s2.binproto": with_rollouts(other, [rollouts[sid] for sid in ids[4:7]] + [stranger]).SerializeToString(),
        "s3.binproto": with_rollouts(template, [rollouts[ids[4]]]).SerializeToString(),
        "s4.binproto": with_rollouts(template, []).SerializeToString(),
    }
    path = write(tmp_path / "s.tar", tar_bytes(members, gzip=False))
    code1, one = validate_json(capsys, [scenario_path], path, "--max-listed", "2")
    code2, two = validate_json(capsys, [scenario_path], path, "--max-listed", "2", "--workers", "2")
    for report in (one, two):
        report["stats"].pop("elapsed_s"), report["stats"].pop("scenarios_per_s")
    assert code1 == code2 == 1
    assert one == two
    assert {g["code"] for g in one["groups"]} >= {
        "shard.unparseable",
        "shard.empty",
        "metadata.inconsistent",
        "coverage.unknown_scenario",
        "coverage.duplicate_scenario",
        "coverage.missing_scenario",
        "rollouts.non_finite",
        "rollouts.missing_sim_agents",
    }


def test_subprocess_on_an_ascii_console_with_non_ascii_names(tmp_path, scenario_file, template, rollouts_a):
    import os
    import subprocess

    shard = with_rollouts(template, [rollouts_a])
    shard.affiliation = "Université"
    other = copy(shard)
    other.affiliation = "Universität"
    members = {"é/0.binproto": shard.SerializeToString(), "é/1.binproto": with_rollouts(other, []).SerializeToString()}
    path = write(tmp_path / "s.tar.gz", tar_bytes(members))
    env = {**os.environ, "PYTHONIOENCODING": "ascii"}
    done = subprocess.run(
        [
            *WOSAC_EVAL,
            "validate",
            "--scenarios",
            str(scenario_file),
            "--submission",
            str(path),
        ],
        capture_output=True,
        text=True,
        env=env,
        encoding="ascii",
        errors="strict",
    )
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    assert "\\xe9/1.binproto: affiliation is 'Universit\\xe4t' but 'Universit\\xe9' in \\xe9/0.binproto" in done.stdout
