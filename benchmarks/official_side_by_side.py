"""The official TensorFlow evaluator and ours on the same scenario, in one run.

Times the official `compute_scenario_metrics_for_bundle` (waymo-open-dataset
1.6.7, in the oracle venv made by ../shared/oracle/setup.sh) and our
`score_scenario` on the real scenario 637f20cafde22ff8 with its official
32-rollout test submission, 2025 config, and prints both, the ratio and the
meta-metrics (which must agree). The official code uses TensorFlow's default
threads (all cores); ours runs on one core.

Usage:
  python benchmarks/official_side_by_side.py [--oracle-python ~/.wosac-oracle/bin/python] [--repeat 2]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench_env import SHARED
SCENARIOS = SHARED / "womd" / "motion_data_one_scenario.tfrecord"
SUBMISSION = SHARED / "golden" / "637f20cafde22ff8__official_test_submission.binproto"
CONFIG = SHARED / "official-configs" / "challenge_2025_sim_agents_config.textproto"

# Runs inside the oracle venv: only calls the official API.
_OFFICIAL = """
import json, os, sys, time
os.environ["TF_CPP_MIN_LOG_LEVEL"] = "3"
import tensorflow as tf
tf.config.set_visible_devices([], "GPU")
from google.protobuf import text_format
from waymo_open_dataset.protos import scenario_pb2, sim_agents_submission_pb2, sim_agents_metrics_pb2
from waymo_open_dataset.wdl_limited.sim_agents_metrics import metrics
scenarios, submission, config, repeat = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
cfg = text_format.Parse(open(config).read(), sim_agents_metrics_pb2.SimAgentMetricsConfig())
rollouts = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(open(submission, "rb").read()).scenario_rollouts[0]
scenario = next(s for s in (scenario_pb2.Scenario.FromString(r.numpy()) for r in tf.data.TFRecordDataset(scenarios))
                if s.scenario_id == rollouts.scenario_id)
times = []
for _ in range(repeat):
    t = time.perf_counter()
    m = metrics.compute_scenario_metrics_for_bundle(cfg, scenario, rollouts)
    times.append(time.perf_counter() - t)
print(json.dumps({"times": times, "metametric": float(m.metametric)}))
"""

_OURS = """
import json, sys, time
from wosac_eval.runtime.allocator import keep_freed_memory
from wosac_eval.scoring.scenario import score_scenario
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import sim_agents_submission_pb2
keep_freed_memory()
rollouts = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(open(sys.argv[2], "rb").read()).scenario_rollouts[0]
scenario = next(s for s, _ in iter_scenarios(sys.argv[1]) if s.scenario_id == rollouts.scenario_id)
score_scenario(scenario, rollouts, sys.argv[3])
times = []
for _ in range(int(sys.argv[4])):
    t = time.perf_counter()
    m = score_scenario(scenario, rollouts, sys.argv[3])
    times.append(time.perf_counter() - t)
print(json.dumps({"times": times, "metametric": m["metametric"]}))
"""


def _run(python: str, code: str, repeat: int, env: dict | None = None) -> dict:
    out = subprocess.run([python, "-c", code, str(SCENARIOS), str(SUBMISSION), str(CONFIG), str(repeat)],
                         capture_output=True, text=True, env={**os.environ, **(env or {})})
    if out.returncode:
        sys.exit(f"{python} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--oracle-python", default=os.environ.get("WOSAC_ORACLE_PYTHON",
                                                             str(Path.home() / ".wosac-oracle" / "bin" / "python")))
    p.add_argument("--repeat", type=int, default=2, help="timed official calls (ours: 20 x this)")
    args = p.parse_args()
    if not Path(args.oracle_python).exists():
        print(f"no oracle venv at {args.oracle_python}: run `bash ../shared/oracle/setup.sh` first")
        return 2
    start = time.perf_counter()
    official = _run(args.oracle_python, _OFFICIAL, args.repeat)
    ours = _run(sys.executable, _OURS, 20 * args.repeat, env={"OMP_NUM_THREADS": "1"})
    o, w = statistics.median(official["times"]), statistics.median(ours["times"])
    print(f"scenario 637f20cafde22ff8, 32 rollouts, 2025 config ({os.cpu_count()} cores)")
    print(f"  official (TensorFlow, all cores): {o:8.2f} s per scenario  (runs: "
          f"{', '.join(f'{t:.1f}' for t in official['times'])})")
    print(f"  wosac-eval (numpy, one core):     {w:8.4f} s per scenario  (median of {len(ours['times'])})")
    print(f"  speed-up: {o / w:.0f}x")
    print(f"  meta-metric: official {official['metametric']:.7f}, ours {ours['metametric']:.7f}, "
          f"|difference| {abs(official['metametric'] - ours['metametric']):.1e}")
    print(f"  ({time.perf_counter() - start:.0f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
