"""A smooth surrogate of the realism metrics, for gradient-based training: a training signal, not the metric.

`soft_realism(prepared, x, y, z, heading, temperature=...)` takes the arguments of
`jax_realism.realism` and returns the same kind of mapping (every `SimAgentMetrics`
field per scene, the meta-metric included), differentiable in the rollouts. The
official metric is piecewise constant in the rollouts (a sample moves the score
only when it crosses a histogram edge or a threshold), so its gradient is zero
almost everywhere; the surrogate replaces each discontinuous step by a smooth
one, with one `temperature`:

- Histogram counts: a simulated sample is in bin k with the weight
  sigmoid((e_k+1 - s) / w) - sigmoid((e_k - s) / w), `w = temperature * bin width`
  (the outer edges at -inf and +inf, which clip as the official histogram does; a
  NaN sample stays in the last bin). The weights of a sample sum to 1, so the
  counts are the official counts' smooth version; the logged value keeps its
  hard bin (the log does not depend on the rollouts).
- Indicator features: collision at a step is sigmoid(-distance_to_nearest_object / t),
  offroad sigmoid(distance_to_road_edge / t), `t = temperature` metres (both
  distances are signed, thresholds 0). "At any valid step" is the maximum over
  the steps (the gradient goes to the step nearest to the event; a product of
  per-step probabilities would add up the tails of 80 steps). The Bernoulli
  estimator counts a soft flag f as f in the "true" bin and 1 - f in the other.
- Red-light violation at a step: officially, the object's centre passes a stop
  point (behind it at the step before, past it now) whose signal shows stop, and
  the object's nearest lane is the signal's; the soft crossing is
  max(0, sigmoid(a_now / t) - sigmoid(a_before / t)), a the signed distance in
  metres of the object's centre past the stop point along the stop point's lane
  segment (each step's own segment): the weight of the stop point in the step's
  sweep [a_before, a_now], as a histogram bin's. An object that waits at the line
  scores 0 (a product of a "behind" and an "ahead" sigmoid would score up to 1/4 at
  every step it waits within t of the line). The signal's state and the lane match
  stay hard (the match is an argmin over lanes, like the minima's pair). The largest
  over the signals; "at any valid step" is the largest over one step or two
  consecutive ones (a crossing whose step ends near the line shares its weight
  with the next step: their sum is the line's weight in the two-step sweep).
- Minima (nearest object, nearest road edge, over the four corners) stay hard:
  they are continuous already, and their gradient is the one of the minimising
  pair. The kernel density estimator (no leaderboard config uses one) is smooth.
- Kernels: the bit tricks that make the official roundings (`xp.differentiable`)
  are the plain operations; the nearest-object search is all pairs (no
  `while_loop` to differentiate through). Features are computed in float32
  (`xp.float32_precision`), whatever x64 says.

As the temperature goes to 0 the surrogate goes to the official value (see
docs/soft-realism.md for the figures on the golden cases): a training signal
whose value tracks the official metric, not a replacement for it: report the
official `realism`. Rates are the soft flags' means; displacement errors are the
official ones (continuous already). The searches must run on the device:
`prepare(..., search="device")` (the host search is a callback without gradients).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wosac_eval import challenges
from wosac_eval.backends import jax_driver, realism_inputs
from wosac_eval.backends import jax_realism as jr
from wosac_eval.estimators import likelihoods
from wosac_eval.features import dense, interaction, ops, registry, road_edge, traffic_lights
from wosac_eval.features.metric_features import MetricFeatures
from wosac_eval.features.xp import differentiable, float32_precision
from wosac_eval.metrics.config import SimAgentMetricsConfig, load_config
from wosac_eval.metrics.registry import METRICS, RATES
from wosac_eval.metrics.scenario_metrics import SCENARIO_FIELDS, metric_values, validity_masks

_F = np.float32
SOFT_MODE = "soft"  # `Realism.mode` of what `soft_realism` returns
DEFAULT_TEMPERATURE = 0.1


def _safe_sigmoid(z: Any) -> Any:
    """sigmoid(z), 0 for NaN, with a finite gradient everywhere."""
    nan = jnp.isnan(z)
    return jnp.where(nan, _F(0), jax.nn.sigmoid(jnp.where(nan, _F(0), z)))


def soft_histogram_counts(samples: Any, edges: np.ndarray, width: Any, weights: Any = None) -> Any:
    """The smooth `likelihoods.histogram_counts`: `(batch, num_bins)`, float32.

    A sample is below interior edge e with the weight sigmoid((e - s) / width); bin k holds the
    differences of those cumulative weights (as the hard counts), so each sample's weights sum to 1.
    NaN samples count in the last bin, as officially.

    Args:
      samples: `(batch, num_samples)`.
      width: the kernel's width in the samples' unit (temperature x bin width), > 0.
      weights: optional 0/1 `(batch, num_samples)`: which samples count.
    """
    samples = jnp.asarray(samples, _F)
    w = jnp.ones(samples.shape, _F) if weights is None else weights.astype(_F)
    interior = np.asarray(edges, _F)[1:-1]
    below = [jnp.sum(w * _safe_sigmoid((edge - samples) / width), axis=1) for edge in interior]
    total = jnp.sum(w, axis=1)
    cumulative = jnp.stack([jnp.zeros_like(total), *below, total], axis=1)
    return cumulative[:, 1:] - cumulative[:, :-1]


def _log_probability_of_bins(counts: Any, pseudocount: Any, log_bins: Any) -> Any:
    """log p(bin of each logged value) from soft counts plus the pseudo-count, float32 `(batch, num_log_samples)`."""
    counts = counts + _F(pseudocount)
    log_prob = jnp.log(counts) - jnp.log(counts.sum(axis=1, keepdims=True))
    return jnp.take_along_axis(log_prob, log_bins, axis=1).astype(_F)


def soft_estimate(
    config: likelihoods.FeatureConfig,
    log_samples: Any,
    sim_samples: Any,
    sim_weights: Any = None,
    num_rows: int | None = None,
    *,
    temperature: float | jax.Array,
) -> Any:
    """The smooth twin of the official estimator of `config` (`likelihoods.official_estimate`'s signature;
    `num_rows` is not needed: the soft estimates follow no packet boundaries).

    Histogram: `soft_histogram_counts` with a kernel `temperature` bins wide. Bernoulli: the soft
    flags' sums (f in the true bin, 1 - f in the other). Kernel density: the official one (smooth).
    """
    kind = config.WhichOneof("estimator")
    if kind == "histogram":
        h = config.histogram
        edges = likelihoods.histogram_edges(h.min_val, h.max_val, h.num_bins)
        width = temperature * _F((_F(h.max_val) - _F(h.min_val)) / _F(h.num_bins))
        counts = soft_histogram_counts(sim_samples, edges, width, sim_weights)
        return _log_probability_of_bins(
            counts, h.additive_smoothing_pseudocount, likelihoods.histogram_bins(log_samples, edges)
        )
    if kind == "bernoulli":
        flags = jnp.asarray(sim_samples, _F)
        w = jnp.ones(flags.shape, _F) if sim_weights is None else sim_weights.astype(_F)
        true = jnp.sum(w * flags, axis=1)
        counts = jnp.stack([jnp.sum(w, axis=1) - true, true], axis=1)
        log_bins = jnp.asarray(jnp.asarray(log_samples, _F) >= _F(0.5), jnp.int32)
        return _log_probability_of_bins(counts, config.bernoulli.additive_smoothing_pseudocount, log_bins)
    return likelihoods.official_estimate(config, log_samples, sim_samples, sim_weights)


# Soft crossings below this weight skip the lane search (their lane match counts as none): the search
# then follows the few points near a stopped signal's line, as the official one follows the crossings.
SOFT_CROSSING_FLOOR = 1e-6
# Points whose lane is looked up at once (`dense.on_signal_lane`), more in further rounds.
SOFT_LANE_SEARCH_CHUNK = 256


def soft_stop_line_crossings(x: Any, y: Any, valid: Any, m: dict, temperature: float | jax.Array) -> Any:
    """The soft `traffic_lights.stop_line_crossings`: float32 `(..., num_objects, num_steps, num_signals)`.

    max(0, sigmoid(a_now / temperature) - sigmoid(a_before / temperature)) where the signal shows stop
    and the object is valid, a the signed distance (metres) past the stop point along the line of that
    step's stop segment: the official crossing (a_before < 0 < a_now) as the temperature goes to 0, 0
    without motion along the line. A NaN position or a stop segment of no length (padding) is never
    crossed, as officially.

    Args:
      x, y: float32 `(..., num_objects, num_steps)`; valid: bool, the same shape.
      m: the padded red-light map arrays (`dense.red_light_violation`).
    """
    sx, sy = m["stop_start"][..., 0], m["stop_start"][..., 1]
    dx, dy = m["stop_delta"][..., 0], m["stop_delta"][..., 1]
    squared = dx * dx + dy * dy
    stop_t = traffic_lights.line_parameter(m["stop_point"][..., 0], m["stop_point"][..., 1], sx, sy, dx, dy, squared)
    obj_t = traffic_lights.line_parameter(x[..., None], y[..., None], sx, sy, dx, dy, squared)
    # Line parameters are in segment lengths: times the length, metres (the sign is the official comparison's).
    past = (obj_t - stop_t) * ops.sqrt(squared)
    before, now = past[..., :-1, :], past[..., 1:, :]
    # The stop point's weight in the sweep [before, now] (0 when the object moves back or stays).
    swept = jnp.maximum(_safe_sigmoid(now / temperature) - _safe_sigmoid(before / temperature), _F(0))
    crossed = jnp.concatenate([jnp.zeros_like(past[..., :1, :]), swept], axis=-2)
    line = squared > 0
    counts = valid[..., None] & m["stopping"] & line & jnp.concatenate([line[:1], line[:-1]])
    counts = counts & ~jnp.isnan(past) & ~jnp.isnan(jnp.concatenate([past[..., :1, :], before], axis=-2))
    return jnp.where(counts, crossed, _F(0))


def soft_red_light_crossings(x: Any, y: Any, valid: Any, m: dict, temperature: float | jax.Array) -> Any:
    """The soft red-light violations per signal: float32 `(..., num_objects, num_steps, num_signals)`, in [0, 1].

    `soft_stop_line_crossings` of the signals on the object's nearest lane (the official lane match of
    `dense.red_light_violation`, hard: found for the points whose soft crossing passes
    `SOFT_CROSSING_FLOOR`); `soft_any_crossing` takes the official `any` over signals and steps.
    """
    crossings = soft_stop_line_crossings(x, y, valid, m, temperature)
    if crossings.shape[-1] == 0:
        return crossings
    flat = crossings.reshape(-1, crossings.shape[-1])
    points = jax.lax.stop_gradient(jnp.stack([x, y], axis=-1).reshape(-1, 2))
    needed = (flat > _F(SOFT_CROSSING_FLOOR)).any(axis=-1)
    on_lane = dense.on_signal_lane(points, needed, m, SOFT_LANE_SEARCH_CHUNK)
    return jnp.where(on_lane, flat, _F(0)).reshape(crossings.shape)


def _soft_red_light_feature(traj: dict, m: dict, layout: Any, temperature: float | jax.Array) -> Any:
    """`soft_red_light_crossings` over the official window of `registry`'s red-light feature (from one
    step before the first reported one, where there is one): `(samples, num_evaluated, reported steps,
    num_signals)`."""
    n, lights = layout.num_evaluated, slice(layout.first_red_light_step, None)
    red = soft_red_light_crossings(
        traj["x"][:, :n, lights], traj["y"][:, :n, lights], traj["valid"][:, :n, lights], m, temperature
    )
    return red[..., 1:, :] if layout.first_step > 0 else red


def soft_events(sim: MetricFeatures, red_light_violation: Any, temperature: float | jax.Array) -> dict:
    """The soft per-step event of each indicator feature, float32 `(num_rollouts, num_evaluated, num_steps)`.

    Collision: sigmoid((threshold - distance to the nearest object) / temperature), offroad:
    sigmoid((distance to the road edge - threshold) / temperature), the distances in metres; the
    red-light violation: `red_light_violation`, per signal (`soft_red_light_crossings`, of the rollouts:
    `(..., num_steps, num_signals)`, for `soft_any_crossing`).
    """
    collision = _F(interaction.COLLISION_DISTANCE_THRESHOLD) - sim.distance_to_nearest_object
    offroad = sim.distance_to_road_edge - _F(road_edge.OFFROAD_DISTANCE_THRESHOLD)
    return {
        "collision_per_step": _safe_sigmoid(collision / temperature),
        "offroad_per_step": _safe_sigmoid(offroad / temperature),
        "traffic_light_violation_per_step": red_light_violation,
    }


def soft_any_over_time(events: Any, mask: Any) -> Any:
    """Whether the event happened at a step of `mask`, smoothly: the largest soft event, `(..., num_evaluated)`."""
    return jnp.max(jnp.where(mask, events, _F(0)), axis=-1)


def soft_any_crossing(crossings: Any, mask: Any) -> Any:
    """`soft_any_over_time` of soft crossings `(..., num_steps, num_signals)`: the largest over the signals
    at each step, then over one step or two consecutive ones, at most 1, `(...)`.

    A crossing whose step ends near the line shares its weight with the next step: the largest single
    step would count it as little as 1/2; the two steps' sum is the line's weight in the two-step
    sweep. The two steps may count it under two signals (lanes that start at one stop point, the
    lane match switching at the line): there the sum can pass 1, and the minimum stops it (no
    gradient: a sure crossing). As the temperature goes to 0, the official `any`.
    """
    events = jnp.max(jnp.where(mask[..., None], crossings, _F(0)), axis=-1, initial=_F(0))
    following = jnp.concatenate([events[..., 1:], jnp.zeros_like(events[..., :1])], axis=-1)
    return jnp.minimum(jnp.max(events + following, axis=-1), _F(1))


def _soft_any(feature: str) -> Any:
    """The soft `any over time` of an indicator feature."""
    return soft_any_crossing if feature == "traffic_light_violation_per_step" else soft_any_over_time


def soft_log_likelihoods(
    config: SimAgentMetricsConfig,
    log: MetricFeatures,
    sim: MetricFeatures,
    events: dict,
    object_mask: Any,
    temperature: float | jax.Array,
) -> dict:
    """`scenario_metrics.metric_log_likelihoods` with the soft estimators and indicators."""
    masks = validity_masks(log)
    estimate = functools.partial(soft_estimate, temperature=temperature)
    out = {}
    for metric in METRICS:
        feature_config = getattr(config, metric.name)
        mask = masks[metric.mask]
        if metric.per_object:
            log_flags = (getattr(log, metric.feature) & mask).any(axis=-1)[0]
            sim_flags = _soft_any(metric.feature)(events[metric.feature], mask)
            out[metric.name] = (
                likelihoods.scenario_level_log_likelihood(feature_config, log_flags, sim_flags, object_mask, estimate),
                None,
            )
        else:
            ll = likelihoods.timeseries_log_likelihood(
                feature_config, getattr(log, metric.feature)[0], getattr(sim, metric.feature), object_mask, estimate
            )
            out[metric.name] = (ll, mask)
    return out


def _scene_soft_realism(
    config: Any,
    spec: challenges.ChallengeSpec,
    layout: Any,
    a: dict,
    rollouts: dict,
    temperature: float | jax.Array,
    features: tuple,
) -> Any:
    """Every SCENARIO_FIELDS value of one prepared scene, soft (leading scene axis removed)."""
    traj = jr.scene_trajectories(spec, a, rollouts)
    both = jr.trajectory_features(layout, a, traj, None, features)
    log, sim = both.samples(slice(0, 1)), both.samples(slice(1, None))
    rollouts_only = {k: traj[k][1:] for k in ("x", "y", "valid")}  # the log's flags stay the official ones
    red_light = _soft_red_light_feature(rollouts_only, a["maps"], layout, temperature)
    events = soft_events(sim, red_light, temperature)
    lls = soft_log_likelihoods(config, log, sim, events, a["evaluated"], temperature)
    values = metric_values(config, log, sim, lls, object_mask=a["evaluated"])
    valid = validity_masks(log)["valid"]
    real = a["evaluated"].astype(_F)
    for rate in RATES:  # the share of (rollout, evaluated object) pairs with the soft event
        flags = _soft_any(rate.feature)(events[rate.feature], valid)
        values[rate.name] = jnp.mean(jnp.sum(flags * real, axis=-1) / jnp.sum(real)).astype(_F)
    return {f: values[f] for f in SCENARIO_FIELDS}


@functools.lru_cache(maxsize=32)
def _soft_fn(config_name: str, challenge: str, layout: Any, features: tuple) -> Any:
    config = load_config(config_name)
    spec = challenges.spec(challenge)

    def scenes(
        a: Any, rollouts: Any, temperature: float | jax.Array
    ) -> Any:  # the temperature shared by the scenes, their segments too
        def one(a: Any, rollouts: Any) -> Any:
            with float32_precision(), differentiable():  # read while tracing
                return _scene_soft_realism(config, spec, layout, a, rollouts, temperature, features)

        return jax_driver.vmap_scenes(one)(a, rollouts)

    return jax.jit(scenes)


def soft_realism(
    prepared: jr.PreparedScenes,
    x: Any,
    y: Any,
    z: Any,
    heading: Any,
    *,
    length: Any = None,
    width: Any = None,
    height: Any = None,
    temperature: float | jax.Array = DEFAULT_TEMPERATURE,
) -> jr.Realism:
    """A smooth surrogate of every `SimAgentMetrics` field per scene, differentiable in the rollouts.

    A training signal, not the official metric (see the module for each smoothing): report `realism`.

    Args:
      prepared: from `jax_realism.prepare(..., search="device")`; in a jitted step, an argument.
      x, y, z, heading, length, width, height: as for `jax_realism.realism` (gradients flow to x, y, z
        and heading).
      temperature: > 0, a float or a traced scalar (an annealing schedule does not recompile): the
        histogram kernels are `temperature` bin widths wide, the indicator sigmoids `temperature`
        metres. As it goes to 0 the values go to the official ones.
    Returns:
      a `Realism` of float32 `(num_scenes,)` arrays, mode "soft".
    Raises:
      ValueError: `prepared`'s searches run on the host, or a non-positive temperature.
    """
    if prepared.host_searches is not None:
        raise ValueError(
            "soft_realism differentiates through the searches, which run on the device only: "
            "prepare the scenes with jax_realism.prepare(..., search='device')"
        )
    if not isinstance(temperature, jax.core.Tracer) and not float(temperature) > 0:
        raise ValueError(f"temperature must be positive, got {temperature}")
    fields = realism_inputs.rollout_fields(
        prepared, x, y, z, heading, {"length": length, "width": width, "height": height}
    )
    fields = {k: jnp.asarray(v, _F) for k, v in fields.items()}
    temperature = jnp.asarray(temperature, _F)
    parts = [
        _soft_fn(prepared.config, prepared.challenge, layout, registry.features())(
            arrays, realism_inputs.take_scenes(fields, indices), temperature
        )
        for arrays, (indices, layout) in zip(prepared.arrays, prepared.groups)
    ]
    return jr.Realism(jr.in_scene_order(prepared, parts), SOFT_MODE)
