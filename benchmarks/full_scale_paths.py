"""The paths of benchmarks/full_scale.py that run on this machine alone, each as its own subprocess,
watched (`full_scale_watch`): validate, the CLI's score (and again, with --per-object, interrupted and
resumed), and the scoring core on one core; and the `Context` every path shares.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from bench_env import REPO
from full_scale_bases import base_pool, scenario_id
from full_scale_bases import Layout
from full_scale_watch import MiB, Run, by_depth, digest_result, run_watched, same_as

CRITICALITY_CACHE = "criticality.sqlite3"  # in WORKDIR/runs: emptied before every path but cli-again


class Context:
    """What every path of one run shares: the build and its manifest, the run's settings, the runs' folder
    and its criticality cache, the cli path's figures for the later paths, and the reference result."""

    def __init__(self, args, manifest: dict):
        self.build = args.workdir / "build"
        self.runs = args.workdir / "runs"
        self.runs.mkdir(parents=True, exist_ok=True)
        self.manifest = manifest
        self.challenge = args.challenge
        # the commands' flag: none for Sim Agents (each command's default), so its commands stay as they were
        self.challenge_args = [] if args.challenge == "sim_agents" else ["--challenge", args.challenge]
        self.challenge_flag = "".join(" " + a for a in self.challenge_args)
        self.layout = Layout(manifest["scenes"], manifest["shards"], manifest["seed"])
        self.pool_size = len(manifest["bases"])
        self.workers = args.workers
        self.disk_margin_gb = args.disk_margin_gb
        self.interrupt_at = args.interrupt_at
        self.core_repeat = args.core_repeat
        self.ray_kill_at = args.ray_kill_at
        self.ray_timeout = args.ray_timeout
        self.service_timeout = args.service_timeout
        self.criticality_cache = self.runs / CRITICALITY_CACHE  # the workload's own, never the user's
        self.cli_wall: float | None = None
        self.cli_cpu: float | None = None
        self.cli_again_cpu: float | None = None
        self.load_before = 0.0
        # The first result on this build is the reference of every later one, in this run or a later run
        # on the same cached build (so that paths measured one at a time are compared too).
        self.reference_file = self.runs / "reference.json"
        self.reference: dict | None = None
        self.reference_from = ""
        if self.reference_file.exists() and not args.new_reference:
            stored = json.loads(self.reference_file.read_text())
            if stored.get("build") == manifest["key"]:
                self.reference, self.reference_from = stored["digest"], stored["from"]

    def env(self) -> dict:
        """The environment of a path's commands: no WOSAC_ setting of the caller's, the workload's
        criticality cache, this tree on the path, one thread per process."""
        env = {k: v for k, v in os.environ.items() if not k.startswith("WOSAC_")}
        env["WOSAC_CRITICALITY_CACHE"] = str(self.criticality_cache)
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
        env.setdefault("OMP_NUM_THREADS", "1")
        return env

    def empty_criticality_cache(self) -> None:
        """A first run against the scenario set: no scene's criticality kept yet."""
        for suffix in ("", "-wal", "-shm"):
            Path(f"{self.criticality_cache}{suffix}").unlink(missing_ok=True)

    def row(self, path: str, what: str, run: Run, peaks: dict, disk: int) -> dict:
        return {
            "path": path,
            "what": what,
            "rc": run.rc,
            "wall_s": round(run.wall_s, 2),
            "cpu_s": round(run.cpu_s, 1),
            "load_before": self.load_before,
            "load_after": os.getloadavg()[0],
            "scenes_per_s": round(self.layout.scenes / run.wall_s, 2) if run.wall_s else None,
            "peak_rss": peaks,
            "disk_bytes": disk,
            "same": "-",
            "ok": run.rc == 0,
            "note": "",
        }

    def skipped(self, path: str, why: str) -> dict:
        print(f"[{path}] skipped: {why}", flush=True)
        return {"path": path, "skipped": why}

    def with_result(self, row: dict, result: Path, run: Run) -> dict:
        if run.rc != 0 or not result.exists():
            row["ok"] = False
            if not row["note"]:
                row["note"] = f"exit {run.rc}: {run.stderr.strip()[-500:]}"
            return row
        digest = digest_result(result, self.layout, self.pool_size)
        row["digest"] = digest
        row["disk_bytes"] = max(row["disk_bytes"], result.stat().st_blocks * 512)
        if self.reference is None:
            self.reference = digest
            self.reference_from = f"the {row['path']} path's result of {time.strftime('%Y-%m-%d %H:%M')}"
            self.reference_file.write_text(
                json.dumps({"build": self.manifest["key"], "from": self.reference_from, "digest": digest})
            )
            row["same"] = "reference"
        else:
            row["same"] = same_as(self.reference, digest)
        row["ok"] = row["ok"] and digest["num_scenarios"] == self.layout.scenes and row["same"] in ("yes", "reference")
        if not digest["copies_alike"]:
            row["note"] += "; copies of one base scene scored differently"
        result.unlink()  # a full-size result is large: its digest is what the comparison needs
        return row


PYTHON = os.path.abspath(sys.executable)  # ".." collapsed, symbolic links kept (a venv's python is one)


def _cli(*args: str) -> list[str]:
    return [PYTHON, "-m", "wosac_eval.fronts.cli", *args]


def workload_paths(build_dir: Path) -> tuple[Path, Path]:
    return build_dir / "scenarios", build_dir / "submission.tar.gz"


def path_validate(ctx: Context) -> dict:
    scenarios, submission = workload_paths(ctx.build)
    cmd = _cli(
        "validate",
        "--scenarios",
        str(scenarios),
        "--submission",
        str(submission),
        "--json",
        "--workers",
        str(ctx.workers),
        *ctx.challenge_args,
    )
    run = run_watched(cmd, ctx.runs, "validate", env=ctx.env())
    row = ctx.row(
        "validate",
        f"wosac-eval validate --workers {ctx.workers}{ctx.challenge_flag}",
        run,
        run.watch.peaks(by_depth("main", "workers")),
        disk=0,
    )
    try:
        report = json.loads(run.stdout)
        stats = report["stats"]
        row["note"] = (
            f"{'valid' if report['valid'] else 'INVALID'}, {report['errors']} error(s), "
            f"{report['warnings']} warning(s), {stats['scenarios_valid']}/{stats['scenarios_expected']} "
            f"scenarios valid"
        )
        row["ok"] = report["valid"] and stats["scenarios_valid"] == ctx.layout.scenes
    except (ValueError, KeyError):
        row["note"], row["ok"] = f"exit {run.rc}: {run.stderr.strip()[-300:]}", False
    return row


def _score_command(ctx: Context, scenarios: Path, submission: Path, out: Path, *extra: str) -> list[str]:
    """`wosac-eval score` of the workload with one worker per core into `out` (the cli, cli-objects and
    interrupt paths)."""
    return _cli(
        "score", "--scenarios", str(scenarios), "--submission", str(submission), "--workers", str(ctx.workers),
        *extra, "-o", str(out), *ctx.challenge_args,
    )  # fmt: skip


def path_cli(ctx: Context, name: str = "cli") -> dict:
    scenarios, submission = workload_paths(ctx.build)
    out = ctx.runs / name / "result.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)
    cmd = _score_command(ctx, scenarios, submission, out)
    run = run_watched(cmd, ctx.runs, name, env=ctx.env(), dirs={"out": out.parent})
    again = " (criticality kept by the cli path)" if name == "cli-again" else ""
    row = ctx.row(
        name,
        f"wosac-eval score --workers {ctx.workers}{ctx.challenge_flag} -o R.json{again}",
        run,
        run.watch.peaks(by_depth("main", "workers")),
        disk=run.watch.disk_peak["out"],
    )
    if name == "cli-again":
        ctx.cli_again_cpu = run.cpu_s if run.rc == 0 else None
    else:
        ctx.cli_wall = run.wall_s if run.rc == 0 else None
        ctx.cli_cpu = run.cpu_s if run.rc == 0 else None
    if out.exists():
        row["note"] = f"result document {out.stat().st_size / MiB:.1f} MiB"
    return ctx.with_result(row, out, run)


# One core, protobuf bytes in, metrics out: `stage_timing.score_bytes`, what benchmarks/score_speed.py times for
# one scene, here for each base scene of the workload (argv: benchmarks/, the folder of base-K.scenario /
# base-K.rollouts, repeats, challenge).
CORE_SCRIPT = """
import json, sys
from pathlib import Path
sys.path.insert(0, sys.argv[1])
from stage_timing import median_time, score_bytes
from wosac_eval import challenges
from wosac_eval.runtime.allocator import keep_freed_memory
from wosac_eval.scoring.scenario import resolve_config

keep_freed_memory()
folder, repeat, challenge = Path(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
config = resolve_config(None, challenges.as_challenge(challenge))
medians = []
for k in range(len(list(folder.glob("base-*.scenario")))):
    raw_scenario = (folder / f"base-{k}.scenario").read_bytes()
    raw_rollouts = (folder / f"base-{k}.rollouts").read_bytes()
    medians.append(median_time(lambda: score_bytes(raw_scenario, raw_rollouts, config, challenge), repeat)[0])
print(json.dumps(medians))
"""


def path_core(ctx: Context) -> dict:
    """The scoring core on one core: each base scene's median seconds, weighted by its copies."""
    pool = base_pool(ctx.manifest["key"]["synthetic"], ctx.manifest["key"]["seed"], ctx.challenge)
    folder = ctx.runs / "core"
    folder.mkdir(parents=True, exist_ok=True)
    for k, base in enumerate(pool):  # each base under a copy's id (the placeholder's length)
        sid = scenario_id(k, ctx.layout.seed).encode()
        (folder / f"base-{k}.scenario").write_bytes(base.scenario_head + sid + base.scenario_tail)
        (folder / f"base-{k}.rollouts").write_bytes(base.rollouts_head + sid + base.rollouts_tail)
    env = {**ctx.env(), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    cmd = [PYTHON, "-c", CORE_SCRIPT, str(Path(__file__).resolve().parent), str(folder), str(ctx.core_repeat),
           ctx.challenge]  # fmt: skip
    run = run_watched(cmd, ctx.runs, "core", env=env)
    row = ctx.row("core", f"score_scenario of each base scene, one core, median of {ctx.core_repeat}", run,
                  run.watch.peaks(by_depth("main")), disk=0)  # fmt: skip
    row["scenes_per_s"] = 0.0  # one core, not the run's wall: set below from the per-scene cost
    if run.rc != 0:
        row["ok"], row["note"] = False, f"exit {run.rc}: {run.stderr.strip()[-500:]}"
        return row
    medians = json.loads(run.stdout.strip().splitlines()[-1])
    copies = [len(range(k, ctx.layout.scenes, len(pool))) for k in range(len(pool))]  # copy i is base i % P
    per_scene = sum(m * c for m, c in zip(medians, copies)) / sum(copies)
    row["core_s_per_scene"] = per_scene
    row["scenes_per_s"] = round(1 / per_scene, 2)
    row["base_medians_s"] = medians
    row["note"] = (
        f"{per_scene * 1e3:.1f} ms per scene (bases {min(medians) * 1e3:.1f}-{max(medians) * 1e3:.1f} ms, "
        f"weighted by their copies)"
    )
    if ctx.cli_cpu is not None:
        cli = ctx.cli_cpu / ctx.layout.scenes
        row["cli_s_per_scene"] = cli
        row["cli_over_core"] = cli / per_scene
        row["note"] += f"; the cli path {cli * 1e3:.1f} ms per scene per core: {cli / per_scene:.2f}x the core"
    if ctx.cli_again_cpu is not None:
        again = ctx.cli_again_cpu / ctx.layout.scenes
        row["cli_again_s_per_scene"] = again
        row["cli_again_over_core"] = again / per_scene
        row["note"] += f"; again {again * 1e3:.1f} ms: {again / per_scene:.2f}x"
    return row


def path_cli_objects(ctx: Context) -> dict:
    """The cli path with `--per-object`: what the side file costs (time, memory, disk) over the plain run."""
    scenarios, submission = workload_paths(ctx.build)
    out = ctx.runs / "cli-objects" / "result.json"
    objects = out.with_name("result.objects.jsonl")
    out.parent.mkdir(parents=True, exist_ok=True)
    for stale in (out, objects, out.with_name(out.name + ".journal")):
        stale.unlink(missing_ok=True)
    cmd = _score_command(ctx, scenarios, submission, out, "--per-object")
    run = run_watched(cmd, ctx.runs, "cli-objects", env=ctx.env(), dirs={"out": out.parent})
    row = ctx.row(
        "cli-objects",
        f"wosac-eval score --workers {ctx.workers}{ctx.challenge_flag} --per-object -o R.json",
        run,
        run.watch.peaks(by_depth("main", "workers")),
        disk=run.watch.disk_peak["out"],
    )
    if out.exists() and objects.exists():
        size = objects.stat().st_size
        num_objects = json.loads(out.read_text()).get("per_object", {}).get("num_objects")
        row["objects_bytes"], row["num_objects"] = size, num_objects
        row["note"] = (
            f"result document {out.stat().st_size / MiB:.1f} MiB; side file {size / MiB:.1f} MiB "
            f"({num_objects} objects, {size / ctx.layout.scenes / 1024:.1f} KiB per scene)"
        )
        if ctx.cli_wall:
            row["vs_cli_wall"] = round(run.wall_s / ctx.cli_wall - 1, 4)
            row["vs_cli_cpu"] = round(run.cpu_s / ctx.cli_cpu - 1, 4) if ctx.cli_cpu else None
            row["note"] += f"; against the cli path: wall {100 * row['vs_cli_wall']:+.1f} %" + (
                f", CPU {100 * row['vs_cli_cpu']:+.1f} %" if row["vs_cli_cpu"] is not None else ""
            )
        else:
            row["note"] += "; run the cli path before it (--paths cli,cli-objects) for its cost relative to it"
        objects.unlink()  # large at full size: its size is what is reported
    elif run.rc == 0:
        row["ok"], row["note"] = False, "no side file written"
    return ctx.with_result(row, out, run)


def journal_available(ctx: Context) -> str | None:
    """Why the interruption row cannot run, or None (the journal of `wosac-eval score -o`)."""
    help_text = subprocess.run(_cli("score", "--help"), capture_output=True, text=True, env=ctx.env(), cwd=REPO).stdout
    if "journal" not in help_text:
        return (
            "`wosac-eval score -o R.json` keeps no journal in this checkout (R.json.journal), so a rerun cannot resume"
        )
    return None


def path_interrupt(ctx: Context) -> dict:
    why = journal_available(ctx)
    if why:
        return ctx.skipped("interrupt", why)
    scenarios, submission = workload_paths(ctx.build)
    folder = ctx.runs / "interrupt"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    out = folder / "result.json"
    journal = folder / "result.json.journal"
    cmd = _score_command(ctx, scenarios, submission, out)
    target = max(1, min(ctx.layout.scenes - 1, math.ceil(ctx.interrupt_at * ctx.layout.scenes)))
    state = {"offset": 0, "rows": -1, "killed_at": None}  # rows: lines after the journal's header

    def poll(proc: subprocess.Popen) -> None:
        if state["killed_at"] is not None or not journal.exists():
            return
        with open(journal, "rb") as f:
            f.seek(state["offset"])
            data = f.read()
        complete = data.rfind(b"\n") + 1
        state["offset"] += complete
        state["rows"] += data.count(b"\n", 0, complete)
        if state["rows"] >= target:
            os.killpg(proc.pid, signal.SIGKILL)  # the command and its worker processes, at once
            state["killed_at"] = state["rows"]

    first = run_watched(cmd, ctx.runs, "interrupt-1", env=ctx.env(), dirs={"out": folder}, poll=poll)
    if state["killed_at"] is None:
        return ctx.skipped(
            "interrupt",
            f"the run ended (exit {first.rc}) before its journal held {target} "
            f"scenarios; nothing to interrupt at this size",
        )
    second = run_watched(cmd, ctx.runs, "interrupt-2", env=ctx.env(), dirs={"out": folder})
    peaks = {}
    for label, run in (("killed run", first), ("rerun", second)):
        for role, r in run.watch.peaks(by_depth("main", "workers")).items():
            peaks[f"{role} ({label})"] = r
    merged = Run(
        second.rc, first.wall_s + second.wall_s, second.stdout, second.stderr, second.watch, first.cpu_s + second.cpu_s
    )
    row = ctx.row(
        "interrupt",
        f"score -o R.json, SIGKILL at {state['killed_at']}/{ctx.layout.scenes}, rerun",
        merged,
        peaks,
        disk=max(first.watch.disk_peak["out"], second.watch.disk_peak["out"]),
    )
    resumed = "resum" in second.stderr.lower()  # the command says it resumes from the journal
    extra = (
        f"{first.wall_s + second.wall_s - ctx.cli_wall:+.1f} s against the uninterrupted cli run"
        if ctx.cli_wall
        else "no uninterrupted cli run to compare"
    )
    share = f", {100 * second.wall_s / ctx.cli_wall:.0f}% of the uninterrupted cli run" if ctx.cli_wall else ""
    row["note"] = (
        f"killed after {first.wall_s:.1f} s with {state['killed_at']} scenarios journaled; rerun "
        f"{second.wall_s:.1f} s{share} ({'resumed' if resumed else 'DID NOT RESUME'}, "
        f"{ctx.layout.scenes - state['killed_at']} left to score); extra cost {extra}"
    )
    row["interrupt"] = {
        "killed_after_s": round(first.wall_s, 2),
        "journaled": state["killed_at"],
        "rerun_s": round(second.wall_s, 2),
        "resumed": resumed,
        "rerun_share": round(second.wall_s / ctx.cli_wall, 4) if ctx.cli_wall else None,
        "extra_s": round(first.wall_s + second.wall_s - ctx.cli_wall, 2) if ctx.cli_wall else None,
    }
    return ctx.with_result(row, out, second)
