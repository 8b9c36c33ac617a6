"""The official TensorFlow evaluator and ours on the same scenario, in one run.

Times the official `compute_scenario_metrics_for_bundle` (waymo-open-dataset
1.6.7, in the oracle venv made by ../shared/oracle/setup.sh) and our
`score_scenario` on the same scenario and rollouts, with the same warm-up (one
call) and the same number of timed calls, and prints both, the ratio and the
meta-metrics (which must agree). Ours runs on one core; the official code with
TensorFlow's default threads (all cores), or with `--official-one-core` on one
core too (one TensorFlow thread, pinned to CPU 0).

- `--challenge sim_agents` (default): the real scenario 637f20cafde22ff8 with
  its official 32-rollout test submission, 2025 config.
- `--challenge scenario_gen`: a 34-object synthetic scene (the
  large-coordinates scene of `generate_scenes(10, seed=5)`) with our
  log-replay scenario-gen baseline, scenario_gen_2025 config.

Usage:
  python benchmarks/official_side_by_side.py [--challenge sim_agents|scenario_gen] [--repeat 3]
      [--official-one-core] [--oracle-python ~/.wosac-oracle/bin/python]
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

import tempfile

from bench_env import SHARED

SCENARIOS = SHARED / "womd" / "motion_data_one_scenario.tfrecord"
SUBMISSION = SHARED / "golden" / "637f20cafde22ff8__official_test_submission.binproto"
CONFIGS = {
    "sim_agents": SHARED / "official-configs" / "challenge_2025_sim_agents_config.textproto",
    "scenario_gen": SHARED / "official-configs" / "challenge_2025_scenario_gen_config.textproto",
}

# Runs inside the oracle venv: only calls the official API.
_OFFICIAL = """
import json, os, sys, time
os.environ["TF_CPP_MIN_LOG_LEVEL"] = "3"
import tensorflow as tf
tf.config.set_visible_devices([], "GPU")
from google.protobuf import text_format
from waymo_open_dataset.protos import scenario_pb2, sim_agents_submission_pb2, sim_agents_metrics_pb2
from waymo_open_dataset.wdl_limited.sim_agents_metrics import metrics
from waymo_open_dataset.utils.sim_agents import submission_specs
scenarios, submission, config, repeat = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
challenge = submission_specs.ChallengeType(sys.argv[5])
if os.environ.get("WOSAC_ONE_THREAD"):
    tf.config.threading.set_intra_op_parallelism_threads(1)
    tf.config.threading.set_inter_op_parallelism_threads(1)
cfg = text_format.Parse(open(config).read(), sim_agents_metrics_pb2.SimAgentMetricsConfig())
rollouts = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(open(submission, "rb").read()).scenario_rollouts[0]
scenario = next(s for s in (scenario_pb2.Scenario.FromString(r.numpy()) for r in tf.data.TFRecordDataset(scenarios))
                if s.scenario_id == rollouts.scenario_id)
metrics.compute_scenario_metrics_for_bundle(cfg, scenario, rollouts, challenge)  # warm-up
times = []
for _ in range(repeat):
    t = time.perf_counter()
    m = metrics.compute_scenario_metrics_for_bundle(cfg, scenario, rollouts, challenge)
    times.append(time.perf_counter() - t)
print(json.dumps({"times": times, "metametric": float(m.metametric)}))
"""

_OURS = """
import json, sys, time
from wosac_eval.runtime.allocator import keep_freed_memory
from wosac_eval.metrics.config import load_config
from wosac_eval.scoring.scenario import score_scenario
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import sim_agents_submission_pb2
keep_freed_memory()
rollouts = sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(open(sys.argv[2], "rb").read()).scenario_rollouts[0]
scenario = next(s for s, _ in iter_scenarios(sys.argv[1]) if s.scenario_id == rollouts.scenario_id)
challenge = sys.argv[5]
config = load_config(sys.argv[3])  # parsed once, as the official side parses its config
score_scenario(scenario, rollouts, config, challenge=challenge)  # warm-up
times = []
for _ in range(int(sys.argv[4])):
    t = time.perf_counter()
    m = score_scenario(scenario, rollouts, config, challenge=challenge)
    times.append(time.perf_counter() - t)
print(json.dumps({"times": times, "metametric": m["metametric"]}))
"""


def _run(python: str, code: str, inputs: tuple, repeat: int, env: dict | None = None, prefix: tuple = ()) -> dict:
    scenarios, submission, config, challenge = inputs
    out = subprocess.run(
        [*prefix, python, "-c", code, str(scenarios), str(submission), str(config), str(repeat), challenge],
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
    )
    if out.returncode:
        sys.exit(f"{python} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def scenario_gen_inputs(folder: Path) -> tuple:
    """The 34-object synthetic scene and a log-replay scenario-gen submission for it, written to `folder`."""
    from wosac_eval.protos import sim_agents_submission_pb2
    from wosac_eval.arrays.messages import rollouts_message
    from wosac_eval.sim import scenes
    from wosac_eval.sim.baselines import policy_rollouts

    scene = scenes.generate_scene(5, 6)
    shard = scenes.write_scenario_shards([scene], folder, num_shards=1)[0]
    rollouts = policy_rollouts(scene, "log_replay_noise", challenge="scenario_gen")
    submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission(scenario_rollouts=[rollouts_message(rollouts)])
    path = folder / "scenario_gen.binproto"
    path.write_bytes(submission.SerializeToString())
    return shard, path, rollouts.object_id.shape[1]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--oracle-python",
        default=os.environ.get("WOSAC_ORACLE_PYTHON", str(Path.home() / ".wosac-oracle" / "bin" / "python")),
    )
    p.add_argument("--challenge", choices=("sim_agents", "scenario_gen"), default="sim_agents")
    p.add_argument("--repeat", type=int, default=3, help="timed calls of each, after one warm-up call")
    p.add_argument(
        "--official-one-core",
        action="store_true",
        help="run the official code on one core too (one TensorFlow thread, pinned to CPU 0)",
    )
    args = p.parse_args()
    if not Path(args.oracle_python).exists():
        print(f"no oracle venv at {args.oracle_python}: run `bash ../shared/oracle/setup.sh` first")
        return 2
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        if args.challenge == "scenario_gen":
            scenarios, submission, objects = scenario_gen_inputs(Path(tmp))
            what = f"synthetic scene of {objects} objects (all evaluated), 32 rollouts of 91 steps, scenario_gen_2025"
        else:
            scenarios, submission = SCENARIOS, SUBMISSION
            what = "scenario 637f20cafde22ff8 (50 sim agents, 4 evaluated), 32 rollouts, 2025 config"
        inputs = (scenarios, submission, CONFIGS[args.challenge], args.challenge)
        one_core = args.official_one_core
        official = _run(
            args.oracle_python,
            _OFFICIAL,
            inputs,
            args.repeat,
            env={"WOSAC_ONE_THREAD": "1"} if one_core else None,
            prefix=("taskset", "-c", "0") if one_core else (),
        )
        ours = _run(sys.executable, _OURS, inputs, args.repeat, env={"OMP_NUM_THREADS": "1"})
    o, w = statistics.median(official["times"]), statistics.median(ours["times"])
    print(f"{what} ({os.cpu_count()} cores)")
    cores = "one core" if one_core else "all cores"
    print(
        f"  official (TensorFlow, {cores}): {o:8.2f} s per scenario  (runs: "
        f"{', '.join(f'{t:.1f}' for t in official['times'])})"
    )
    print(
        f"  wosac-eval (numpy, one core):     {w:8.4f} s per scenario  (median of {len(ours['times'])}: "
        f"{', '.join(f'{t:.3f}' for t in ours['times'])})"
    )
    print(f"  speed-up: {o / w:.0f}x  (each: one warm-up call, then {args.repeat} timed calls)")
    print(
        f"  meta-metric: official {official['metametric']:.7f}, ours {ours['metametric']:.7f}, "
        f"|difference| {abs(official['metametric'] - ours['metametric']):.1e}"
    )
    print(f"  ({time.perf_counter() - start:.0f} s in all)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
