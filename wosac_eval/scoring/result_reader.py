"""Reading the result JSON written by `wosac-eval score --output` into arrays.

A result holds per-scenario metrics (`scenarios`), their mean (`aggregate`)
and the leaderboard buckets (`buckets`). The gate compares per-scenario values,
so it turns the scenario list into one `(num_scenarios,)` array per metric.

It lives beside its writer (`result`): scoring writes the document, and `results/`
(compare, report, scene pictures), which stands above scoring, reads it from here.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from wosac_eval.challenges import CHALLENGE_NAMES as CHALLENGES
from wosac_eval.metrics.buckets import metametric_weights, weighted_bucket
from wosac_eval.metrics.config import load_config

# The metric schema comes from the one registry: fields, buckets, directions.
from wosac_eval.metrics.registry import (  # noqa: F401  (re-exported to compare and report)
    BUCKET_ALIASES,
    BUCKET_FIELDS,
    BUCKET_MEMBERS,
    RATE_FIELDS,
    SCENARIO_FIELDS,
    higher_is_better,
)


class ResultError(ValueError):
    """A result file that cannot be read, with the file (and scenario, field) at fault."""


# The per-scenario fields the rows of each schema version carry (the document's `schema_version`), each
# list frozen once its version is written: a saved document stays readable whatever the registry gains
# later. A field the registry knows beyond its version's is read when every row carries it.
# 1: the documents written before "schema_version" was recorded; 2: the same fields, the version recorded.
_FIELDS_1 = (
    "metametric",
    "average_displacement_error",
    "min_average_displacement_error",
    "linear_speed_likelihood",
    "linear_acceleration_likelihood",
    "angular_speed_likelihood",
    "angular_acceleration_likelihood",
    "distance_to_nearest_object_likelihood",
    "collision_indication_likelihood",
    "time_to_collision_likelihood",
    "distance_to_road_edge_likelihood",
    "offroad_indication_likelihood",
    "traffic_light_violation_likelihood",
    "simulated_collision_rate",
    "simulated_offroad_rate",
    "simulated_traffic_light_violation_rate",
)
VERSION_FIELDS: dict[int, tuple[str, ...]] = {1: _FIELDS_1, 2: _FIELDS_1}
SCHEMA_VERSION = max(VERSION_FIELDS)  # the newest: what `scoring.result` writes


@dataclasses.dataclass
class ScoringResult:
    """One scoring run.

    Attributes:
      path: the file it was read from (for messages).
      config: the config name or textproto path it was scored with.
      challenge: "sim_agents" or "scenario_gen" (results written before the
        challenge was recorded are sim agents results).
      scenario_ids: `(num_scenarios,)` ids, unique, in file order.
      values: metric name -> `(num_scenarios,)` per-scenario values. Holds every
        field of SCENARIO_FIELDS, plus the weighted buckets when the file carries
        them per scenario or the config's weights are known.
      aggregate: metric name -> the file's own aggregate (mean over its scenarios).
      buckets: bucket name -> the file's leaderboard bucket value.
      skipped: `{"scenario_id", "reason"}` entries the scorer left out.
      criticality: `(num_scenarios,)` criticality scores, or None when the rows carry none (results
        written before the analysis was added).
      by_type: object type -> metric -> `(num_scenarios,)` values, NaN where the scenario has no
        evaluated object of the type (or the metric is undefined for it).
      objects: the per-object file the result names (`score --per-object`, `scoring.objects`), resolved
        beside the result, or None.
      schema_version: the document's `schema_version` (1 for documents written before it was recorded).
    """

    path: str
    config: str
    challenge: str
    scenario_ids: np.ndarray
    values: dict[str, np.ndarray]
    aggregate: dict[str, float]
    buckets: dict[str, float]
    skipped: list[dict[str, Any]]
    criticality: np.ndarray | None = None
    by_type: dict[str, dict[str, np.ndarray]] = dataclasses.field(default_factory=dict)
    objects: str | None = None
    schema_version: int = SCHEMA_VERSION

    @property
    def num_scenarios(self) -> int:
        return int(self.scenario_ids.size)

    def has_per_scenario(self, metric: str) -> bool:
        return metric in self.values

    def per_scenario(self, metric: str) -> np.ndarray:
        """`(num_scenarios,)` values of a field or bucket (bucket names accepted)."""
        return self.values[BUCKET_ALIASES.get(metric, metric)]

    def headline(self, metric: str) -> float | None:
        """The file's own figure for a field or bucket (mean over all its scenarios)."""
        if metric in self.buckets:
            return self.buckets[metric]
        if metric in self.aggregate:
            return self.aggregate[metric]
        if metric in self.values:
            return float(self.values[metric].mean()) if self.num_scenarios else None
        return None


def shared_rows(base: ScoringResult, new: ScoringResult) -> tuple[np.ndarray, np.ndarray]:
    """Row indices `(base_rows, new_rows)`, int64 `(num_scenarios,)` each, of the scenarios both results hold,
    in base order: `base.values[m][base_rows]` pairs with `new.values[m][new_rows]`."""
    in_new = {sid: i for i, sid in enumerate(new.scenario_ids)}
    base_rows = np.array([i for i, sid in enumerate(base.scenario_ids) if sid in in_new], dtype=np.int64)
    new_rows = np.array([in_new[base.scenario_ids[i]] for i in base_rows], dtype=np.int64)
    return base_rows, new_rows


def _number(value: Any, where: str, finite: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ResultError(f"{where}: expected a number, got {value!r}")
    value = float(value)
    if finite and not math.isfinite(value):
        raise ResultError(f"{where}: value is {value}, expected a finite number")
    return value


def _numbers(obj: Any, where: str) -> dict[str, float]:
    """The numeric entries of an aggregate / buckets object; NaN entries (nothing scored) are left out."""
    if obj is None:
        return {}
    if not isinstance(obj, dict):
        raise ResultError(f"{where}: expected an object, got {type(obj).__name__}")
    return {
        k: _number(v, f"{where}.{k}", finite=k not in MAY_BE_NON_FINITE)
        for k, v in obj.items()
        if k != "scenario_id" and not (isinstance(v, float) and math.isnan(v))
    }


def _scenario_ids(scenarios: list, path: str) -> list[str]:
    """The scenario ids, checked: every entry an object with a unique non-empty id string."""
    if set(map(type, scenarios)) <= {dict}:
        ids = [e.get("scenario_id") for e in scenarios]
        if set(map(type, ids)) <= {str} and all(ids) and len(set(ids)) == len(ids):
            return ids
    seen: dict[str, int] = {}  # something is wrong: find the first entry at fault
    for i, entry in enumerate(scenarios):
        if not isinstance(entry, dict):
            raise ResultError(f"{path}: scenarios[{i}] is not an object")
        sid = entry.get("scenario_id")
        if not isinstance(sid, str) or not sid:
            raise ResultError(f"{path}: scenarios[{i}] has no 'scenario_id' string")
        if sid in seen:
            raise ResultError(f"{path}: scenario {sid!r} appears twice (scenarios[{seen[sid]}] and scenarios[{i}])")
        seen[sid] = i
    raise AssertionError("unreachable: the fast check failed but no entry is at fault")


# Fields the official evaluator itself reports as NaN or inf for a submission with NaN or inf positions.
MAY_BE_NON_FINITE = frozenset({"average_displacement_error", "min_average_displacement_error"})


def _column(scenarios: list[dict], field: str, ids: list[str], path: str) -> np.ndarray:
    """`(num_scenarios,)` values of one per-scenario field, checked to be finite numbers (or NaN and
    inf where the official evaluator reports them: `MAY_BE_NON_FINITE`)."""
    raw = [e.get(field) for e in scenarios]
    # Fast path, checked without a Python call per value: only ints and floats (bools and numeric
    # strings would convert silently), all finite.
    if set(map(type, raw)) <= {float, int}:
        column = np.asarray(raw, dtype=np.float64).reshape(len(raw))
        if field in MAY_BE_NON_FINITE or np.isfinite(column).all():
            return column
    for i, value in enumerate(raw):  # find the first scenario at fault
        if field not in scenarios[i]:
            raise ResultError(f"{path}: scenario {ids[i]!r} (scenarios[{i}]) has no field {field!r}")
        _number(value, f"{path}: scenario {ids[i]!r} field {field!r}")
    raise AssertionError("unreachable: the fast check failed but no value is at fault")


def _analysis_columns(scenarios: list[dict], ids: list[str], path: str) -> Any:
    """The rows' criticality scores (None unless every row has one) and per-type values (NaN where absent)."""
    criticality = None
    if ids and all(isinstance(e.get("criticality"), dict) for e in scenarios):
        criticality = np.array(
            [
                _number(e["criticality"].get("score"), f"{path}: scenario {sid!r} field 'criticality.score'")
                for e, sid in zip(scenarios, ids)
            ]
        )
    by_type: dict[str, dict[str, np.ndarray]] = {}
    for i, entry in enumerate(scenarios):
        types = entry.get("by_object_type")
        if not isinstance(types, dict):
            continue
        for kind, fields in types.items():
            if not isinstance(fields, dict):
                raise ResultError(f"{path}: scenario {ids[i]!r} field 'by_object_type.{kind}' is not an object")
            for field, value in fields.items():
                if value is None or field == "num_objects":
                    continue
                column = by_type.setdefault(kind, {}).setdefault(field, np.full(len(ids), np.nan))
                column[i] = _number(
                    value,
                    f"{path}: scenario {ids[i]!r} field 'by_object_type.{kind}.{field}'",
                    finite=field not in MAY_BE_NON_FINITE,
                )
    return criticality, by_type


def default_bucket_weights(config: str) -> dict[str, float] | None:
    """Metametric weights of the config, by config field name, or None if unavailable.

    Comes from the metrics package's config loader; None when the config cannot be
    found (then per-scenario weighted buckets are only available when the result
    file carries them).
    """
    try:
        proto = load_config(config)
    except (ValueError, OSError):  # an unknown name, or a textproto path that is not on this machine
        return None
    return metametric_weights(proto)


def weighted_buckets(values: dict[str, np.ndarray], weights: dict[str, float]) -> dict[str, np.ndarray]:
    """Per-scenario kinematic / interactive / map-based buckets, each `(num_scenarios,)`.

    A bucket is the mean of its likelihoods weighted by their metametric weights, as the
    scorer's (`buckets.weighted_bucket`). A bucket whose weights sum to zero is left out.
    """
    # A bucket one of whose weighted likelihoods the document predates cannot be recomputed: left out.
    means = {
        bucket: weighted_bucket(members, values, weights)
        for bucket, members in BUCKET_MEMBERS.items()
        if all(f"{m}_likelihood" in values for m in members if weights.get(m))
    }
    return {bucket: mean for bucket, mean in means.items() if mean is not None}


def parse_result(
    data: object,
    path: str = "<result>",
    weights_for: Callable[[str], dict[str, float] | None] = default_bucket_weights,
) -> ScoringResult:
    """Validates a decoded result JSON and returns it as arrays.

    Raises:
      ResultError: naming the file, scenario and field at fault.
    """
    if not isinstance(data, dict):
        raise ResultError(f"{path}: expected a JSON object at the top level, got {type(data).__name__}")
    version = schema_version(data, path)
    scenarios = data.get("scenarios")
    if not isinstance(scenarios, list):
        raise ResultError(f"{path}: missing 'scenarios' list (is this a `wosac-eval score --output` file?)")
    config = data.get("config")
    if not isinstance(config, str):
        raise ResultError(f"{path}: missing 'config' (expected the config name or textproto path as a string)")

    challenge = data.get("challenge", "sim_agents")
    if challenge not in CHALLENGES:
        raise ResultError(f"{path}: unknown challenge {challenge!r} (expected one of {', '.join(CHALLENGES)})")

    ids = _scenario_ids(scenarios, path)
    required = VERSION_FIELDS[version]
    values = {f: _column(scenarios, f, ids, path) for f in required}
    values.update(
        (f, _column(scenarios, f, ids, path))
        for f in SCENARIO_FIELDS
        if f not in values and ids and all(f in e for e in scenarios)
    )
    carried = {b: _column(scenarios, b, ids, path) for b in BUCKET_MEMBERS if ids and all(b in e for e in scenarios)}
    if len(carried) < len(BUCKET_MEMBERS) and ids:
        weights = weights_for(config)
        if weights is not None:
            carried = {**weighted_buckets(values, weights), **carried}
    values.update(carried)

    criticality, by_type = _analysis_columns(scenarios, ids, path)
    skipped = data.get("skipped") or []
    if not isinstance(skipped, list):
        raise ResultError(f"{path}: 'skipped' must be a list")
    return ScoringResult(
        path=path,
        config=config,
        challenge=challenge,
        scenario_ids=np.asarray(ids, dtype=object).reshape(len(ids)),
        values=values,
        aggregate=_numbers(data.get("aggregate"), f"{path}: aggregate"),
        buckets=_numbers(data.get("buckets"), f"{path}: buckets"),
        skipped=[s if isinstance(s, dict) else {"scenario_id": str(s), "reason": ""} for s in skipped],
        criticality=criticality,
        by_type=by_type,
        objects=_objects_file(data, path),
        schema_version=version,
    )


def schema_version(data: dict, path: str = "<result>") -> int:
    """The document's schema version (1 when it records none: written before the field); a ResultError
    for a version this wosac-eval does not know (a newer one: the message says to upgrade)."""
    version = data.get("schema_version", 1)
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise ResultError(f"{path}: 'schema_version' is {version!r}, expected a whole number >= 1")
    if version > SCHEMA_VERSION:
        raise ResultError(
            f"{path}: result schema version {version} is newer than this wosac-eval reads "
            f"(versions 1 to {SCHEMA_VERSION}): upgrade wosac-eval to read it"
        )
    return version


def _objects_file(data: dict, path: str) -> str | None:
    entry = data.get("per_object")
    if not isinstance(entry, dict) or not isinstance(entry.get("objects"), str):
        return None
    return str(Path(path).parent / entry["objects"])


def load_result(path: str | Path, **kwargs: Any) -> ScoringResult:
    """Reads and validates a result JSON file (see `parse_result`)."""
    path = str(path)
    try:
        with open(path, encoding="utf-8") as f:
            data = json.load(f)
    except FileNotFoundError:
        raise ResultError(f"{path}: no such file") from None
    except json.JSONDecodeError as e:
        raise ResultError(f"{path}: not valid JSON ({e}); give a result of `wosac-eval score --output`") from None
    except UnicodeDecodeError:
        raise ResultError(
            f"{path}: a binary file, not a result JSON; give a result of `wosac-eval score "
            f"--output` (not a submission or a scenario file)"
        ) from None
    except IsADirectoryError:
        raise ResultError(f"{path}: is a folder; give a result JSON file") from None
    except OSError as e:
        raise ResultError(f"{path}: cannot read ({e.strerror})") from None
    return parse_result(data, path, **kwargs)
