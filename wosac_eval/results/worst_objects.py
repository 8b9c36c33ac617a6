"""The objects that cost a run most, per bucket: an exact split of each bucket's gap from 1 over the objects.

A bucket (kinematic, interactive, map-based) is the weighted mean of its likelihood fields over the
scenes: `1 - bucket = (1/N) sum_scenes sum_fields w_f (1 - field)` (`w` the config's meta-metric weights,
normalised within the bucket). A scene's field is the count-weighted geometric mean of its objects'
likelihoods (`metrics.per_object`), so `-log field = sum_i share_i (-log l_i)`, `share_i` the object's
count over the scene's; the scene's gap `1 - field` is split over its objects in those proportions:

    contribution_i = (1/N) sum_{f in bucket} w_f (1 - field_f) share_if (-log l_if) / (-log field_f)

These add up, over every object of every scene, to the bucket's gap from 1. The per-object file is
read once, scene by scene (it is grouped by scene, in the result's order), keeping only the top objects
of each bucket: memory does not grow with the number of objects.
"""

from __future__ import annotations

import dataclasses
import heapq
import itertools
import math
from typing import Any

from wosac_eval.metrics.registry import BUCKET_MEMBERS
from wosac_eval.scoring.objects import count_column, read_objects
from wosac_eval.scoring.result_reader import ScoringResult, default_bucket_weights


@dataclasses.dataclass(frozen=True)
class WorstObject:
    """One object's part of a bucket's gap from 1.

    Attributes:
      contribution: its part of `1 - bucket` (in the bucket's units: they sum to the gap over all objects).
      fields: (likelihood field, the object's likelihood, its part of the contribution), largest first.
    """

    bucket: str
    scenario_id: str
    object_id: int
    object_type: str
    contribution: float
    fields: tuple


def _scene_contributions(records: list[dict], fields: dict, weights: dict, scene_field: dict, n: int) -> Any:
    """(bucket, contribution, fields) of every object of one scene."""
    totals = {f: sum(r[count_column(f)] for r in records) for f in scene_field}
    for record in records:
        for bucket, members in fields.items():
            parts = []
            for name in members:
                f = f"{name}_likelihood"
                value, count, field = record.get(f), record.get(count_column(f), 0), scene_field.get(f)
                if not count or value is None or field is None or not totals[f] or field >= 1.0 or value <= 0:
                    continue
                share = count / totals[f]
                part = weights[bucket][name] * (1.0 - field) * share * -math.log(value) / -math.log(field) / n
                parts.append((f, value, part))
            total = sum(p for _, _, p in parts)
            if total > 0:
                yield bucket, record, total, tuple(sorted(parts, key=lambda p: -p[2]))


def _bucket_weights(config: str) -> tuple[dict, dict] | None:
    """(weights, fields) of each bucket: its members' meta-metric weights normalised within the bucket, and
    the members of positive weight; None when the config's weights are unknown."""
    config_weights = default_bucket_weights(config)
    if config_weights is None:
        return None
    weights, fields = {}, {}
    for bucket, members in BUCKET_MEMBERS.items():
        total = sum(config_weights.get(m, 0.0) for m in members)
        if total > 0:
            weights[bucket] = {m: config_weights.get(m, 0.0) / total for m in members}
            fields[bucket] = [m for m in members if weights[bucket][m] > 0]
    return weights, fields


def scene_worst_objects(records: list[dict], row: dict, config: str, top_k: int = 5) -> list[dict]:
    """The objects of one scene that cost its buckets most, worst first: the split above within the scene
    alone (N = 1), so an object's part of a bucket is its part of that scene's `1 - bucket`.

    records: the scene's per-object records (`scoring.objects.read_objects`, one scene's group).
    row: the scene's row of the result (its `*_likelihood` fields).
    Returns up to `top_k` dicts: object_id, object_type, contribution (its parts of the scene's bucket gaps,
    summed), buckets ({bucket: part}) and fields ([field, the object's likelihood, its part], largest first);
    [] when the config's weights are unknown or the scene has no objects.
    """
    bucket_weights = _bucket_weights(config)
    if bucket_weights is None or not records:
        return []
    weights, fields = bucket_weights
    scene_field = {}
    for members in fields.values():
        for m in members:
            value = row.get(f"{m}_likelihood")
            scene_field[f"{m}_likelihood"] = float(value) if isinstance(value, (int, float)) else None
    scene_field = {f: v for f, v in scene_field.items() if v is not None and math.isfinite(v)}
    fields = {b: [m for m in ms if f"{m}_likelihood" in scene_field] for b, ms in fields.items()}
    per_object: dict[int, dict] = {}
    for bucket, record, total, parts in _scene_contributions(records, fields, weights, scene_field, 1):
        entry = per_object.setdefault(
            int(record["object_id"]),
            {
                "object_id": int(record["object_id"]),
                "object_type": record["object_type"],
                "contribution": 0.0,
                "buckets": {},
                "fields": [],
            },
        )
        entry["contribution"] += total
        entry["buckets"][bucket] = total
        entry["fields"].extend([f, value, part] for f, value, part in parts)
    ranked = sorted(per_object.values(), key=lambda e: (-e["contribution"], e["object_id"]))[:top_k]
    for entry in ranked:
        entry["fields"].sort(key=lambda p: -p[2])
    return ranked


def worst_objects(result: ScoringResult, top_k: int = 10) -> dict[str, list[WorstObject]]:
    """The `top_k` objects contributing most to each bucket's gap from 1 (see the module); {} when the
    result has no per-object file or no known config weights."""
    if result.objects is None or result.num_scenarios == 0:
        return {}
    bucket_weights = _bucket_weights(result.config)
    if bucket_weights is None:
        return {}
    weights, fields = bucket_weights
    row_of = {sid: i for i, sid in enumerate(result.scenario_ids.tolist())}
    heaps: dict[str, list] = {bucket: [] for bucket in fields}
    tie = itertools.count()
    n = result.num_scenarios
    for sid, group in itertools.groupby(read_objects(result.objects), key=lambda r: r["scenario_id"]):
        i = row_of.get(sid)
        if i is None:
            continue
        records = list(group)
        scene_field = {
            f"{m}_likelihood": float(result.values[f"{m}_likelihood"][i])
            for members in fields.values()
            for m in members
        }
        for bucket, record, total, parts in _scene_contributions(records, fields, weights, scene_field, n):
            entry = (
                total,
                next(tie),
                WorstObject(bucket, sid, int(record["object_id"]), record["object_type"], total, parts),
            )
            heap = heaps[bucket]
            if len(heap) < top_k:
                heapq.heappush(heap, entry)
            elif entry[0] > heap[0][0]:
                heapq.heapreplace(heap, entry)
    return {bucket: [e[2] for e in sorted(heap, key=lambda e: (-e[0], e[1]))] for bucket, heap in heaps.items()}
