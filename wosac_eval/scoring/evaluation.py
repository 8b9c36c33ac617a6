"""One evaluation, resolved once at the edge and passed down.

Every front (the CLI, the Python API, the service) turns what it was asked
into an `Evaluation` with `resolve_evaluation`: the challenge's spec, the
metrics config (the challenge's current preset when none is named; a preset of
the other challenge refused) and the run's options (`RunOptions`: backend,
engine, workers, input limits...), each checked here and nowhere else, before
any long work. The layers below take the `Evaluation` (or the parts they need)
as decided.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

from wosac_eval import challenges
from wosac_eval.analysis.scenario_set_criticality import parse_selection
from wosac_eval.extras import check_backend, check_engine
from wosac_eval.metrics.config import SimAgentMetricsConfig, config_name_for, load_config
from wosac_eval.options import Backend, Choice, Engine, MetadataChecks
from wosac_eval.parse.limits import InputLimits


@dataclasses.dataclass(frozen=True)
class RunOptions:
    """How a run goes: every option of `score_submission` but its inputs, the challenge and the config.

    Built once (the names become `wosac_eval.options` members here, and a bad value is refused here, in
    one sentence naming it and what is allowed); every front and engine reads this object.

    Attributes:
      backend: `Backend` "numpy" or "jax" (the `jax` extra); results are identical.
      engine: `Engine` "local" (this host) or "ray" (the `ray` extra; joins the cluster at `ray_address`,
        or `RAY_ADDRESS`, or starts a local Ray). Ray workers read the submission and the scenarios from
        the same paths: give paths every node can see (a shared filesystem).
      ray_address: the cluster to join with the ray engine (None: `RAY_ADDRESS` or a local Ray).
      workers: worker processes of this host with the local engine (results are identical for any count).
      allow_partial: score the valid scenarios of an invalid submission instead of refusing it; skipped
        scenarios are listed in `skipped`.
      metadata_checks: `MetadataChecks` "warn" (local scoring needs no account, method name or flags; their
        findings are listed under `validation.findings` as warnings) or "error" (the challenge server's
        rules, as `wosac-eval validate` and the service apply them).
      select: score only the most critical scenarios of the set: "top:0.1" (a fraction) or "top:100" (a
        count), ranked by `analysis.scenario_set_criticality` before scoring; None: every scenario. The
        whole submission is still validated; rarity is rated against the whole set.
      analysis: with False, rows carry the official metrics only (no criticality, driving scores or
        per-type metrics, and no `analysis` summary): a little faster.
      limits: how far the submission may expand when read (`parse.limits.InputLimits`; None: the defaults).
      per_object: also give every evaluated object's values (`scoring.scenario.object_records`): with
        `objects`, streamed to that file (`.jsonl` or `.parquet`, `scoring.objects`), never all held in
        memory, and the document's `per_object` names it; without, each row carries its `objects`.
      objects: the per-object file of `per_object` (None: in the rows).
    """

    backend: Backend = Backend.NUMPY
    engine: Engine = Engine.LOCAL
    ray_address: str | None = None
    workers: int = 1
    allow_partial: bool = False
    metadata_checks: MetadataChecks = MetadataChecks.WARN
    select: str | None = None
    analysis: bool = True
    limits: InputLimits = InputLimits()
    per_object: bool = False
    objects: str | os.PathLike | None = None

    def __post_init__(self) -> None:
        # The one boundary: names become members (frozen, so set through object.__setattr__).
        object.__setattr__(self, "backend", Backend.parse(self.backend))
        object.__setattr__(self, "engine", Engine.parse(self.engine))
        object.__setattr__(self, "metadata_checks", MetadataChecks.parse(self.metadata_checks))
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or self.workers < 1:
            raise ValueError(f"workers must be a whole number >= 1, not {self.workers!r}")
        if self.select is not None:
            parse_selection(self.select)
        if self.limits is None:
            object.__setattr__(self, "limits", InputLimits())
        if not isinstance(self.limits, InputLimits):
            raise ValueError(f"limits must be an InputLimits, not {type(self.limits).__name__}")
        if self.objects is not None and not self.per_object:
            raise ValueError("objects= names the per-object file: it needs per_object=True")

    @classmethod
    def of(cls, caller: str, **values: Any) -> RunOptions:
        """The options named in `values`, the others default; an unknown name is a TypeError of `caller`."""
        unknown = sorted(set(values) - OPTION_NAMES)
        if unknown:
            raise TypeError(
                f"{caller}() got an unexpected keyword argument {unknown[0]!r} "
                f"(its options: {', '.join(f.name for f in dataclasses.fields(cls))})"
            )
        return cls(**values)


OPTION_NAMES = frozenset(field.name for field in dataclasses.fields(RunOptions))


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """What an evaluation is and how it runs, decided.

    Attributes:
      spec: the challenge's `ChallengeSpec` (steps, rollouts, which objects are evaluated).
      config_name: the preset or textproto path it is scored with (named in the result).
      config: that `SimAgentMetricsConfig`, loaded.
      options: how it runs (`RunOptions`).
    """

    spec: challenges.ChallengeSpec
    config_name: str
    config: SimAgentMetricsConfig
    options: RunOptions = RunOptions()

    @property
    def challenge(self) -> challenges.Challenge:
        return self.spec.challenge


def resolve_evaluation(
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    config: str | os.PathLike | None = None,
    options: RunOptions | None = None,
    **option_values: Any,
) -> Evaluation:
    """Check and resolve everything an evaluation is asked with; ValueError (or the backend's and
    engine's unavailable errors) in one sentence for the first thing that cannot be.

    Args:
      challenge: "sim_agents" or "scenario_gen".
      config: a preset name or a textproto path; None: the challenge's current preset.
      options: the run's `RunOptions`; or leave it out and name them (`workers=2`, `backend="jax"`...).
    """
    if options is not None and option_values:
        raise TypeError(
            f"resolve_evaluation: give options= or the options by name ({', '.join(sorted(option_values))}), not both"
        )
    if options is None:
        options = RunOptions.of("resolve_evaluation", **option_values)
    config_name = config_name_for(challenge, config)
    spec = challenges.spec(challenge)
    check_backend(options.backend)  # installed here: the names were checked by RunOptions
    check_engine(options.engine)
    return Evaluation(spec=spec, config_name=config_name, config=load_config(config_name), options=options)


def evaluation_for(
    caller: str,
    evaluation: Evaluation | None,
    challenge: challenges.ChallengeLike | None,
    config: str | os.PathLike | None,
    option_values: dict[str, Any],
) -> Evaluation:
    """The evaluation of a call that takes either `evaluation=` or the arguments it is resolved from.

    With `evaluation`, the arguments also given must say what it says: one that differs is refused
    (a ValueError naming each), never silently ignored. `challenge` None is "sim_agents".
    """
    if evaluation is None:
        return resolve_evaluation(
            challenges.Challenge.SIM_AGENTS if challenge is None else challenge, config, **option_values
        )
    asked = RunOptions.of(caller, **option_values)
    conflicts = []
    if challenge is not None and challenges.as_challenge(challenge) != evaluation.challenge:
        conflicts.append(f"challenge={challenge!r} (it has {evaluation.challenge.value!r})")
    if config is not None and str(config) != evaluation.config_name:
        conflicts.append(f"config={str(config)!r} (it has {evaluation.config_name!r})")
    conflicts += [
        f"{name}={_shown(option_values[name])} (it has {_shown(getattr(evaluation.options, name))})"
        for name in option_values
        if getattr(asked, name) != getattr(evaluation.options, name)
    ]
    if conflicts:
        raise ValueError(
            f"{caller}: evaluation= already decides the run, and {'; '.join(conflicts)} "
            f"disagree(s) with it: pass these to resolve_evaluation instead, or leave them out"
        )
    return evaluation


def _shown(value: Any) -> str:
    """A value as a message quotes it (an option's member by its name)."""
    return repr(value.value if isinstance(value, Choice) else value)
