"""The generated modules are current and wire-compatible with real WOSAC files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from google.protobuf import text_format

from wosac_eval.parse.tfrecord import iter_records
from wosac_eval.protos import (
    map_pb2,
    scenario_pb2,
    sim_agents_metrics_pb2,
    sim_agents_submission_pb2,
)

from support.paths import REPO as REPO_ROOT, SHARED

needs_shared = pytest.mark.skipif(not SHARED.is_dir(), reason="../shared (real WOMD files, official configs) is absent")


def shared_files(pattern: str) -> list[Path]:
    """Files under ../shared matching pattern; the test is skipped when there are none."""
    files = sorted(SHARED.glob(pattern))
    if not files:
        pytest.skip(f"no ../shared/{pattern} files")
    return files


def test_committed_modules_match_the_proto_sources():
    result = subprocess.run(
        [sys.executable, str(REPO_ROOT / "scripts" / "gen_protos.py"), "--check"],
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_messages_live_in_our_own_package():
    # A different package than waymo.open_dataset lets both be loaded together.
    assert scenario_pb2.Scenario.DESCRIPTOR.full_name == "wosac_eval.protos.Scenario"
    assert map_pb2.DESCRIPTOR.package == "wosac_eval.protos"


def test_smoothing_pseudocount_defaults_to_one_thousandth():
    config = sim_agents_metrics_pb2.SimAgentMetricsConfig
    assert config.HistogramEstimate().additive_smoothing_pseudocount == pytest.approx(1e-3)
    assert config.BernoulliEstimate().additive_smoothing_pseudocount == pytest.approx(1e-3)


def test_trajectory_floats_are_packed_on_the_wire():
    trajectory = sim_agents_submission_pb2.SimulatedTrajectory(center_x=[1.0, 2.0], object_id=7)
    # Field 2, wire type 2 (one length-delimited run of 8 bytes), then field 6 varint 7.
    assert trajectory.SerializeToString() == b"\x12\x08" + b"\x00\x00\x80?\x00\x00\x00@" + b"\x30\x07"


@needs_shared
@pytest.mark.parametrize("name", ["womd/test_submission.binproto", "golden/*.binproto"])
def test_real_submissions_round_trip_byte_for_byte(name):
    for path in shared_files(name):
        raw = path.read_bytes()
        submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw)
        assert submission.scenario_rollouts, path
        assert submission.scenario_rollouts[0].joint_scenes[0].simulated_trajectories, path
        assert submission.SerializeToString() == raw, path


@needs_shared
def test_real_scenario_round_trips_byte_for_byte():
    (path,) = shared_files("womd/motion_data_one_scenario.tfrecord")
    (record,) = list(iter_records(path))
    scenario = scenario_pb2.Scenario.FromString(record.data)
    assert scenario.scenario_id == "637f20cafde22ff8"
    assert len(scenario.tracks) == 83
    assert len(scenario.map_features) == 301
    assert len(scenario.dynamic_map_states) == 91
    assert scenario.SerializeToString() == record.data


@needs_shared
def test_second_real_scenario_parses_with_all_known_fields():
    # This record also carries an empty field 3 that no public Scenario
    # definition declares; protobuf keeps it as an unknown field and writes it
    # last, so only the parsed content (not the byte order) is compared here.
    (path,) = shared_files("womd/womd_scenario_input.tfrecord")
    (record,) = list(iter_records(path))
    scenario = scenario_pb2.Scenario.FromString(record.data)
    assert scenario.scenario_id == "ee519cf571686d19"
    assert len(scenario.tracks) == 257
    assert all(len(track.states) == len(scenario.timestamps_seconds) for track in scenario.tracks)
    assert len(scenario.SerializeToString()) == len(record.data)
    assert scenario_pb2.Scenario.FromString(scenario.SerializeToString()) == scenario


@needs_shared
def test_official_metric_configs_parse():
    for path in shared_files("official-configs/*.textproto"):
        config = text_format.Parse(path.read_text(), sim_agents_metrics_pb2.SimAgentMetricsConfig())
        assert config.linear_speed.WhichOneof("estimator") == "histogram", path
        assert config.collision_indication.WhichOneof("estimator") == "bernoulli", path
        assert config.linear_speed.histogram.num_bins > 0, path
        features = [feature for _, feature in config.ListFields()]
        assert len(features) >= 9, path
        assert all(feature.WhichOneof("estimator") for feature in features), path
        weights = [feature.metametric_weight for feature in features]
        assert min(weights) >= 0 and sum(weights) > 0, path
        reparsed = text_format.Parse(
            text_format.MessageToString(config), sim_agents_metrics_pb2.SimAgentMetricsConfig()
        )
        assert reparsed == config, path
