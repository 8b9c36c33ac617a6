"""numpy vs jax backend, side by side: seconds per scenario, scenarios per second, compile time, RSS.

Usage:
  python benchmarks/score_backends.py [--repeat N] [--copies K] [--max-batch B]

Two workloads, from parsed arrays to per-scenario metrics (parsing excluded):
  * golden: the real scenario 637f20cafde22ff8 (50 agents, 5251 road-edge
    segments) with its official 32-rollout test submission (../shared);
  * batch: the 7 synthetic oracle scenes of tests/data/oracle, `--copies`
    times each (a stream of small scenarios, batched per size bucket).
For jax, the first call (which compiles one function per bucket) is reported
apart from the steady-state calls. Peak RSS is sampled after each backend.
"""

from __future__ import annotations

import argparse
import gzip
import os
import resource
import time

from bench_env import REPO, SHARED, median_seconds

ORACLE = REPO / "tests" / "data" / "oracle"

import jax  # noqa: E402

from wosac_eval.backends import jax_backend  # noqa: E402

jax_backend.exact_cpu()  # this program opts in to exact float32 on XLA's CPU, as the CLI does

from wosac_eval.arrays.rollouts import rollout_arrays  # noqa: E402
from wosac_eval.arrays.scenario import scenario_arrays  # noqa: E402
from wosac_eval.features.metric_features import scenario_features  # noqa: E402
from wosac_eval.metrics.config import load_config  # noqa: E402
from wosac_eval.metrics.scenario_metrics import scenario_metrics  # noqa: E402
from wosac_eval.parse.scenarios import iter_scenarios  # noqa: E402
from wosac_eval.protos import sim_agents_submission_pb2  # noqa: E402

CONFIG = load_config("2025")


def _rollouts(raw: bytes):
    return sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw).scenario_rollouts[0]


def golden_pairs():
    if not (SHARED / "golden").is_dir():
        return []
    scenarios = {s.scenario_id: s for s, _ in iter_scenarios(SHARED / "womd")}
    r = _rollouts((SHARED / "golden" / "637f20cafde22ff8__official_test_submission.binproto").read_bytes())
    return [(scenario_arrays(scenarios[r.scenario_id]), rollout_arrays(r))]


def oracle_pairs(copies: int):
    scenarios = {s.scenario_id: s for s, _ in iter_scenarios(ORACLE / "scenes")}
    pairs = []
    for path in sorted(ORACLE.glob("*.binproto.gz")):
        r = _rollouts(gzip.decompress(path.read_bytes()))
        pairs.append((scenario_arrays(scenarios[r.scenario_id]), rollout_arrays(r)))
    return pairs * copies


def score_numpy(pairs):
    return [scenario_metrics(CONFIG, *scenario_features(s, r)) for s, r in pairs]


def score_jax(pairs, max_batch: int):
    features = jax_backend.scenarios_features(pairs, max_batch=max_batch)
    return [scenario_metrics(CONFIG, log, sim) for log, sim in features]


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _row(label, n, seconds, compile_s=None):
    extra = "" if compile_s is None else f"   first call (compiles) {compile_s:7.2f} s"
    print(f"  {label:<6s} {seconds / n:8.3f} s/scenario {n / seconds:8.2f} scenarios/s{extra}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="timed repetitions (median)")
    parser.add_argument("--copies", type=int, default=2, help="copies of the 7 oracle scenes in the batch")
    parser.add_argument("--max-batch", type=int, default=8, help="scenarios per jax call")
    args = parser.parse_args()
    device = jax.devices()[0]
    print(
        f"jax {jax.__version__} on {device.platform} ({device.device_kind}); {os.cpu_count()} CPUs; "
        f"fused multiply-add in XLA: {jax_backend.fma_contraction()}"
    )
    workloads = [("golden", golden_pairs()), (f"batch of {7 * args.copies}", oracle_pairs(args.copies))]
    workloads = [(name, pairs) for name, pairs in workloads if pairs]
    if len(workloads) == 1:
        print("(../shared is absent: golden workload skipped)")
    results = {}
    for name, pairs in workloads:
        n = len(pairs)
        print(f"{name}: {n} scenario(s)")
        numpy_s = median_seconds(lambda: score_numpy(pairs), args.repeat)
        rss_numpy = _rss_mib()
        _row("numpy", n, numpy_s)
        start = time.perf_counter()
        first = score_jax(pairs, args.max_batch)
        first_s = time.perf_counter() - start
        jax_s = median_seconds(lambda: score_jax(pairs, args.max_batch), args.repeat)
        _row("jax", n, jax_s, first_s)
        same = first == score_numpy(pairs)
        print(f"  jax/numpy time {jax_s / numpy_s:5.2f}x; metrics identical: {same}")
        results[name] = (rss_numpy, _rss_mib())
    print(
        f"peak RSS: {max(r[0] for r in results.values()):.0f} MiB after numpy, "
        f"{max(r[1] for r in results.values()):.0f} MiB after jax (process peak, cumulative)"
    )


if __name__ == "__main__":
    main()
