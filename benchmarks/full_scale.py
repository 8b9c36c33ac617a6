"""Full scale: a validation-size workload in the official layout, and every path measured on it.

The workload (cached in --workdir, rebuilt only when its parameters change):

- a scenario set of N scenarios (default 44,097, the WOMD validation set) as TFRecord shards
  `validation.tfrecord-0000k-of-0000S` (S: 150 at full size, the official count; about 294 scenarios
  per shard at any size);
- the matching submission in the official layout: one `submission.tar.gz` holding the shards
  `submission.binproto-0000k-of-0000S`, shard k covering the scenarios of scenario shard k, each a
  `SimAgentsChallengeSubmission` with every metadata field the challenge asks for.

The N scenarios are copies of a pool of base scenes, taken in turn: the two real WOMD scenes of
../shared (with their golden 32-rollout submissions) and `--synthetic` scenes of `wosac_eval.sim`
(one per recipe, with `idm` rollouts), every copy under its own 16-hex-digit scenario id. Each base
is serialised once with a placeholder id; a copy is its bytes with the 16 id bytes replaced (the
same length, so no varint moves). The TFRecord CRC32C of a copy is one pass of the hardware CRC;
the submission's gzip stream is stitched from each base's rollouts deflated once (raw deflate,
sync-flushed, so that pieces concatenate) and stored blocks for what changes per copy (the
`scenario_rollouts` field header and id, tar headers, shard metadata), with the gzip CRC32 computed
over the raw bytes. Memory stays at the pool's size whatever N is; the build is bound by disk speed.

Then each path runs as its own subprocess, sampled every 0.2 s for the peak RSS (VmHWM) of every
process of its tree and the disk use of the folders it writes:

- validate:  `wosac-eval validate --json --workers K`
- cli:       `wosac-eval score --workers K -o result.json` (default analysis), the first run against the
             scenario set: every path but cli-again starts with an empty criticality cache
             (`WORKDIR/runs/criticality.sqlite3`, `analysis.criticality_cache`)
- cli-again: the same command again, the scenes' criticality kept by the cli path read from the cache
             (what scoring the next checkpoint against the same set costs); with the core in the same
             run, its CPU per scene over the core too
- core:      the scoring core the cli path is measured against: one copy of each base scene scored on
             one core (`score_scenario` of its protobuf bytes, parsing included, as `score_speed.py`
             measures one scene: median of --core-repeat runs after a warm-up), weighted by the base's
             copies; with the cli path in the same run, the cli path's CPU per scene over it
- cli-objects: the same with `--per-object`: every evaluated object's values streamed through the run's
             journal into the side file `result.objects.jsonl`; its size, its objects, and its wall and
             CPU time against the cli path's of the same run (the goal: at most 10 % more, in bounded memory)
- service:   `wosac-server serve` (API + 1 worker, K scoring processes per job) on 127.0.0.1 with a
             temporary data dir; the submission uploaded with `wosac_eval.client.submit` (a resumable
             httpx upload of 64 MiB chunks when that client is not installed), scored and published
- ray:       `score_submission(engine="ray")` on a `ray.cluster_utils.Cluster` (a head without
             CPUs and K+1 nodes of one CPU), one node killed without warning at --ray-kill-at of the
             scenarios; inside a loopback-only network (and PID) namespace (`unshare`, as root)
- interrupt: the cli command killed (SIGKILL, its whole process group) once its journal
             (`result.json.journal`) holds --interrupt-at of the scenarios, then run again: the
             extra cost of the interruption

and every scoring path's result document is compared with the first one got on this workload, in
this run or an earlier one (`WORKDIR/runs/reference.json`; --new-reference forgets it): per-scenario
rows, buckets, aggregate and the rest, timing fields aside. Copies of one base scene must score
alike, and the real scenes' copies are checked against the official implementation's golden
meta-metric. A folder's disk use is its allocated blocks.

`--challenge scenario_gen` does the same for the Scenario Generation challenge (in its own default workdir,
`full-scale-scenario_gen`): each submission holds 32 rollouts of all 91 steps of every object valid at step
10, with per-step box sizes, validity and object type, and every path runs with `--challenge scenario_gen`
(the service's upload and leaderboard, Ray's `score_submission(challenge=...)` alike). Its base pool: the
synthetic scenes of ../shared/golden/scenario_gen/scenes with their golden submissions (each copy checked
against the official implementation's `scenario_gen_2025` meta-metric), the two real WOMD scenes with
baseline rollouts (`log_replay_noise`, `constant_velocity`; there is no golden for them: the official code
ran out of memory) and `--synthetic` scenes of `wosac_eval.sim` with `idm` rollouts, the rollouts made by
`wosac_eval.sim.baselines.policy_rollouts(..., challenge="scenario_gen")` (with the per-step `valid` the
baselines leave out added, all true, as in the golden submissions).

Usage:
  python benchmarks/full_scale.py [--scenes 44097] [--paths validate,cli,service,ray,interrupt]
      [--workdir DIR] [--workers K] [--synthetic 10] [--shards S] [--json summary.json]
  python benchmarks/full_scale.py --scenes 2000 --paths none      # build (or reuse) only
  python benchmarks/full_scale.py --challenge scenario_gen --scenes 4000 --paths validate,cli,service

Never fills the disk: the build, and each path that writes a copy of the submission (the service),
first check that at least --disk-margin-gb (default 20) stay free after it, and stop or skip saying so.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path

from bench_env import SHARED, VALIDATION_SET
from full_scale_bases import CHALLENGES, REAL_BASES, SG_CONFIG
from full_scale_build import OFFICIAL_SHARDS, PER_SHARD, build, print_build
from full_scale_paths import Context, path_cli, path_cli_objects, path_core, path_interrupt, path_validate
from full_scale_remote import path_ray, path_service
from full_scale_watch import MiB
from wosac_eval.runtime.cache_dirs import user_cache_dir

# The workload is built by full_scale_bases.py (the pool of base scenes) and full_scale_build.py (the files);
# each path runs as full_scale_paths.py (this machine) or full_scale_remote.py (the service, Ray) says,
# watched and compared as full_scale_watch.py measures.
ALL_PATHS = ("validate", "cli", "cli-again", "core", "cli-objects", "service", "ray", "interrupt")
PATH_RUNNERS: dict[str, Callable[[Context], dict]] = {
    "validate": path_validate,
    "cli": path_cli,
    "cli-again": lambda ctx: path_cli(ctx, "cli-again"),
    "core": path_core,
    "cli-objects": path_cli_objects,
    "service": path_service,
    "ray": path_ray,
    "interrupt": path_interrupt,
}


def _fmt_peaks(peaks: dict) -> str:
    parts = []
    for role, r in peaks.items():
        if r["count"] == 1:
            parts.append(f"{role} {r['max_mib']:.0f}")
        else:
            many = f"{r['count']}" if r["at_once"] == r["count"] else f"{r['at_once']} at a time ({r['count']} in all)"
            parts.append(f"{role} {many} <= {r['max_mib']:.0f}")
    return ", ".join(parts) + " MiB"


def golden_metametrics(manifest: dict) -> dict[int, float]:
    """{base index: the official implementation's 2025 meta-metric} of the real bases (../shared/golden); for
    Scenario Generation, its `scenario_gen_2025` meta-metric of the golden bases (../shared/golden/scenario_gen)."""
    out = {}
    if manifest["key"].get("challenge") == "scenario_gen":
        for b, base in enumerate(manifest["bases"]):
            path = SHARED / "golden" / "scenario_gen" / f"{base.get('golden')}.json"
            if base.get("golden") and path.exists():
                out[b] = json.loads(path.read_text())["metrics"][SG_CONFIG]["metametric"]
        return out
    for b, base in enumerate(manifest["bases"]):
        for sid, _, golden in REAL_BASES:
            if base["name"].startswith(sid):
                path = SHARED / "golden" / f"{golden}.json"
                if path.exists():
                    out[b] = json.loads(path.read_text())["metrics"]["2025"]["metametric"]
    return out


def print_table(rows: list[dict], manifest: dict) -> None:
    n = manifest["scenes"]
    print(
        f"\n{n} scenarios, {os.cpu_count()} cores; peak RSS from each process's VmHWM (sampled every 0.2 s); "
        f"CPU: user + system seconds of the path's processes (service: the upload client and the job); "
        f"disk: allocated bytes the path wrote (peak); load: the 1-minute load average before-after"
    )
    print(
        f"{'path':11s} {'wall s':>8s} {'scenes/s':>8s} {'CPU s':>7s} {'disk MiB':>9s} {'same result':>11s} "
        f"{'load':>9s}  peak RSS per process"
    )
    for r in rows:
        if "skipped" in r or "failed" in r:
            print(f"{r['path']:11s} {'skipped: ' + r['skipped'] if 'skipped' in r else 'FAILED: ' + r['failed'][:300]}")
            continue
        load = f"{r['load_before']:.1f}-{r['load_after']:.1f}"
        print(
            f"{r['path']:11s} {r['wall_s']:8.1f} {r['scenes_per_s']:8.1f} {r['cpu_s']:7.0f} "
            f"{r['disk_bytes'] / MiB:9.1f} {r['same']:>11s} {load:>9s}  {_fmt_peaks(r['peak_rss'])}"
        )
    print()
    for r in rows:
        if "skipped" not in r and "failed" not in r:
            print(f"{r['path']:11s} {r['what']}: {r['note'].lstrip('; ')}")
    digests = [r["digest"] for r in rows if "digest" in r]
    if digests:
        d = digests[0]
        print(
            f"\nresult: meta-metric {d['metametric']:.4f} over {d['num_scenarios']} scenarios; copies of each base "
            f"scene scored alike: {'yes' if all(x['copies_alike'] for x in digests) else 'NO'}; per base: "
            + ", ".join(f"{m:.4f}" for m in d["base_metametric"].values() if m is not None)
        )
        for b, official in golden_metametrics(manifest).items():
            ours = d["base_metametric"].get(b)
            if ours is not None:
                print(
                    f"  {manifest['bases'][b]['name']}: {ours:.6f}, the official implementation's (golden): "
                    f"{official:.6f} (diff {abs(ours - official):.1e})"
                )


def _arguments(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--challenge",
        choices=CHALLENGES,
        default="sim_agents",
        help="the submission's challenge, and every path's --challenge (default %(default)s)",
    )
    p.add_argument("--scenes", type=int, default=VALIDATION_SET, help="scenarios (default %(default)s)")
    p.add_argument(
        "--paths",
        default=",".join(ALL_PATHS),
        help=f"comma-separated, run in this order (default {','.join(ALL_PATHS)}); 'none': build only",
    )
    cache = user_cache_dir()
    p.add_argument(
        "--workdir",
        type=Path,
        default=None,
        help=f"where the workload is cached and the paths write (default {cache / 'full-scale'}; "
        f"with --challenge scenario_gen, {cache / 'full-scale-scenario_gen'})",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=os.cpu_count() or 1,
        help="processes per path: validate and score --workers, the service's processes per job, "
        "the Ray cluster's nodes (plus one, the node killed) (default: the cores, %(default)s)",
    )
    p.add_argument("--synthetic", type=int, default=10, help="synthetic base scenes, one per recipe (default 10)")
    p.add_argument(
        "--shards",
        type=int,
        default=None,
        help=f"shards of the scenario set and the submission (default: {PER_SHARD} scenarios per shard, "
        f"{OFFICIAL_SHARDS} at {VALIDATION_SET})",
    )
    p.add_argument("--seed", type=int, default=11, help="synthetic scenes and scenario ids")
    p.add_argument(
        "--interrupt-at",
        type=float,
        default=0.8,
        help="share of the scenarios journaled when the interrupt path kills the run (default 0.8)",
    )
    p.add_argument(
        "--ray-kill-at",
        type=float,
        default=0.5,
        help="share of the scenarios scored when the ray path kills a node (default 0.5)",
    )
    p.add_argument("--core-repeat", type=int, default=5, help="runs of each base scene in the core path (default 5)")
    p.add_argument("--ray-timeout", type=float, default=7200.0)
    p.add_argument("--service-timeout", type=float, default=7 * 3600.0)
    p.add_argument(
        "--disk-margin-gb",
        type=float,
        default=20.0,
        help="free space the build and the service path must leave (default 20)",
    )
    p.add_argument(
        "--new-reference",
        action="store_true",
        help="compare with this run's first result only, not with the first result an earlier run "
        "got on the same cached workload (kept in WORKDIR/runs/reference.json)",
    )
    p.add_argument("--json", type=Path, help="also write the build's sizes and every row here")
    args = p.parse_args(argv)
    if args.workdir is None:
        args.workdir = cache / ("full-scale" if args.challenge == "sim_agents" else f"full-scale-{args.challenge}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = _arguments(argv)
    if not ((SHARED / "womd").is_dir() and (SHARED / "golden").is_dir()):
        sys.exit(f"needs the reference data in {SHARED} (womd/ and golden/): the real base scenes")
    if args.challenge == "scenario_gen" and not (SHARED / "golden" / "scenario_gen" / "scenes").is_dir():
        sys.exit(
            f"needs the reference data in {SHARED / 'golden' / 'scenario_gen'} (its scenes/ and golden "
            f"submissions): the golden base scenes of --challenge scenario_gen"
        )
    if args.scenes < 1 or args.workers < 1 or args.synthetic < 0:
        sys.exit("--scenes and --workers must be >= 1, --synthetic >= 0")
    paths = [] if args.paths == "none" else [s.strip() for s in args.paths.split(",") if s.strip()]
    unknown = sorted(set(paths) - set(ALL_PATHS))
    if unknown:
        sys.exit(f"unknown path(s) {', '.join(unknown)}; choose from {', '.join(ALL_PATHS)}")
    args.shards = args.shards or max(1, min(args.scenes, round(args.scenes / PER_SHARD)))
    args.workdir = args.workdir.resolve()

    manifest = build(args)
    print_build(manifest, args.workdir)
    ctx = Context(args, manifest)
    rows = [run_path(ctx, path) for path in paths]
    if rows:
        print_table(rows, manifest)
        if ctx.reference_from:
            print(f"(same result: compared with {ctx.reference_from})")
    if args.json:
        args.json.write_text(
            json.dumps(
                {"build": manifest, "workers": args.workers, "rows": rows, "reference": ctx.reference_from}, indent=1
            )
        )
    failed = [r["path"] for r in rows if "skipped" not in r and not r["ok"]]
    if failed:
        print(f"\nFAILED: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


def run_path(ctx: Context, path: str) -> dict:
    """One path's row: measured, skipped (saying why), or failed (its error; the other paths still run)."""
    print(f"[{path}] running...", flush=True)
    ctx.load_before = os.getloadavg()[0]
    if path != "cli-again":
        ctx.empty_criticality_cache()
    try:
        row = PATH_RUNNERS[path](ctx)
    except Exception as error:  # noqa: BLE001 - one path's failure is a row; the others still run
        row = {"path": path, "failed": f"{type(error).__name__}: {error}"[-2000:], "ok": False}
        print(f"[{path}] FAILED: {row['failed']}", flush=True)
        return row
    if "skipped" not in row:
        print(
            f"[{path}] {row['wall_s']:.1f} s, {row['scenes_per_s']:.1f} scenes/s, same result: {row['same']}",
            flush=True,
        )
    return row


if __name__ == "__main__":
    sys.exit(main())
