"""One evaluation, resolved once at the edge and passed down.

Every front (the CLI, the Python API, the service) turns what it was asked
into an `Evaluation` with `resolve_evaluation`: the challenge's spec, the
metrics config (the challenge's current preset when none is named; a preset of
the other challenge refused), the input limits and the run options, each
checked here and nowhere else, before any long work. The layers below take the
`Evaluation` (or the parts they need) as decided.
"""
from __future__ import annotations

import dataclasses
import os

from wosac_eval import challenges
from wosac_eval.analysis.scenario_set_criticality import parse_selection
from wosac_eval.extras import check_backend, check_engine
from wosac_eval.metrics.config import SimAgentMetricsConfig, config_name_for, load_config
from wosac_eval.parse.limits import InputLimits
from wosac_eval.validate.validator import METADATA_CHECKS


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """What an evaluation is and how it runs, decided.

    Attributes:
      spec: the challenge's `ChallengeSpec` (steps, rollouts, which objects are evaluated).
      config_name: the preset or textproto path it is scored with (named in the result).
      config: that `SimAgentMetricsConfig`, loaded.
      limits: how far the submission may expand when read (`InputLimits`).
      backend: "numpy" or "jax".
      engine: "local" or "ray"; ray_address: the cluster to join (None: `RAY_ADDRESS` or a local Ray).
      workers: processes of this host with the local engine.
      allow_partial: score the valid scenarios of an invalid submission (skipped ones are listed).
      metadata_checks: "warn" (local scoring) or "error" (the challenge server's rules).
      select: score only the most critical scenarios ("top:0.1", "top:100"), or None.
      analysis: add criticality, driving scores and per-type metrics to each row.
    """

    spec: challenges.ChallengeSpec
    config_name: str
    config: SimAgentMetricsConfig
    limits: InputLimits = InputLimits()
    backend: str = "numpy"
    engine: str = "local"
    ray_address: str | None = None
    workers: int = 1
    allow_partial: bool = False
    metadata_checks: str = "warn"
    select: str | None = None
    analysis: bool = True

    @property
    def challenge(self) -> challenges.Challenge:
        return self.spec.challenge


def resolve_evaluation(challenge="sim_agents", config: str | os.PathLike | None = None, *,
                       limits: InputLimits | None = None, backend: str = "numpy", engine: str = "local",
                       ray_address: str | None = None, workers: int = 1, allow_partial: bool = False,
                       metadata_checks: str = "warn", select: str | None = None,
                       analysis: bool = True) -> Evaluation:
    """Check and resolve everything an evaluation is asked with; ValueError (or the backend's and
    engine's unavailable errors) in one sentence for the first thing that cannot be.

    Args are those of `score_submission`; `config` None is the challenge's current preset.
    """
    if select is not None:
        parse_selection(select)
    config_name = config_name_for(challenge, config)
    spec = challenges.spec(challenge)
    check_backend(backend)
    check_engine(engine)
    if metadata_checks not in METADATA_CHECKS:
        raise ValueError(f"metadata_checks must be one of {', '.join(METADATA_CHECKS)}, not {metadata_checks!r}")
    return Evaluation(spec=spec, config_name=config_name, config=load_config(config_name),
                      limits=InputLimits() if limits is None else limits, backend=backend, engine=engine,
                      ray_address=ray_address, workers=workers, allow_partial=allow_partial,
                      metadata_checks=metadata_checks, select=select, analysis=analysis)
