"""Realism as a JAX function on device arrays: prepare scenes once, score new rollouts every training step.

`prepare(scenarios)` does the host work once per scene set: the log in the official object order, the map
(road-edge segments, stop lines, lane segments), the trailing-packet masks of the official float32 ops, all
padded to common sizes and stacked into a device pytree (`PreparedScenes`). `realism(prepared, x, y, z,
heading)` then runs the whole metric on the device: rollouts gathered into the official order, joined to the
logged history, per-step features (`metric_features.per_step_features`), log-likelihoods and every
`SimAgentMetrics` field (`metrics.scenario_metrics.metric_values`), per scene, under one `jax.jit`. The four
nearest-thing searches run where `prepare`'s `search` says: on the device over fixed-size candidate sets
(`dense.DenseSearch`, an accelerator's choice), or, on a CPU, in the numpy path's compiled, pruned search
called back from the trace (`host_search.HostSearch`). It is the same orchestration as the file path; padding
(objects, evaluated objects, map entries) is masked everywhere, so it never changes a result.

Shapes: rollouts are `(num_scenes, num_rollouts, max_agents, num_steps)`
with the agents in the order of `prepared.sim_agent_ids` (`-1` columns are
padding; their values are ignored), 80 steps after the current one (sim
agents) or all 91 (scenario gen, with per-step box sizes). Any array with
`__dlpack__` on JAX's device (a torch tensor, a CuPy or numpy array) is taken
without a copy.

Precision (`mode`): "float32" keeps every step in float32, so it runs in the
caller's `jit` with x64 off (JAX's default): metrics within 1e-5 of the
official outputs, per-step features possibly a last bit off. "exact" rounds a
few steps through float64 as the official arithmetic does: per-step features
bit-identical on CPU (with `jax_backend.exact_cpu()`), and needs x64 on while
tracing. The default follows the trace: "exact" under x64, else "float32". The
mode is recorded in what `realism` returns.

The module is the public face and the device side: `prepare` (the host side) is `realism_prepare`'s, and
`PreparedScenes` and `Realism` are `realism_types`'s.

In a training step, pass `prepared` to your `jax.jit` as an argument: closed
over, its arrays become constants of the compiled program (`realism_inputs`:
`jit_step`, the rollouts' layout and checks).
"""

from __future__ import annotations

import contextlib
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wosac_eval import challenges
from wosac_eval.backends import jax_driver
from wosac_eval.backends.exact_rounding import exactly_rounded
from wosac_eval.backends.host_search import HostSearches
from wosac_eval.backends.jax_driver import device_features
from wosac_eval.backends.realism_inputs import POSITIONS, SIZES, rollout_fields, take_scenes
from wosac_eval.backends.realism_prepare import prepare
from wosac_eval.backends.realism_types import PreparedScenes, Realism
from wosac_eval.features import metric_features as mf
from wosac_eval.features import registry
from wosac_eval.features.xp import float32_precision
from wosac_eval.metrics.config import load_config
from wosac_eval.metrics.registry import active_likelihood_fields, active_metrics
from wosac_eval.metrics.scenario_metrics import (
    metric_log_likelihoods,
    metric_values,
    per_object_likelihoods,
    scenario_fields,
)
from wosac_eval.options import Mode, Search

__all__ = ["MODES", "SEARCHES", "PreparedScenes", "Realism", "features", "prepare", "realism", "resolve_mode"]

_F = np.float32
MODES = Mode.names()
SEARCHES = Search.names()


def resolve_mode(mode: str | None = None) -> str:
    """The precision of a `realism` call: `mode` checked, or the trace's ("exact" under x64, else "float32").

    Raises:
      ValueError: an unknown mode, or "exact" while x64 is off (the sentence names both fixes).
    """
    x64 = bool(jax.config.read("jax_enable_x64"))
    if mode is None:
        return "exact" if x64 else "float32"
    mode = Mode.parse(mode).value
    if mode == "exact" and not x64:
        raise ValueError(
            "mode='exact' rounds through float64, so x64 must be on while it traces: wrap the call "
            "(or your jit's first call) in `with jax.enable_x64(True):`, or pass mode='float32' "
            "(metrics within 1e-5)"
        )
    return mode


def _precision(mode: str) -> Any:
    """The context the kernels are traced in for `mode` (see `xp.wide_float`)."""
    return float32_precision() if mode == "float32" else contextlib.nullcontext()


def _gather_agents(values: Any, columns: Any) -> Any:
    """`(num_rollouts, max_agents, num_steps)` user columns -> `(num_rollouts, num_objects, num_steps)` official
    rows."""
    padded = jnp.concatenate([values, jnp.zeros_like(values[:, :1])], axis=1)
    return jnp.take(padded, columns, axis=1)


def scene_features(
    spec: challenges.ChallengeSpec,
    layout: mf.FeatureLayout,
    a: dict,
    rollouts: dict,
    host: HostSearches | None,
    features: tuple,
) -> mf.MetricFeatures:
    """The features of one prepared scene (leading scene axis removed): sample 0 the log, then the rollouts."""
    return trajectory_features(layout, a, scene_trajectories(spec, a, rollouts), host, features)


def trajectory_features(
    layout: mf.FeatureLayout, a: dict, traj: dict, host: HostSearches | None, features: tuple
) -> mf.MetricFeatures:
    """`scene_features` of the scene's trajectories (`scene_trajectories`), for a caller that needs them too."""
    per_step = device_features(traj, a["tails"], a["maps"], layout, features, host, a["scene"])
    reported = layout.reported
    e = layout.num_evaluated
    valid = jnp.concatenate([a["feature_valid"][None], traj["valid"][1:, :e] & a["evaluated"][None, :, None]])
    return mf.MetricFeatures.from_dict(
        {
            "object_id": jnp.zeros(e, jnp.int32),
            "object_type": jnp.broadcast_to(a["object_type"][None], valid.shape[:2]),
            "valid": valid[..., reported],
            **per_step,
        }
    )


def scene_trajectories(spec: challenges.ChallengeSpec, a: dict, rollouts: dict) -> dict:
    """The `metric_features.TRAJECTORY_FIELDS` of one prepared scene (leading scene axis removed), each
    `(1 + num_rollouts, num_objects, num_steps)`: sample 0 the log, then the rollouts over the log's history."""
    log, real = a["log"], a["real"]
    num_rollouts = rollouts["x"].shape[0]
    n_obj, steps = log["x"].shape
    tile = lambda v: jnp.broadcast_to(v[None], (num_rollouts,) + v.shape)  # noqa: E731
    gathered = {f: _gather_agents(v.astype(_F), a["columns"]) for f, v in rollouts.items()}
    if spec.submits_boxes:
        sim = {**gathered, "valid": tile(log["valid"])}
        return {f: jnp.concatenate([log[f][None], sim[f]], axis=0) for f in mf.TRAJECTORY_FIELDS}
    now = spec.first_simulated_step
    sim = {f: jnp.concatenate([tile(log[f][:, :now]), gathered[f]], axis=-1) for f in POSITIONS}
    future_valid = jnp.broadcast_to(real[None, :, None], (num_rollouts, n_obj, steps - now))
    sim["valid"] = jnp.concatenate([tile(log["valid"][:, :now]), future_valid], axis=-1)
    out = {f: jnp.concatenate([log[f][None], sim[f]], axis=0) for f in sim}
    # The box sizes are the log's in every sample: a broadcast, which XLA reads from the log, never stored.
    out.update({f: jnp.broadcast_to(log[f][None], (1 + num_rollouts, n_obj, steps)) for f in SIZES})
    return {f: out[f] for f in mf.TRAJECTORY_FIELDS}


def _scene_realism(
    config: Any,
    spec: challenges.ChallengeSpec,
    layout: mf.FeatureLayout,
    a: dict,
    rollouts: dict,
    host: HostSearches | None,
    features: tuple,
) -> Any:
    """Every `scenario_fields()` value of one prepared scene (leading scene axis removed) and its rollouts."""
    both = scene_features(spec, layout, a, rollouts, host, features)
    values = metric_values(config, both.samples(slice(0, 1)), both.samples(slice(1, None)), object_mask=a["evaluated"])
    return {f: values[f] for f in scenario_fields()}


def _scene_realism_per_object(
    config: Any,
    spec: challenges.ChallengeSpec,
    layout: mf.FeatureLayout,
    a: dict,
    rollouts: dict,
    host: HostSearches | None,
    features: tuple,
) -> Any:
    """`_scene_realism`'s fields, and each likelihood field per object in the rollouts' columns:
    (fields, {field: float32 `(max_agents,)`}, {field: int32 `(max_agents,)`}); one set of log-likelihoods."""
    both = scene_features(spec, layout, a, rollouts, host, features)
    log, sim = both.samples(slice(0, 1)), both.samples(slice(1, None))
    lls = metric_log_likelihoods(config, log, sim, a["evaluated"])
    values = metric_values(config, log, sim, lls, object_mask=a["evaluated"])
    per_object = per_object_likelihoods(config, log, sim, lls, object_mask=a["evaluated"])
    max_agents = rollouts["x"].shape[1]
    # Evaluated rows to their users' columns; other rows to the dropped column `max_agents`.
    rows = jnp.where(a["evaluated"], a["columns"][: layout.num_evaluated], max_agents)

    def to_columns(v: Any, fill: Any) -> Any:
        return jnp.full((max_agents + 1,), fill, v.dtype).at[rows].set(v)[:max_agents]

    return (
        {f: values[f] for f in scenario_fields()},
        {f: to_columns(per_object[f][0], np.nan) for f in active_likelihood_fields()},
        {f: to_columns(per_object[f][1], 0) for f in active_likelihood_fields()},
    )


# Bounded: a function holds its scene set's host searches (maps) while it is cached.
# The registry's features and metrics are part of the key: registering one compiles anew.
@functools.lru_cache(maxsize=32)
def _realism_fn(
    config_name: str,
    challenge: str,
    layout: mf.FeatureLayout,
    mode: str,
    host: HostSearches | None,
    per_object: bool = False,
    features: tuple = (),
    metrics: tuple = (),
) -> Any:
    config = load_config(config_name)
    spec = challenges.spec(challenge)
    scene = _scene_realism_per_object if per_object else _scene_realism

    def one(a: Any, rollouts: Any) -> Any:
        with _precision(mode):  # read while tracing; the mode is part of this function's cache key
            return scene(config, spec, layout, a, rollouts, host, features)

    return jax.jit(_scenes_in_mode(one, mode))


@functools.lru_cache(maxsize=32)
def _features_fn(
    challenge: str, layout: mf.FeatureLayout, mode: str, host: HostSearches | None, features: tuple
) -> Any:
    def one(a: Any, rollouts: Any) -> Any:
        with _precision(mode):
            both = scene_features(challenges.spec(challenge), layout, a, rollouts, host, features)
        return {k: v for k, v in both.as_dict().items() if k != "object_id"}

    return jax.jit(_scenes_in_mode(one, mode))


def _scenes_in_mode(one: Any, mode: str) -> Any:
    """`one` over the stacked scenes (`jax_driver.vmap_scenes`); in exact mode rewritten by `exact_rounding`
    (exact on any device). The rewrite wraps the `vmap`: batching the unrewritten program is faster."""
    batched = jax_driver.vmap_scenes(one)
    if mode != "exact":
        return batched
    rounded = exactly_rounded(batched)
    return lambda a, rollouts: rounded(a["opaque_zero"][0], a, rollouts)


def realism(
    prepared: PreparedScenes,
    x: Any,
    y: Any,
    z: Any,
    heading: Any,
    *,
    length: Any = None,
    width: Any = None,
    height: Any = None,
    mode: str | None = None,
    per_object: bool = False,
) -> Realism:
    """Every `SimAgentMetrics` field of every scene, from rollouts on the device.

    Args:
      prepared: from `prepare`. In your jitted step, an argument of the jit (`jax.jit(step)(prepared, ...)`
        or `jit_step`), not closed over: closed over, its arrays become constants of the program (a
        warning says so once, beyond `CLOSED_OVER_WARNING_BYTES`).
      x, y, z, heading: float `(num_scenes, num_rollouts, max_agents, num_steps)` (see the module):
        columns in the order of `prepared.sim_agent_ids`; 80 steps (sim agents) or 91 (scenario gen).
        JAX arrays, numpy arrays or any `__dlpack__` array on JAX's device.
      length, width, height: the submitted box sizes, same shape (scenario gen only, required there).
      mode: "float32", "exact" or None (the trace's: "exact" under x64, else "float32"); see the module.
      per_object: also each evaluated object's likelihoods and their counts (`Realism.per_object`,
        `Realism.per_object_counts`), from the same log-likelihoods (another compiled program).
    Returns:
      a `Realism`: field name -> `(num_scenes,)` device array, float32 (the meta-metric float64 in
      exact mode, as `score_scenario` returns it before rounding to float), and the mode.
    Works under `jax.jit`, `jax.vmap` and `lax.scan` (e.g. over several rollout sets of the same scenes).
    """
    mode = resolve_mode(mode)
    fields = rollout_fields(prepared, x, y, z, heading, {"length": length, "width": width, "height": height})
    run = functools.partial(
        _realism_fn,
        prepared.config,
        prepared.challenge,
        mode=mode,
        host=prepared.host_searches,
        features=registry.features(),
        metrics=active_metrics(),
    )
    if per_object:
        run = functools.partial(run, per_object=True)
    parts = [
        run(layout)(arrays, take_scenes(fields, indices))
        for arrays, (indices, layout) in zip(prepared.arrays, prepared.groups)
    ]
    if per_object:
        metrics, values, counts = in_scene_order(prepared, parts)
        return Realism(metrics, mode, per_object=values, per_object_counts=counts)
    return Realism(in_scene_order(prepared, parts), mode)


def in_scene_order(prepared: PreparedScenes, parts: list) -> Any:
    """Group results (pytrees with a leading scene axis) put back in the order of `prepared.scenario_ids`."""
    if len(parts) == 1:
        return parts[0]
    order = np.argsort(np.concatenate([np.asarray(indices) for indices, _ in prepared.groups]), kind="stable")
    return jax.tree_util.tree_map(lambda *leaves: jnp.concatenate(leaves)[order], *parts)


def features(
    prepared: PreparedScenes,
    x: Any,
    y: Any,
    z: Any,
    heading: Any,
    *,
    length: Any = None,
    width: Any = None,
    height: Any = None,
    mode: str | None = None,
) -> mf.MetricFeatures:
    """The per-step features behind `realism` (same arguments), a `MetricFeatures` of device arrays.

    Every field has the leading axes `(num_scenes, 1 + num_rollouts, num_evaluated_rows)`: sample 0 is
    the log; the first `len(scenario.evaluated_ids())` rows of a scene are its evaluated objects in the
    official order, the others padding. In exact mode on CPU (with `jax_backend.exact_cpu()`) they are
    bit-identical to the official features; in float32 mode a last bit may differ.
    """
    mode = resolve_mode(mode)
    fields = rollout_fields(prepared, x, y, z, heading, {"length": length, "width": width, "height": height})
    rows = prepared.layout.num_evaluated
    parts = []
    for arrays, (indices, layout) in zip(prepared.arrays, prepared.groups):
        fn = _features_fn(prepared.challenge, layout, mode, prepared.host_searches, registry.features())
        out = fn(arrays, take_scenes(fields, indices))
        # Groups have different row counts: pad rows (axis 2) to the largest group's.
        parts.append(
            {k: jnp.pad(v, [(0, 0), (0, 0), (0, rows - v.shape[2])] + [(0, 0)] * (v.ndim - 3)) for k, v in out.items()}
        )
    out = in_scene_order(prepared, parts)
    return mf.MetricFeatures.from_dict({"object_id": np.zeros(rows, np.int32), **out})
