"""The benchmarks' stage timing (`benchmarks/stage_timing.py`) runs on the current pipeline and counts right.

Timings are not checked here (they are measured by the benchmark scripts); what is checked is that
the breakdown scores what `score_scenario` scores, and that its operation counts are consistent.
"""

import sys

import numpy as np
import pytest

from support.paths import REPO
from wosac_eval.arrays.messages import rollouts_bytes
from wosac_eval.metrics.config import load_config
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.scoring.scenario import score_scenario
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import policy_rollouts

sys.path.insert(0, str(REPO / "benchmarks"))
import stage_timing  # noqa: E402


@pytest.mark.parametrize("challenge, config", [("sim_agents", "2025"), ("scenario_gen", "scenario_gen_2025")])
@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_breakdown_scores_as_score_scenario_and_counts_add_up(challenge, config):
    scenario = scenes.generate_scenes(1, seed=3)[0]
    raw_rollouts = rollouts_bytes(policy_rollouts(scenario, "constant_velocity", challenge=challenge))
    r = stage_timing.stage_breakdown(
        scenario.SerializeToString(), raw_rollouts, load_config(config), challenge, repeat=1
    )
    expected = score_scenario(
        scenario,
        sim_agents_submission_pb2.ScenarioRollouts.FromString(raw_rollouts),
        load_config(config),
        challenge=challenge,
    )
    assert r["metametric"] == pytest.approx(expected["metametric"], abs=0)
    assert set(r["stages"]) >= {
        "scenario arrays",
        "parse rollouts",
        "map index",
        "features: road edge distance",
        "features: nearest object",
        "estimators and metrics",
    }
    assert all(np.isfinite(s) and s >= 0 for s in r["stages"].values())
    edge, nearest = r["counts"]["road edge"], r["counts"]["nearest object"]
    # Four corners per valid evaluated box, over 33 samples (the log and 32 rollouts).
    assert edge["queries"] > 0 and edge["queries"] % 4 == 0
    assert edge["pairs evaluated"] >= edge["queries"]  # every query evaluates its nearest segment at least
    assert nearest["queries"] <= nearest["pairs evaluated"] <= nearest["all pairs"]
    assert edge["floor seconds"] > 0 and nearest["floor seconds"] > 0
