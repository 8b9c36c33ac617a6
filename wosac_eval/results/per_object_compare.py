"""Per-object comparison of two scoring runs (`wosac-eval compare BASE.json NEW.json --per-object`).

Both results need their per-object file (`score --per-object`). Objects are matched by
(scenario_id, object_id); for each matched object and each metric, the change is `new - base` of
its likelihood, or of its own meta-metric: the config's meta-metric weights over the likelihoods the
object has (`object_metametric`, as `by_object_type` weights a type's).

- objects: the matched objects whose meta-metric changed most (both ways), with the likelihood that
  moved most;
- strata: object type x the scene's criticality (all scenes, the terciles, the long tail; from the
  base result, as `compare --stratify criticality` takes them), per metric, a paired comparison with
  its bootstrap interval and permutation p-value (`stats.paired_test`). The objects of one scene
  are not independent draws, so the unit is the scene: per scene, the mean over its objects of the
  stratum, paired between the runs; the difference is the mean of those over the scenes of the
  stratum that hold such objects. The strata listed are those that changed most: first those whose
  change is significant (p < alpha), each group by the size of the change.

Every (stratum, metric) pair is a test: p-values are also Holm-adjusted over all of them.
"""

from __future__ import annotations

import array
import dataclasses
from typing import Any

import numpy as np

from wosac_eval.arrays.object_types import ANALYSED_TYPES
from wosac_eval.metrics.registry import LIKELIHOOD_FIELDS, METRIC_NAMES
from wosac_eval.results import stats
from wosac_eval.results.stats import PairedSettings
from wosac_eval.results.stratify import cohens_d, criticality_strata
from wosac_eval.scoring.objects import read_objects
from wosac_eval.scoring.result_reader import ScoringResult, default_bucket_weights

OBJECT_METAMETRIC = "object_metametric"
METRICS = (OBJECT_METAMETRIC, *LIKELIHOOD_FIELDS)


class PerObjectError(ValueError):
    """The results cannot be compared object by object (a usage error)."""


@dataclasses.dataclass
class ObjectTable:
    """The per-object values of a result, as columns (one entry per object, in file order)."""

    scenario_id: np.ndarray  # object
    object_id: np.ndarray  # int64
    object_type: np.ndarray  # object (vehicle, pedestrian, cyclist, other)
    values: dict[str, np.ndarray]  # metric (METRICS) -> float64, NaN where the object has none

    def __len__(self) -> int:
        return int(self.object_id.size)


def object_metametric(values: dict[str, np.ndarray], weights: dict[str, float] | None) -> np.ndarray:
    """Each object's meta-metric: the weighted mean of the likelihoods it has (weights renormalised)."""
    weights = weights or dict.fromkeys(METRIC_NAMES, 1.0)
    total = np.zeros_like(values[LIKELIHOOD_FIELDS[0]])
    norm = np.zeros_like(total)
    for name in METRIC_NAMES:
        column, w = values[f"{name}_likelihood"], weights.get(name, 0.0)
        if w:
            present = np.isfinite(column)
            total += np.where(present, w * np.nan_to_num(column), 0.0)
            norm += np.where(present, w, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm > 0, total / norm, np.nan)


def load_objects(result: ScoringResult) -> ObjectTable:
    """The per-object file of a result, as columns; PerObjectError if it has none or it is missing."""
    if result.objects is None:
        raise PerObjectError(f"{result.path} has no per-object values: score it with `wosac-eval score --per-object`")
    sids, oids, types = [], array.array("q"), []
    columns = {f: array.array("d") for f in LIKELIHOOD_FIELDS}  # 8 bytes a value, not a float object
    try:
        for record in read_objects(result.objects):
            sids.append(record["scenario_id"])
            oids.append(record["object_id"])
            types.append(record["object_type"])
            for f in LIKELIHOOD_FIELDS:
                columns[f].append(np.nan if record[f] is None else record[f])
    except FileNotFoundError:
        raise PerObjectError(
            f"{result.path} names the per-object file {result.objects}, which is missing (keep it beside the result)"
        ) from None
    except (KeyError, TypeError, ValueError) as e:
        raise PerObjectError(
            f"{result.objects}: not a per-object file of `wosac-eval score --per-object` ({e})"
        ) from None
    values = {f: np.frombuffer(c, dtype=np.float64).copy() for f, c in columns.items()}
    values[OBJECT_METAMETRIC] = object_metametric(values, default_bucket_weights(result.config))
    return ObjectTable(
        np.asarray(sids, dtype=object),
        np.frombuffer(oids, dtype=np.int64).copy(),
        np.asarray(types, dtype=object),
        values,
    )


@dataclasses.dataclass(frozen=True)
class ObjectChange:
    scenario_id: str
    object_id: int
    object_type: str
    base: float
    new: float
    difference: float
    most_changed: str | None  # the likelihood that moved most
    most_changed_difference: float | None


@dataclasses.dataclass(frozen=True)
class StratumChange:
    object_type: str
    criticality: str
    description: str
    metric: str
    num_scenarios: int
    num_objects: int
    base: float
    new: float
    difference: float
    ci_low: float
    ci_high: float
    p_value: float
    p_holm: float | None
    cohens_d: float | None

    @property
    def label(self) -> str:
        """e.g. "pedestrians in the long tail", "vehicles in high-criticality scenes", "cyclists"."""
        kind = "other objects" if self.object_type == "other" else f"{self.object_type}s"
        if self.criticality == "all":
            return kind
        if self.criticality == "long tail":
            return f"{kind} in the long tail"
        return f"{kind} in {self.criticality}-criticality scenes"


@dataclasses.dataclass
class PerObjectComparison:
    num_matched: int
    num_base_only: int
    num_new_only: int
    alpha: float
    objects: list[ObjectChange]
    strata: list[StratumChange]
    num_tests: int
    notes: list[str]

    def to_json(self) -> dict[str, Any]:
        return {
            "objects": {"matched": self.num_matched, "base_only": self.num_base_only, "new_only": self.num_new_only},
            "alpha": self.alpha,
            "num_tests": self.num_tests,
            "changed_objects": [dataclasses.asdict(o) for o in self.objects],
            "changed_strata": [{**dataclasses.asdict(s), "label": s.label} for s in self.strata],
            "notes": list(self.notes),
        }


def _match(base: ObjectTable, new: ObjectTable) -> tuple[np.ndarray, np.ndarray]:
    where = {(s, o): i for i, (s, o) in enumerate(zip(new.scenario_id, new.object_id.tolist()))}
    b_rows, n_rows = [], []
    for i, key in enumerate(zip(base.scenario_id, base.object_id.tolist())):
        j = where.get(key)
        if j is not None:
            b_rows.append(i)
            n_rows.append(j)
    return np.asarray(b_rows, dtype=np.int64), np.asarray(n_rows, dtype=np.int64)


def _scene_means(groups: np.ndarray, values: np.ndarray, num_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """(sum, count) per scene of the finite values."""
    ok = np.isfinite(values)
    sums = np.bincount(groups[ok], weights=values[ok], minlength=num_groups)
    counts = np.bincount(groups[ok], minlength=num_groups)
    return sums, counts


def compare_objects(
    base_result: ScoringResult,
    new_result: ScoringResult,
    *,
    metrics: list[str] | None = None,
    top: int = 10,
    settings: PairedSettings | None = None,
    base: ObjectTable | None = None,
    new: ObjectTable | None = None,
) -> PerObjectComparison:
    """The objects and the (object type x criticality) strata whose likelihoods changed most (see the module).

    Args:
      metrics: of METRICS ("metametric" means `object_metametric`); None: all.
      top: objects listed each way, and strata listed.
      settings: the paired tests' (`stats.PairedSettings`: alpha, seed, n_boot, n_perm; None: the
        defaults). The strata are ranked by their raw p-values; the Holm-adjusted ones are listed beside
        (`settings.adjust` is not used).
      base, new: the results' per-object tables when the caller has read them (`load_objects`).
    """
    settings = PairedSettings() if settings is None else settings
    wanted = _wanted(metrics)
    base = base if base is not None else load_objects(base_result)
    new = new if new is not None else load_objects(new_result)
    b_rows, n_rows = _match(base, new)
    if b_rows.size == 0:
        raise PerObjectError(f"{base_result.path} and {new_result.path} share no object (scenario_id, object_id)")
    notes: list[str] = []
    changes = _changed_objects(base, new, b_rows, n_rows, top)
    # Strata: object type x criticality of the scene, one paired test per (stratum, metric) over scenes.
    scene_ids, groups = np.unique(base.scenario_id[b_rows].astype(str), return_inverse=True)
    strata_of_scenes = _scene_strata(base_result, new_result, scene_ids, notes)
    matched = _Matched(base, new, b_rows, n_rows, groups, scene_ids.size)
    rows = [
        row
        for kind in (k for k in (*ANALYSED_TYPES, "other") if (matched.types == k).any())
        for metric in wanted
        for row in _stratum_changes(matched, kind, metric, strata_of_scenes, settings)
    ]
    if rows:
        holm = stats.holm_adjust(np.array([r.p_value for r in rows]))
        rows = [dataclasses.replace(r, p_holm=float(p)) for r, p in zip(rows, holm)]
    alpha = settings.alpha
    # The significant ones first (a change, not noise: one scene never is), then by the size of the change.
    ranked = sorted(
        rows, key=lambda r: (not r.p_value < alpha, -abs(r.difference), r.object_type, r.criticality, r.metric)
    )[:top]
    notes.append(
        f"{len(rows)} tests (object type x criticality x metric) at alpha={alpha:g}; p_holm controls the "
        "family-wise error over all of them. The unit is the scene (the mean over its objects of the "
        "stratum): objects of one scene are not independent."
    )
    if any(r.num_scenarios < 30 for r in ranked):
        notes.append("strata with fewer than 30 scenes have rough intervals and p-values")
    return PerObjectComparison(
        int(b_rows.size),
        len(base) - int(b_rows.size),
        len(new) - int(n_rows.size),
        alpha,
        changes,
        ranked,
        len(rows),
        notes,
    )


def _wanted(metrics: list[str] | None) -> list[str]:
    """The metrics asked for, of METRICS, in its order; PerObjectError when none is one of them."""
    wanted = [OBJECT_METAMETRIC if m == "metametric" else m for m in (metrics or METRICS)]
    wanted = [m for m in METRICS if m in wanted]
    if not wanted:
        raise PerObjectError(
            f"no per-object metric among {', '.join(metrics or [])}: the objects have "
            f"{', '.join(('metametric',) + LIKELIHOOD_FIELDS)}"
        )
    return wanted


def _changed_objects(
    base: ObjectTable, new: ObjectTable, b_rows: np.ndarray, n_rows: np.ndarray, top: int
) -> list[ObjectChange]:
    """The matched objects whose meta-metric changed most: the `top` that fell most, then the `top` that
    rose most (those not already listed), each with the likelihood that moved most."""
    types = base.object_type[b_rows]
    b_meta, n_meta = base.values[OBJECT_METAMETRIC][b_rows], new.values[OBJECT_METAMETRIC][n_rows]
    diff = n_meta - b_meta
    finite = np.flatnonzero(np.isfinite(diff))
    order = finite[np.argsort(diff[finite], kind="stable")]
    picked = list(order[:top]) + [i for i in order[::-1][:top] if diff[i] > 0 and i not in set(order[:top])]
    changes = []
    for i in picked:
        moved = {f: new.values[f][n_rows[i]] - base.values[f][b_rows[i]] for f in LIKELIHOOD_FIELDS}
        moved = {f: d for f, d in moved.items() if np.isfinite(d)}
        field = max(moved, key=lambda f: abs(moved[f])) if moved else None
        changes.append(
            ObjectChange(
                str(base.scenario_id[b_rows[i]]),
                int(base.object_id[b_rows[i]]),
                str(types[i]),
                float(b_meta[i]),
                float(n_meta[i]),
                float(diff[i]),
                field,
                None if field is None else float(moved[field]),
            )
        )
    return changes


def _scene_strata(
    base_result: ScoringResult, new_result: ScoringResult, scene_ids: np.ndarray, notes: list[str]
) -> list[tuple[str, str, np.ndarray]]:
    """(name, description, mask over `scene_ids`) of every scene, and of the criticality terciles and the
    long tail when a result carries criticality (the base's, else the new's); a note when neither does."""
    strata: list[tuple[str, str, np.ndarray]] = [("all", "every scene", np.ones(scene_ids.size, bool))]
    source = base_result if base_result.criticality is not None else new_result
    if source.criticality is not None:
        score_of = dict(zip(source.scenario_ids.tolist(), source.criticality.tolist()))
        scores = np.array([score_of.get(s, np.nan) for s in scene_ids])
        if np.isfinite(scores).all() and scene_ids.size >= 3:
            strata += [(n, d, m) for n, d, m in criticality_strata(scores) if n != "rest"]
    else:
        notes.append("no criticality in either result: strata by object type only")
    return strata


@dataclasses.dataclass(frozen=True)
class _Matched:
    """The objects of both tables matched by (scenario_id, object_id): their rows in each, and the scene
    (an index into the matched scenes, `num_scenes` of them) of each."""

    base: ObjectTable
    new: ObjectTable
    b_rows: np.ndarray
    n_rows: np.ndarray
    groups: np.ndarray
    num_scenes: int

    @property
    def types(self) -> np.ndarray:
        return self.base.object_type[self.b_rows]


def _stratum_changes(
    matched: _Matched,
    kind: str,
    metric: str,
    strata_of_scenes: list[tuple[str, str, np.ndarray]],
    settings: PairedSettings,
) -> list[StratumChange]:
    """One object type's change on one metric in each scene stratum that holds such objects: per scene,
    the mean over its objects, paired between the runs and tested over the scenes."""
    bv, nv = matched.base.values[metric][matched.b_rows], matched.new.values[metric][matched.n_rows]
    both = (matched.types == kind) & np.isfinite(bv) & np.isfinite(nv)
    b_sum, count = _scene_means(matched.groups[both], bv[both], matched.num_scenes)
    n_sum, _ = _scene_means(matched.groups[both], nv[both], matched.num_scenes)
    rows = []
    for name, description, scene_mask in strata_of_scenes:
        keep = scene_mask & (count > 0)
        if not keep.any():
            continue
        b_mean, n_mean = b_sum[keep] / count[keep], n_sum[keep] / count[keep]
        test = settings.test(b_mean, n_mean)
        rows.append(
            StratumChange(
                kind,
                name,
                description,
                metric,
                int(keep.sum()),
                int(count[keep].sum()),
                float(b_mean.mean()),
                float(n_mean.mean()),
                float(test.mean_difference[0]),
                float(test.ci_low[0]),
                float(test.ci_high[0]),
                float(test.p_value[0]),
                None,
                cohens_d(n_mean - b_mean),
            )
        )
    return rows


def _f(x: float | None, signed: bool = False) -> str:
    if x is None:
        return "-"
    x = round(x, 4) or 0.0
    return f"{x:+.4f}" if signed else f"{x:.4f}"


def _table(header: list[str], body: list[list[str]]) -> list[str]:
    widths = [max(len(row[i]) for row in [header] + body) for i in range(len(header))]
    line = lambda cells: "  ".join(c.ljust(w) for c, w in zip(cells, widths)).rstrip()  # noqa: E731
    return [line(header), line(["-" * w for w in widths]), *map(line, body)]


def format_objects(c: PerObjectComparison) -> str:
    """The per-object comparison as plain text: the strata that changed most, then the objects."""
    conf = f"{round((1 - c.alpha) * 100)}% CI"
    out = [
        f"per object: {c.num_matched} objects matched by (scenario_id, object_id)"
        + (
            f"; {c.num_base_only} only in base, {c.num_new_only} only in new"
            if c.num_base_only or c.num_new_only
            else ""
        ),
        "",
        "strata that changed most (object type x scene criticality; diff = new - base, mean over scenes):",
    ]
    out += _table(
        ["stratum", "metric", "scenes", "objects", "base", "new", "diff", conf, "p", "p_holm"],
        [
            [
                s.label,
                s.metric,
                str(s.num_scenarios),
                str(s.num_objects),
                _f(s.base),
                _f(s.new),
                _f(s.difference, True),
                f"[{_f(s.ci_low, True)}, {_f(s.ci_high, True)}]",
                f"{s.p_value:.3g}",
                "-" if s.p_holm is None else f"{s.p_holm:.3g}",
            ]
            for s in c.strata
        ],
    )
    out += ["", f"objects that changed most ({OBJECT_METAMETRIC}: the config's weights over its likelihoods):"]
    out += _table(
        ["scenario", "object", "type", "base", "new", "diff", "moved most"],
        [
            [
                o.scenario_id,
                str(o.object_id),
                o.object_type,
                _f(o.base),
                _f(o.new),
                _f(o.difference, True),
                "-" if o.most_changed is None else f"{o.most_changed} {_f(o.most_changed_difference, True)}",
            ]
            for o in c.objects
        ],
    )
    out += [""] + [f"note: {n}" for n in c.notes]
    return "\n".join(out)


def format_objects_markdown(c: PerObjectComparison) -> str:
    """The per-object comparison as GitHub-flavoured Markdown (appended to `compare --markdown-output`)."""
    conf = f"{round((1 - c.alpha) * 100)}% CI"
    out = [
        "#### Per object: the strata that changed most",
        "",
        f"{c.num_matched} objects matched by (scenario_id, object_id); diff = new - base, mean over scenes.",
        "",
        f"| stratum | metric | scenes | objects | diff | {conf} | p | p_holm |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    out += [
        f"| {s.label} | `{s.metric}` | {s.num_scenarios} | {s.num_objects} | {_f(s.difference, True)} | "
        f"[{_f(s.ci_low, True)}, {_f(s.ci_high, True)}] | {s.p_value:.3g} | "
        f"{'-' if s.p_holm is None else f'{s.p_holm:.3g}'} |"
        for s in c.strata
    ]
    out += [
        "",
        "#### Per object: the objects that changed most",
        "",
        "| scenario | object | type | base | new | diff | moved most |",
        "| --- | ---: | --- | ---: | ---: | ---: | --- |",
    ]
    out += [
        f"| `{o.scenario_id}` | {o.object_id} | {o.object_type} | {_f(o.base)} | {_f(o.new)} | "
        f"{_f(o.difference, True)} | "
        + ("-" if o.most_changed is None else f"`{o.most_changed}` {_f(o.most_changed_difference, True)}")
        + " |"
        for o in c.objects
    ]
    return "\n".join(out) + "\n"
