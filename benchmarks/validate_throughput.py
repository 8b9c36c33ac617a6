"""Throughput and peak memory of `validate_submission` on a many-scenario .tar.gz.

Builds, in a temporary folder, a scenario set of N copies of the real WOMD
scenario 637f20cafde22ff8 (renamed scenario ids) and a matching submission: the
golden ScenarioRollouts replicated under the N ids, packed into shards of
--per-shard scenarios in a .tar.gz. Then validates it in a fresh child process
and prints scenarios/s and the child's peak RSS (resource.getrusage), next to
its RSS right before validating (after imports), so the memory the validation
itself needs is visible. Run with two sizes to see that the peak does not grow
with the number of scenarios (only with the shard size):

    .venv/bin/python benchmarks/validate_throughput.py --scenarios 100
    .venv/bin/python benchmarks/validate_throughput.py --scenarios 400
    .venv/bin/python benchmarks/validate_throughput.py --scenarios 100 --workers 2

Needs ../shared (golden/ and womd/).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_env import REPO  # noqa: E402


def _peak_rss_mib() -> float:
    # Linux keeps ru_maxrss across exec, so the parent that spawns the child
    # must stay small itself: it builds the data in another child (see main).
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def build(folder: Path, n_scenarios: int, per_shard: int, case: str) -> tuple[Path, Path]:
    """Write the scenario set (N renamed scenarios) and the .tar.gz submission (N replicated rollouts)."""
    from support.submissions import GOLDEN, WOMD, replicated_submission

    if not (GOLDEN.is_dir() and WOMD.is_dir()):
        sys.exit(f"needs the reference data in {GOLDEN.parent} (golden/ and womd/)")
    return replicated_submission(folder, n_scenarios, per_shard, case)


def child(scenario_file: str, archive: str, workers: int) -> None:
    """Validate once and print a JSON line of figures (runs in a fresh process)."""
    from wosac_eval.validate import validate_submission

    rss_before = _peak_rss_mib()
    start = time.perf_counter()
    report = validate_submission([scenario_file], archive, workers=workers)
    wall = time.perf_counter() - start
    print(
        json.dumps(
            {
                "valid": report.ok,
                "errors": report.error_count,
                "scenarios": report.stats.scenarios_submitted,
                "shards": report.stats.shards,
                "bytes_read": report.stats.bytes_read,
                "wall_s": wall,
                "rss_before_mib": rss_before,
                "peak_rss_mib": _peak_rss_mib(),
                # the largest peak among the worker processes (0 without workers)
                "worker_peak_rss_mib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
            }
        )
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenarios", type=int, default=100)
    parser.add_argument("--per-shard", type=int, default=25, help="scenarios per shard (default 25)")
    parser.add_argument("--case", default="637f20cafde22ff8__logreplay", help="golden case to replicate")
    parser.add_argument("--workers", type=int, default=1, help="worker processes of validate_submission (default 1)")
    parser.add_argument("--child", nargs=2, metavar=("SCENARIOS", "ARCHIVE"), help=argparse.SUPPRESS)
    parser.add_argument("--build", metavar="FOLDER", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(*args.child, args.workers)
        return
    if args.build:
        build(Path(args.build), args.scenarios, args.per_shard, args.case)
        return
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                __file__,
                "--build",
                tmp,
                "--scenarios",
                str(args.scenarios),
                "--per-shard",
                str(args.per_shard),
                "--case",
                args.case,
            ],
            check=True,
        )
        built = time.perf_counter() - start
        scenario_file = Path(tmp) / f"scenarios-{args.scenarios}.tfrecord"
        archive = Path(tmp) / f"submission-{args.scenarios}.tar.gz"
        out = subprocess.run(
            [sys.executable, __file__, "--child", str(scenario_file), str(archive), "--workers", str(args.workers)],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        figures = json.loads(out.strip().splitlines()[-1])
        size = archive.stat().st_size
    if not figures["valid"] or figures["scenarios"] != args.scenarios:
        sys.exit(f"unexpected result: {figures}")
    print(
        f"submission: {args.scenarios} scenarios in {figures['shards']} shard(s) of {args.per_shard}, "
        f"{size / 2**20:.1f} MiB .tar.gz ({figures['bytes_read'] / 2**20:.1f} MiB of shards); built in {built:.1f} s"
    )
    print(
        f"validated in {figures['wall_s']:.2f} s: {args.scenarios / figures['wall_s']:.1f} scenarios/s "
        f"({figures['bytes_read'] / 2**20 / figures['wall_s']:.1f} MiB/s of shard bytes), valid={figures['valid']}"
    )
    workers = f", each of {args.workers} workers {figures['worker_peak_rss_mib']:.0f} MiB" if args.workers > 1 else ""
    print(
        f"peak RSS {figures['peak_rss_mib']:.0f} MiB{workers} (RSS after imports, before validating: "
        f"{figures['rss_before_mib']:.0f} MiB; one shard is {figures['bytes_read'] / figures['shards'] / 2**20:.1f} MiB)"
    )


if __name__ == "__main__":
    main()
