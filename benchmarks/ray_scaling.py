"""Throughput on Ray against local worker processes, a simulated cluster, and a projection for 44,097 scenarios.

Workload: `--scenarios` renamed copies of the real scenario 637f20cafde22ff8 and
its official 32-rollout submission (../shared), as a folder of shards (the
layout workers read by byte ranges), validated and scored by
`score_submission`. Each row runs in a fresh process and times the whole call
(indexing, validation, scoring, assembly); Ray's start-up is timed apart.

Rows:
- local: `--workers k` processes of this host;
- ray: a local Ray with k CPUs (`ray.init(num_cpus=k)`), same k: the overhead of the engine;
- cluster: `ray.cluster_utils.Cluster`, a head without CPUs and k nodes of one CPU each.

Every result must be identical to the one-worker local result. The
projection takes the measured per-scenario cost on one core (validation
included), the measured Ray overhead, and the driver's serial share, for N
machines of 16 cores. Ray binds to the machine's interface address: as root the
script re-runs itself inside a network namespace with only loopback (`unshare -n`).

Usage: python benchmarks/ray_scaling.py [--scenarios 48] [--cores 1 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench_env import REPO, VALIDATION_SET  # noqa: F401  (puts tests/support on the path)
from support.submissions import replicated_submission

_CHILD = r"""
import json, os, sys, time
kind, k, scenarios, submission = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
from wosac_eval.scoring.submission import score_submission
started = time.perf_counter()
address = None
if kind == "ray":
    import ray
    # "local": without it Ray joins whatever /tmp/ray/ray_current_cluster names, even a cluster gone.
    ray.init(address="local", num_cpus=k, include_dashboard=False, log_to_driver=False)
elif kind == "cluster":
    import ray
    from ray.cluster_utils import Cluster
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 0})
    for _ in range(k):
        cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    address = cluster.address
    ray.init(address=address, log_to_driver=False)
startup = time.perf_counter() - started
engine = "local" if kind == "local" else "ray"
if engine == "ray":  # warm the workers (imports), as the local pool's fork inherits them
    score_submission([scenarios], submission, engine="ray", ray_address=address)
t = time.perf_counter()
result = score_submission([scenarios], submission, workers=k, engine=engine, ray_address=address)
seconds = time.perf_counter() - t
t = time.perf_counter()
from wosac_eval.parse.scenarios import ScenarioIndex
ScenarioIndex([scenarios])
index_seconds = time.perf_counter() - t
print(json.dumps({"seconds": seconds, "startup": startup, "index_seconds": index_seconds,
                  "result": json.dumps(result, sort_keys=True)}))
if kind != "local":
    ray.shutdown()
if kind == "cluster":
    cluster.shutdown()  # its processes, and the /tmp/ray/ray_current_cluster it wrote
"""


def _in_loopback_namespace() -> bool:
    return os.environ.get("WOSAC_BENCH_NETNS") == "1"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", type=int, default=48)
    p.add_argument("--per-shard", type=int, default=8)
    p.add_argument("--cores", type=int, nargs="+", default=[1, 2])
    args = p.parse_args()
    if not _in_loopback_namespace() and os.geteuid() == 0:
        inner = f"ip link set lo up && exec {sys.executable} {' '.join(map(str, sys.argv))}"
        return subprocess.run(
            ["unshare", "-n", "bash", "-c", inner],
            env={**os.environ, "WOSAC_BENCH_NETNS": "1", "RAY_DISABLE_USAGE_STATS": "1"},
        ).returncode
    with tempfile.TemporaryDirectory() as tmp:
        scenarios, submission = replicated_submission(Path(tmp), args.scenarios, args.per_shard, layout="folder")
        rows, reference = [], None
        for kind in ("local", "ray", "cluster"):
            for k in args.cores:
                out = subprocess.run(
                    [sys.executable, "-c", _CHILD, kind, str(k), str(scenarios), str(submission)],
                    capture_output=True,
                    text=True,
                    env={**os.environ, "OMP_NUM_THREADS": "1"},
                )
                if out.returncode:
                    sys.exit(f"{kind} {k} failed:\n{out.stderr[-3000:]}")
                row = json.loads(out.stdout.strip().splitlines()[-1])
                reference = reference or row["result"]
                rows.append((kind, k, row, row["result"] == reference))
    n = args.scenarios
    print(
        f"{n} scenarios (637f20cafde22ff8 x {n}, 32 rollouts, {args.per_shard} per shard, a folder of shards); "
        f"{os.cpu_count()} cores on this machine"
    )
    print(
        f"{'engine':8s} {'cores':>5s} {'s/scenario':>10s} {'scenarios/s':>11s} {'vs local':>8s} "
        f"{'start-up s':>10s} {'identical':>9s}"
    )
    local = {k: row["seconds"] for kind, k, row, _ in rows if kind == "local"}
    for kind, k, row, same in rows:
        ratio = row["seconds"] / local[k]
        print(
            f"{kind:8s} {k:5d} {row['seconds'] / n:10.4f} {n / row['seconds']:11.1f} {ratio:8.2f} "
            f"{row['startup']:10.1f} {'yes' if same else 'NO':>9s}"
        )
    # Projection: the per-scenario cost on one core, Ray's overhead at the largest core count, and the
    # driver's serial share (indexing the scenario set; the rest runs in the workers).
    k = max(args.cores)
    cost = local[1] / n if 1 in local else local[k] * k / n
    overhead = next(row["seconds"] for kind, kk, row, _ in rows if kind == "ray" and kk == k) / local[k] - 1
    serial = next(row["index_seconds"] for kind, _, row, _ in rows if kind == "local") / n
    print(
        f"\nprojection for {VALIDATION_SET} scenarios: {cost:.3f} s per scenario on one core, Ray overhead "
        f"{100 * overhead:+.0f}% at {k} cores, driver's serial share {1000 * serial:.1f} ms per scenario"
    )
    for machines in (1, 2, 4, 8, 16):
        cores = 16 * machines
        minutes = VALIDATION_SET * (serial + cost * (1 + max(overhead, 0)) / cores) / 60
        print(f"  {machines:2d} machine(s) x 16 cores: {minutes:6.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
