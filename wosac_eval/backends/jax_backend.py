"""Scenario features under `jax.jit` / `vmap`, batched over scenarios padded to buckets.

Host side (numpy): the composite trajectories in the official object order,
the road-edge and lane tables, the stop lines, and everything that depends on
the official tensor shapes (the trailing-packet masks of `float32_math`) are
prepared from the real shapes, then padded to a bucket: the next power of two
of the object, evaluated-object and signal counts, and the next multiple of a
quarter of the next power of two of the road-edge and lane segment counts
(`bucket`, `fine_bucket`). Scenarios of one bucket share one compiled function and are stacked
and `vmap`ped. The dense drivers in `wosac_eval.features.dense` evaluate the
same per-pair kernels as the numpy path, so features are bit-identical on CPU.

Exactness on CPU: XLA's CPU compiler fuses a multiply followed by an add into
one fused multiply-add (one rounding instead of two) whenever the processor
has FMA instructions. The official float32 arithmetic rounds each operation,
so importing this module (before JAX starts its CPU backend) restricts XLA's
CPU code to AVX, which has no FMA (`XLA_FLAGS=--xla_cpu_max_isa=AVX`, unless
`XLA_FLAGS` already sets `xla_cpu_max_isa`). `fma_contraction()` checks it.
"""
from __future__ import annotations

import dataclasses
import functools
import os
import warnings

_MAX_ISA_FLAG = "--xla_cpu_max_isa=AVX"


def _restrict_cpu_isa() -> None:
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_max_isa" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {_MAX_ISA_FLAG}".strip()


_restrict_cpu_isa()

import jax  # noqa: E402
import numpy as np  # noqa: E402

from wosac_eval.arrays.rollouts import RolloutArrays  # noqa: E402
from wosac_eval.arrays.scenario import CURRENT_TIME_INDEX, STEP_SECONDS, ScenarioArrays  # noqa: E402
from wosac_eval.features import dense, interaction, metric_features, road_edge, traffic_lights  # noqa: E402
from wosac_eval.features.float32_math import packet_tail  # noqa: E402
from wosac_eval.features.metric_features import FUTURE, MetricFeatures  # noqa: E402

_F = np.float32
MIN_BUCKET = 8
# Object pairs (samples x steps x evaluated x objects) of one batched call, summed over its
# scenarios: big scenes are batched fewer at a time so that memory stays bounded.
PAIRS_PER_BATCH = 1 << 23


def bucket(n: int, minimum: int = MIN_BUCKET) -> int:
    """The padded size for `n` items: the next power of two, at least `minimum`."""
    return max(minimum, 1 << max(0, int(n) - 1).bit_length())


def fine_bucket(n: int, minimum: int = 64) -> int:
    """A padded size for large counts: the next multiple of a quarter of the next power of two.

    At most a third is padding (instead of up to a half), for the road-edge
    and lane segments, which dominate the work of the dense searches.
    """
    top = bucket(n, minimum)
    step = max(minimum, top // 4)
    return max(minimum, -(-int(n) // step) * step)


@functools.lru_cache(maxsize=None)
def fma_contraction() -> bool:
    """True when XLA fuses `a * b + c` into one rounding on the default device.

    With fusion, float32 results differ from numpy (and the official code) in
    the last bit; the features are then close, not bit-identical.
    """
    a = np.float32(1 + 2.0 ** -12)
    c = np.float32(-(1 + 2.0 ** -11))
    # a * a = 1 + 2**-11 + 2**-24 rounds (ties to even) to 1 + 2**-11, so
    # separate roundings give exactly 0 and a fused one gives 2**-24.
    out = jax.jit(lambda a, b, c: a * b + c)(np.array([a]), np.array([a]), np.array([c]))
    return bool(np.asarray(out)[0] != 0)


def _warn_if_inexact() -> None:
    if fma_contraction():
        warnings.warn("XLA fuses multiply-adds on this device (JAX was started before "
                      "wosac_eval.backends.jax_backend was imported, or XLA_FLAGS sets another "
                      "xla_cpu_max_isa, or the device is a GPU): jax-backend features may differ "
                      "from numpy in the last bit", RuntimeWarning, stacklevel=3)


# --- Host preparation ----------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class PreparedScenario:
    """One scenario's inputs for the jitted features, unpadded, plus host-side results.

    `traj` and `maps` hold the arrays that `dense.sample_features` takes (before
    padding); `lanes` the compact lane segments for the red-light lane search.
    """

    scenario_id: str
    num_objects: int
    num_evaluated: int
    traj: dict
    maps: dict
    lanes: dict
    signal_lane_id: np.ndarray
    object_id: np.ndarray
    object_type: np.ndarray
    feature_valid: np.ndarray
    ade: np.ndarray
    num_log_samples: int

    @property
    def bucket_key(self) -> tuple:
        """(objects, evaluated objects, road-edge segments, signals) after padding.

        The lane segments are padded separately: only the red-light lane
        search, run on the few crossing points, uses them.
        """
        # Evaluated objects: every padded row is computed against everything, so no minimum.
        return (bucket(self.num_objects), bucket(self.num_evaluated, 1),
                fine_bucket(len(self.maps["start"])), bucket(len(self.maps["stopping"][0]), 1))


def _segment_arrays(table: road_edge.SegmentTable) -> dict:
    """The valid road-edge segments, in official order, with their neighbours' geometry."""
    idx = np.flatnonzero(table.valid)
    prior, nxt = table.prior[idx], table.next[idx]
    return {"start": table.start[idx], "delta": table.delta[idx],
            "prior_start": table.start[prior], "prior_delta": table.delta[prior],
            "next_start": table.start[nxt], "next_delta": table.delta[nxt],
            "valid": np.ones(len(idx), bool), "prior_valid": table.prior_valid[idx],
            "next_valid": table.next_valid[idx], "convex_before": table.convex_before[idx],
            "convex_after": table.convex_after[idx]}


def _stop_lines(scenario: ScenarioArrays, lanes, num_steps: int) -> tuple[dict, dict, np.ndarray]:
    """Stop-line arrays from `CURRENT_TIME_INDEX` on, compact lane segments, signal lane ids."""
    steps = num_steps - CURRENT_TIME_INDEX
    signals = scenario.signals
    if lanes is None or signals is None:
        lines = {"stop_start": np.zeros((steps, 0, 2), _F), "stop_delta": np.zeros((steps, 0, 2), _F),
                 "stop_point": np.zeros((steps, 0, 2), _F), "stopping": np.zeros((steps, 0), bool)}
        return lines, {"start": np.zeros((0, 2), _F), "delta": np.zeros((0, 2), _F),
                       "lane_id": np.zeros(0, np.int64)}, np.zeros(0, np.int64)
    if signals.state.shape[0] != num_steps:
        raise ValueError(f"the scenario has {signals.state.shape[0]} dynamic map states, "
                         f"expected one per step ({num_steps})")
    signals = metric_features._signals_from(signals, CURRENT_TIME_INDEX)
    start, delta, lane_known = traffic_lights._stop_point_segments(lanes, signals)
    stopping = np.isin(signals.state, traffic_lights.LANE_STATE_STOP_VALUES) & lane_known
    lines = {"stop_start": start.astype(_F), "stop_delta": delta.astype(_F),
             "stop_point": signals.stop_point.astype(_F), "stopping": stopping}
    seg = np.flatnonzero(lanes.valid)
    lane_segments = {"start": lanes.start[seg], "delta": lanes.delta[seg],
                     "lane_id": lanes.lane_ids[seg // lanes.num_segments]}
    return lines, lane_segments, signals.lane_id.astype(np.int64)


def _tails(num_objects: int, num_evaluated: int, num_steps: int) -> dict:
    """Trailing-packet masks of the official ops, for the real shapes."""
    return {"heading_tail": packet_tail((num_objects, num_steps))[:, FUTURE],
            "ego_tail": packet_tail((num_steps, num_evaluated, 1))[FUTURE],
            "pair_tail": packet_tail((num_steps, num_evaluated, num_objects))[FUTURE]}


def prepare(scenario: ScenarioArrays, rollouts: RolloutArrays,
            context: metric_features.MapContext | None = None) -> PreparedScenario:
    """Host-side inputs of one scenario: the log as sample 0, then one sample per rollout."""
    context = context or metric_features.map_context(scenario)
    log = metric_features.log_trajectories(scenario)
    sim = metric_features.simulated_trajectories(scenario, rollouts)
    n_eval = len(scenario.evaluated_ids)
    # Log and rollouts list the same sim agents; pad anyway should their counts differ.
    num_objects = max(log.x.shape[1], sim.x.shape[1])
    num_steps = log.x.shape[-1]
    traj = {}
    for name in ("x", "y", "z", "heading", "length", "width", "height", "valid"):
        traj[name] = np.concatenate([_pad_axis(getattr(t, name), num_objects, 1) for t in (log, sim)])
    per_group = []
    for t in (log, sim):
        tails = _tails(t.x.shape[1], n_eval, num_steps)
        tails = {"heading_tail": _pad_axis(tails["heading_tail"], num_objects, 0),
                 "ego_tail": tails["ego_tail"],
                 "pair_tail": _pad_axis(tails["pair_tail"], num_objects, 2)}
        per_group.append({k: np.broadcast_to(v, (t.x.shape[0],) + v.shape) for k, v in tails.items()})
    for name in per_group[0]:
        traj[name] = np.concatenate([g[name] for g in per_group])
    lines, lanes, signal_lane_id = _stop_lines(scenario, context.lanes, num_steps)
    maps = {**_segment_arrays(context.road_edges), **lines}
    e = slice(0, n_eval)
    object_type = np.concatenate([_pad_axis(t.object_type, num_objects, 1) for t in (log, sim)])
    ade = np.concatenate([metric_features.average_displacement_error(scenario, t) for t in (log, sim)])
    valid = np.concatenate([t.valid[:, e] for t in (log, sim)])
    return PreparedScenario(
        scenario_id=scenario.scenario_id, num_objects=num_objects, num_evaluated=n_eval, traj=traj,
        maps=maps, lanes=lanes, signal_lane_id=signal_lane_id, object_id=scenario.evaluated_ids,
        object_type=object_type[:, e], feature_valid=valid[..., FUTURE], ade=ade,
        num_log_samples=log.x.shape[0])


def _pad_axis(a: np.ndarray, size: int, axis: int, value=0) -> np.ndarray:
    a = np.asarray(a)
    if a.shape[axis] == size:
        return a
    widths = [(0, 0)] * a.ndim
    widths[axis] = (0, size - a.shape[axis])
    return np.pad(a, widths, constant_values=value)


def _padded_inputs(p: PreparedScenario, key: tuple) -> tuple[dict, dict]:
    """`traj` and `maps` padded to the bucket `key`; padding is invalid everywhere."""
    n_obj, n_eval, n_seg, n_sig = key
    traj = {}
    for name, a in p.traj.items():
        if name == "heading_tail":
            traj[name] = _pad_axis(a, n_obj, 1)
        elif name == "ego_tail":
            traj[name] = _pad_axis(a, n_eval, 2)
        elif name == "pair_tail":
            traj[name] = _pad_axis(_pad_axis(a, n_eval, 2), n_obj, 3)
        else:
            traj[name] = _pad_axis(a, n_obj, 1)
    maps = {}
    for name, a in p.maps.items():
        if name.startswith("stop"):
            maps[name] = _pad_axis(a, n_sig, 1)
        else:
            maps[name] = _pad_axis(a, n_seg, 0)
    return traj, maps


# --- Compiled functions ----------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def _features_fn(num_evaluated: int):
    """Jitted features of a stack of scenarios (leading axis) of one bucket."""
    fn = functools.partial(dense.sample_features, num_evaluated=num_evaluated,
                           seconds_per_step=STEP_SECONDS, future=FUTURE, lights_from=CURRENT_TIME_INDEX)
    return jax.jit(jax.vmap(fn))


@functools.lru_cache(maxsize=None)
def _lane_fn():
    return jax.jit(dense.nearest_lane_segment)


def _red_light(p: PreparedScenario, suspect: np.ndarray) -> np.ndarray:
    """Violations from the crossings: the lane search runs on the crossing points only.

    Args:
      suspect: bool `(num_samples, num_evaluated, steps from now, num_signals)`.
    Returns:
      bool `(num_samples, num_evaluated, future steps)`.
    """
    lights = slice(CURRENT_TIME_INDEX, None)
    e = slice(0, p.num_evaluated)
    violation = np.zeros(suspect.shape[:-1], bool)
    where = np.nonzero(suspect.any(axis=-1))
    if where[0].size:
        xy = np.stack([p.traj["x"][:, e, lights], p.traj["y"][:, e, lights]], axis=-1).astype(_F)[where]
        n_lane = fine_bucket(len(p.lanes["start"]))
        lanes = {k: _pad_axis(v, n_lane, 0) for k, v in p.lanes.items()}
        lane_valid = np.arange(n_lane) < len(p.lanes["start"])
        points = _pad_axis(xy, bucket(len(xy)), 0)
        with jax.enable_x64(True):
            best = np.asarray(_lane_fn()(points, lanes["start"], lanes["delta"], lane_valid))[: len(xy)]
        on_lane = lanes["lane_id"][best][:, None] == p.signal_lane_id[None, :]
        violation[where] = np.any(suspect[where] & on_lane, axis=-1)
    return violation[..., 1:]


def _metric_features(p: PreparedScenario, out: dict, samples: slice) -> MetricFeatures:
    e = slice(0, p.num_evaluated)
    pick = lambda name: out[name][samples, e]
    nearest, edge = pick("distance_to_nearest_object"), pick("distance_to_road_edge")
    return MetricFeatures(
        object_id=p.object_id, object_type=p.object_type[samples], valid=p.feature_valid[samples],
        average_displacement_error=p.ade[samples],
        linear_speed=pick("linear_speed"), linear_acceleration=pick("linear_acceleration"),
        angular_speed=pick("angular_speed"), angular_acceleration=pick("angular_acceleration"),
        distance_to_nearest_object=nearest,
        collision_per_step=nearest < _F(interaction.COLLISION_DISTANCE_THRESHOLD),
        time_to_collision=pick("time_to_collision"), distance_to_road_edge=edge,
        offroad_per_step=edge > _F(road_edge.OFFROAD_DISTANCE_THRESHOLD),
        traffic_light_violation_per_step=out["red_light"][samples])


def prepared_features(prepared: list[PreparedScenario], max_batch: int = 8,
                      min_bucket: tuple | None = None) -> list[tuple[MetricFeatures, MetricFeatures]]:
    """(log features, simulated features) of each prepared scenario, in order.

    Scenarios are grouped by bucket; each group is run up to `max_batch` at a
    time (fewer for big scenes, see `PAIRS_PER_BATCH`; always a power of two,
    a partial batch being padded by repeating its first scenario, so a stream
    of scenarios reuses a few compiled functions).

    Args:
      min_bucket: optional lower bound of the bucket sizes (objects,
        evaluated objects, road-edge segments, signals), to pad more than needed.
    """
    _warn_if_inexact()
    results: list = [None] * len(prepared)
    groups: dict[tuple, list[int]] = {}
    for i, p in enumerate(prepared):
        key = p.bucket_key if min_bucket is None else tuple(map(max, p.bucket_key, min_bucket))
        groups.setdefault(key, []).append(i)
    for key, members in groups.items():
        samples, steps = prepared[members[0]].traj["x"].shape[0], prepared[members[0]].traj["x"].shape[-1]
        fit = max(1, PAIRS_PER_BATCH // (samples * steps * key[0] * key[1]))
        per_call = 1 << (min(max(max_batch, 1), fit).bit_length() - 1)  # a power of two
        for lo in range(0, len(members), per_call):
            chunk = members[lo: lo + per_call]
            padded = [_padded_inputs(prepared[i], key) for i in chunk]
            size = min(bucket(len(chunk), 1), per_call)
            padded += [padded[0]] * (size - len(padded))
            traj = {k: np.stack([t[k] for t, _ in padded]) for k in padded[0][0]}
            maps = {k: np.stack([m[k] for _, m in padded]) for k in padded[0][1]}
            with jax.enable_x64(True):
                out = jax.device_get(_features_fn(key[1])(traj, maps))
            for j, i in enumerate(chunk):
                p = prepared[i]
                one = {k: np.asarray(v[j]) for k, v in out.items()}
                suspect = one.pop("red_light_suspect")[:, : p.num_evaluated, :, : len(p.signal_lane_id)]
                one["red_light"] = _red_light(p, suspect)
                n_log = p.num_log_samples
                results[i] = (_metric_features(p, one, slice(0, n_log)),
                              _metric_features(p, one, slice(n_log, None)))
    return results


def scenario_features(scenario: ScenarioArrays, rollouts: RolloutArrays,
                      context: metric_features.MapContext | None = None
                      ) -> tuple[MetricFeatures, MetricFeatures]:
    """JAX counterpart of `metric_features.scenario_features` (same results on CPU)."""
    return prepared_features([prepare(scenario, rollouts, context)])[0]


def scenarios_features(pairs, max_batch: int = 8, min_bucket: tuple | None = None
                       ) -> list[tuple[MetricFeatures, MetricFeatures]]:
    """Features of many (ScenarioArrays, RolloutArrays) pairs, batched by bucket."""
    return prepared_features([prepare(s, r) for s, r in pairs], max_batch=max_batch, min_bucket=min_bucket)
