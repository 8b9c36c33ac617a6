"""The demo: synthetic scenes, every baseline, validated and scored, as a leaderboard per challenge.

Needs nothing but this package: the scenes are generated deterministically on
first use and cached in the work directory (regenerated when the generator,
seed or count changes). Sim agents results go to `results/<policy>.json`,
scenario gen results to `results/scenario_gen/<policy>.json` (submissions alike).

It drives `sim` (scenes, baselines) and `scoring` as the `demo` command does, so it stands
with the fronts, beside `commands/demo.py` (every module of `commands` is a command).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from wosac_eval.challenges import Challenge, ChallengeLike, as_challenge
from wosac_eval.runtime.cache_dirs import user_cache_dir
from wosac_eval.sim import scenes

DEMO_SEED = 0
DEMO_SCENES = 10
DEMO_POLICIES = ("log_replay_noise", "idm", "constant_velocity")
BUCKETS = (
    ("realism_meta_metric", "meta"),
    ("kinematic_metrics", "kinematic"),
    ("interactive_metrics", "interactive"),
    ("map_based_metrics", "map"),
    ("min_ade", "minADE"),  # not for scenario gen: a generated object has no logged counterpart
    ("simulated_collision_rate", "collision"),
    ("simulated_offroad_rate", "offroad"),
    ("simulated_traffic_light_violation_rate", "red-light"),
)


def _say(line: str) -> None:
    """Progress on stdout, flushed at once: the demo must never look stuck, even in a pipe."""
    print(line, flush=True)


def default_workdir() -> Path:
    return user_cache_dir("demo")


def ensure_scenes(workdir: Path, num_scenes: int = DEMO_SCENES, seed: int = DEMO_SEED) -> tuple[list[Path], bool]:
    """Scenario shards of the demo set in `workdir/scenarios`; generated unless cached.

    Returns the shard paths and whether they were generated now.
    """
    folder = Path(workdir) / "scenarios"
    manifest = folder / "manifest.json"
    wanted = {"seed": seed, "num_scenes": num_scenes, "generator": scenes.GENERATOR_VERSION}
    if manifest.exists():
        try:
            recorded = json.loads(manifest.read_text())
            paths = [folder / name for name in recorded.get("shards", [])]
            if {k: recorded.get(k) for k in wanted} == wanted and paths and all(p.exists() for p in paths):
                return paths, False
        except (OSError, ValueError):
            pass  # unreadable manifest: regenerate
    generated = scenes.generate_scenes(num_scenes, seed)
    for old in folder.glob("synthetic.tfrecord-*"):
        old.unlink()
    paths = scenes.write_scenario_shards(generated, folder, num_shards=2)
    manifest.write_text(
        json.dumps(
            {
                **wanted,
                "shards": [p.name for p in paths],
                "sha256": scenes.scenario_fingerprint(generated),
                "scenario_ids": [s.scenario_id for s in generated],
            },
            indent=2,
        )
    )
    return paths, True


@dataclass
class PolicyResult:
    policy: str
    submission: Path
    result_json: Path
    buckets: dict
    valid: bool
    seconds: float


def challenge_folder(workdir: Path, kind: str, challenge: ChallengeLike) -> Path:
    """`workdir/kind` for sim agents, `workdir/kind/scenario_gen` for scenario gen."""
    folder = Path(workdir) / kind
    challenge = as_challenge(challenge)
    return folder if challenge is Challenge.SIM_AGENTS else folder / challenge.value


def run_demo(
    workdir: Path,
    *,
    num_scenes: int = DEMO_SCENES,
    seed: int = DEMO_SEED,
    policies: tuple[str, ...] = DEMO_POLICIES,
    config: str | None = None,
    workers: int = 1,
    challenge: ChallengeLike = Challenge.SIM_AGENTS,
    log: Callable[[str], object] | None = None,
) -> list[PolicyResult]:
    """Generates (or loads) the scenes, runs, validates and scores each policy; returns the rows.

    `challenge`: "sim_agents" or "scenario_gen" (all 91 steps of every object);
    `config`: None for the challenge's current one.
    """
    from wosac_eval.scoring.submission import InvalidSubmissionError, score_submission
    from wosac_eval.sim.baselines import make_submission

    log = log or _say
    workdir = Path(workdir)
    start = time.perf_counter()
    log(f"{challenge}: {len(policies)} policies on {num_scenes} synthetic scenes ({workdir})")
    scenario_paths, fresh = ensure_scenes(workdir, num_scenes, seed)
    log(
        f"{'generated' if fresh else 'loaded'} {num_scenes} synthetic scenes in {workdir / 'scenarios'} "
        f"({time.perf_counter() - start:.1f} s)"
    )
    rows = []
    for policy in policies:
        t0 = time.perf_counter()
        log(f"  {challenge} {policy}: simulating, validating and scoring ...")
        submission = make_submission(
            scenario_paths,
            policy,
            challenge_folder(workdir, "submissions", challenge) / f"{policy}.tar.gz",
            seed=seed,
            workers=workers,
            challenge=challenge,
        )
        t1 = time.perf_counter()
        try:  # scoring validates the submission first
            result = score_submission(scenario_paths, submission, config, challenge=challenge, workers=workers)
        except InvalidSubmissionError as error:
            log(error.report.format_text())
            rows.append(PolicyResult(policy, submission, Path(), {}, False, time.perf_counter() - t0))
            continue
        result_json = challenge_folder(workdir, "results", challenge) / f"{policy}.json"
        result_json.parent.mkdir(parents=True, exist_ok=True)
        result_json.write_text(json.dumps(result, indent=2, sort_keys=True))
        rows.append(PolicyResult(policy, submission, result_json, result["buckets"], True, time.perf_counter() - t0))
        log(
            f"  {challenge} {policy}: simulated in {t1 - t0:.1f} s, validated and scored in "
            f"{time.perf_counter() - t1:.1f} s"
        )
    return rows


def leaderboard(rows: list[PolicyResult], challenge: ChallengeLike = Challenge.SIM_AGENTS) -> str:
    """A plain-text table of the policies, best meta-metric first."""
    columns = [(key, label) for key, label in BUCKETS if not (challenge == "scenario_gen" and key == "min_ade")]
    header = ["policy"] + [label for _, label in columns]
    table = [header]
    for row in sorted(rows, key=lambda r: -r.buckets.get("realism_meta_metric", -1.0)):
        if not row.valid:
            table.append([row.policy] + ["invalid"] + [""] * (len(columns) - 1))
            continue
        table.append([row.policy] + [f"{row.buckets[key]:.4f}" for key, _ in columns])
    widths = [max(len(r[i]) for r in table) for i in range(len(header))]
    lines = [
        "  ".join(cell.ljust(w) if i == 0 else cell.rjust(w) for i, (cell, w) in enumerate(zip(r, widths)))
        for r in table
    ]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
