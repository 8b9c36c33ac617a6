"""Realism per object type: the scenario's metrics over its evaluated vehicles, pedestrians or cyclists alone.

The same log-likelihoods as the scenario's metrics (`metric_log_likelihoods`),
averaged over the objects of one type instead of all of them: a likelihood is
exp(mean log-likelihood) over that type's valid samples, a rate the share of
(rollout, object) pairs of that type with the event. A metric with no valid
sample for a type is None (time-to-collision counts vehicles only); the
meta-metric is the config's weighted mean of the likelihoods the type has
(weights renormalised over them). These are diagnostics beside the official
metrics, not part of them.
"""

from __future__ import annotations

import numpy as np

from wosac_eval.arrays.object_types import SHORT_NAMES
from wosac_eval.features.metric_features import MetricFeatures
from wosac_eval.metrics.buckets import metametric_weights
from wosac_eval.metrics.config import SimAgentMetricsConfig
from wosac_eval.metrics.registry import METRIC_NAMES, METRICS, RATES


def _likelihood(ll: np.ndarray, mask: np.ndarray | None, rows: np.ndarray) -> float | None:
    """exp(mean log-likelihood) over the rows' valid samples, or None without any."""
    values = ll[rows] if mask is None else ll[rows][mask[rows]]
    return float(np.exp(values.astype(np.float64).mean())) if values.size else None


def by_object_type(
    config: SimAgentMetricsConfig, log: MetricFeatures, sim: MetricFeatures, log_likelihoods: dict
) -> dict[str, dict]:
    """Per object type present among the evaluated objects: its likelihoods, meta-metric, rates and count.

    Args:
      log_likelihoods: `metric_log_likelihoods(config, log, sim)` of the scenario (numpy).
    Returns:
      {"vehicle": {"num_objects": n, "metametric": ..., "<metric>_likelihood": ..., "<rate>": ...,
      "min_average_displacement_error": ...}, ...}; types without evaluated objects are left out.
    """
    types = np.asarray(log.object_type)[0]
    valid = np.asarray(log.valid)[0]
    weights = metametric_weights(config)
    out = {}
    for code, name in SHORT_NAMES.items():
        rows = np.flatnonzero(types == code)
        if rows.size == 0:
            continue
        row: dict[str, int | float | None] = {"num_objects": int(rows.size)}
        for metric in METRICS:
            ll, mask = log_likelihoods[metric.name]
            row[metric.output] = _likelihood(np.asarray(ll), None if mask is None else np.asarray(mask), rows)
        likelihoods = {m: row[f"{m}_likelihood"] for m in METRIC_NAMES}
        weighted = [(weights[m], v) for m, v in likelihoods.items() if v is not None]
        total = sum(w for w, _ in weighted)
        row["metametric"] = float(sum(w * v for w, v in weighted) / total) if total > 0 else None
        ade = np.asarray(sim.average_displacement_error)[:, rows]
        row["min_average_displacement_error"] = float(ade.astype(np.float64).mean(axis=1).min())
        for rate in RATES:
            flags = np.asarray(getattr(sim, rate.feature))[:, rows] & valid[rows]
            row[rate.name] = float(flags.any(axis=-1).mean())
        out[name] = row
    return out
