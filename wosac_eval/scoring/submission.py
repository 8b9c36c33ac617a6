"""Score a whole submission against a scenario set: the pipeline every front calls.

stream -> validate -> schedule -> assemble. The submission is validated first
(the same rules as `wosac-eval validate`); an invalid one is refused unless
partial scoring is asked for, in which case every skipped scenario is listed
with its reason. The valid scenarios are then scored by an engine
(`scoring.engines`: this process, worker processes, or a Ray cluster) and
the per-scenario results are assembled, in submission order, into the result
document (`scoring.result`). The CLI, the service and the Python API all
call `score_submission`.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator

from wosac_eval import challenges
from wosac_eval.backends import check_backend
from wosac_eval.metrics.config import default_config, load_config
from wosac_eval.parse.archive import iter_submission_shards, parse_submission_shard
from wosac_eval.parse.errors import ParseError
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.parse.wire import field_spans
from wosac_eval.scoring.engines import ScoringSettings, check_engine, score_locally
from wosac_eval.scoring.result import result_document
from wosac_eval.validate import validate_submission

PathLike = str | os.PathLike
Progress = Callable[[int, int], None]


class InvalidSubmissionError(ValueError):
    """The submission failed validation; `.report` says every reason."""

    def __init__(self, report):
        self.report = report
        super().__init__(f"invalid submission: {report.error_count} error(s); "
                         f"run `wosac-eval validate` for the full report")


def split_shard(name: str, raw: bytes) -> list[tuple[str, bytes]]:
    """(scenario_id, serialized ScenarioRollouts) of every scenario of a shard.

    The shard is split at the wire level (`field_spans`: scenario_rollouts is
    field 1 of the submission, scenario_id field 1 of each element), so the
    parent process hands the workers bytes without parsing and re-serialising
    them; anything unexpected falls back to a full parse.
    """
    try:
        items = []
        for start, end in field_spans(raw, 1):
            data = raw[start:end]
            ids = field_spans(data, 1)  # a repeated singular field: the last one counts, as in a parse
            items.append((data[ids[-1][0]:ids[-1][1]].decode("utf-8") if ids else "", data))
        return items
    except (ValueError, UnicodeDecodeError):
        try:
            submission = parse_submission_shard(name, raw)
        except ParseError:
            return []
        return [(r.scenario_id, r.SerializeToString()) for r in submission.scenario_rollouts]


def rollouts_to_score(submission_path: PathLike, index: ScenarioIndex, report) -> Iterator[tuple[str, bytes]]:
    """(scenario_id, serialized ScenarioRollouts) of every valid scenario, once each, in submission order."""
    seen: set[str] = set()
    # Shards validation could not parse hold no valid scenario (only reached in partial mode).
    unparseable = {finding.shard for finding in report.findings("shard.unparseable")}
    for shard_name, raw in iter_submission_shards(submission_path):
        if shard_name in unparseable:
            continue
        for sid, data in split_shard(shard_name, raw):
            if sid in seen or sid not in index or not report.is_scenario_valid(sid):
                continue
            seen.add(sid)
            yield sid, data


def score_submission(scenario_paths: PathLike | Iterable[PathLike], submission_path: PathLike,
                     config: str | PathLike | None = None, *, challenge="sim_agents", workers: int = 1,
                     allow_partial: bool = False, progress: Progress | None = None, backend: str = "numpy",
                     engine: str = "local", ray_address: str | None = None) -> dict:
    """Validate and score a submission; returns the `result.json` document.

    Args:
      scenario_paths: TFRecord files, folders or globs of `Scenario`s.
      submission_path: a `.binproto`, a folder of shards, or a `.tar`/`.tar.gz`.
      config: preset name ("2025", "2024", "2023", "scenario_gen_2025") or a
        textproto path; None: the challenge's current leaderboard config.
      challenge: "sim_agents" or "scenario_gen".
      workers: worker processes with the local engine (results are identical for any count).
      allow_partial: score the valid scenarios of an invalid submission
        instead of refusing it; skipped scenarios are listed in `skipped`.
      progress: called as `progress(done, total)` after each scored scenario.
      backend: "numpy" or "jax" (needs the `jax` extra); results are identical.
      engine: "local" (this host) or "ray" (needs the `ray` extra; joins the
        cluster at `ray_address`, or `RAY_ADDRESS`, or starts a local one).
    Raises:
      InvalidSubmissionError: the submission is invalid and `allow_partial` is False.
    """
    check_backend(backend)
    check_engine(engine)
    challenge = challenges.as_challenge(challenge)
    config_name = default_config(challenge) if config is None else str(config)
    metrics_config = load_config(config_name)
    index = ScenarioIndex(scenario_paths)
    report = validate_submission(index, submission_path, workers=workers, challenge=challenge)
    if not report.ok and not allow_partial:
        raise InvalidSubmissionError(report)
    total = sum(1 for sid in index if report.is_scenario_valid(sid))
    settings = ScoringSettings(config=metrics_config.SerializeToString(), challenge=challenge.value,
                               backend=backend)
    if engine == "ray":
        from wosac_eval.scoring import ray_engine
        results = ray_engine.score_on_ray(submission_path, index, report, settings, address=ray_address)
    else:
        results = score_locally(rollouts_to_score(submission_path, index, report), settings, index, workers)
    per_scenario = []
    if progress is not None:
        progress(0, total)
    for result in results:
        per_scenario.append(result)
        if progress is not None:
            progress(len(per_scenario), total)
    if not per_scenario:
        raise InvalidSubmissionError(report) if not report.ok else ValueError(
            "the submission has no scenario in common with the scenario set")
    return result_document(challenge, config_name, metrics_config, per_scenario, report)
