"""Scenario features under `jax.jit` / `vmap`, batched over scenarios padded to buckets.

Host side (numpy, `prepare`): the samples in the official object order
(`arrays.samples`), the road-edge segments, stop lines and lane segments, and
everything that depends on the official tensor shapes (the trailing-packet
masks of `float32_math`) are prepared from the real shapes, then padded to a
bucket: the next power of two of the object, evaluated-object and signal
counts, and the next multiple of a quarter of the next power of two of the
road-edge and lane segment counts (`bucket`, `fine_bucket`). Scenarios of one
bucket share one compiled function and are stacked and `vmap`ped. The device
runs the same orchestration as numpy (`metric_features.per_step_features`)
with the dense search (`features.dense.DenseSearch`), the red-light lane
search included, so features are bit-identical on CPU.

Exactness on CPU: XLA's CPU compiler fuses a multiply followed by an add into
one fused multiply-add (one rounding instead of two) whenever the processor
has FMA instructions. The official float32 arithmetic rounds each operation,
so bit-identical features need XLA's CPU code restricted to AVX, which has no
FMA (`XLA_FLAGS=--xla_cpu_max_isa=AVX`). That is the process's setting, not a
library's: importing wosac-eval leaves it alone, `exact_cpu()` opts in (the
CLI's `--backend jax` does), and without it features may differ in the last
bit (a RuntimeWarning says so once per process).
"""
from __future__ import annotations

import dataclasses
import functools
import os
import warnings

import jax
import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.samples import SampleBatch, sample_batch
from wosac_eval.arrays.scenario import ScenarioArrays
from wosac_eval.features import dense, road_edge, traffic_lights
from wosac_eval.features import metric_features as mf
from wosac_eval.features.spatial import non_finite_pick

EXACT_CPU_FLAG = "--xla_cpu_max_isa=AVX"  # XLA's CPU code without FMA: every float32 op rounded alone

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


def exact_cpu() -> None:
    """Opts this process in to bit-identical features on XLA's CPU (no fused multiply-adds).

    Adds `EXACT_CPU_FLAG` to `XLA_FLAGS` unless it already names a CPU instruction set, then checks
    that XLA's CPU compiler honours it. It applies to every JAX computation of the process on CPU
    (the caller's own model too: no FMA, no AVX-512), so it is the program's choice, made before its
    first JAX computation; the CLI makes it for `--backend jax`.

    Raises:
      RuntimeError: XLA's CPU backend had already started with fused multiply-adds.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_max_isa" not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {EXACT_CPU_FLAG}".strip()
    if fma_contraction(jax.devices("cpu")[0]):
        raise RuntimeError("XLA's CPU backend already started with fused multiply-adds: set "
                           f"XLA_FLAGS={EXACT_CPU_FLAG} in the environment (or call exact_cpu()) before "
                           "the program's first JAX computation")


def fma_contraction(device=None) -> bool:
    """True when XLA fuses `a * b + c` into one rounding on `device` (default: JAX's default device).

    With fusion, float32 results differ from numpy (and the official code) in
    the last bit; the features are then close, not bit-identical.
    """
    device = device or jax.devices()[0]
    if device not in _FMA_PROBED:
        a = np.float32(1 + 2.0 ** -12)
        c = np.float32(-(1 + 2.0 ** -11))
        # a * a = 1 + 2**-11 + 2**-24 rounds (ties to even) to 1 + 2**-11, so
        # separate roundings give exactly 0 and a fused one gives 2**-24.
        put = lambda v: jax.device_put(np.array([v]), device)  # noqa: E731
        out = jax.jit(lambda a, b, c: a * b + c)(put(a), put(a), put(c))
        _FMA_PROBED[device] = bool(np.asarray(out)[0] != 0)
    return _FMA_PROBED[device]


_FMA_PROBED: dict = {}


def _warn_if_inexact() -> None:
    if fma_contraction():
        warnings.warn("XLA fuses multiply-adds on this device (a GPU, or the CPU without "
                      "wosac_eval.backends.jax_backend.exact_cpu() or XLA_FLAGS=--xla_cpu_max_isa=AVX set "
                      "before JAX started): jax-backend features may differ from numpy in the last bit",
                      RuntimeWarning, stacklevel=3)


# --- Host preparation ----------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class PreparedScenario:
    """One scenario's inputs for the jitted features, unpadded.

    Attributes:
      scenario_id: the scenario's id.
      batch: the samples (kept on the host to assemble `MetricFeatures`).
      traj: `per_step_features`' trajectory arrays `(num_samples, num_objects, num_steps)`.
      tails: `metric_features.official_tails` of the real shapes.
      maps: road-edge segments, stop lines and lane segments (`dense.DenseSearch`).
      layout: the unpadded feature layout.
    """

    scenario_id: str
    batch: SampleBatch
    traj: dict
    tails: dict
    maps: dict
    layout: mf.FeatureLayout

    @property
    def bucket_key(self) -> tuple:
        """(samples, steps, first step, objects, evaluated objects, road-edge segments, signals, lane segments,
        road-edge grid cells) after padding: scenarios with one key share a compiled function."""
        samples, objects, steps = self.traj["x"].shape
        # Evaluated objects: every padded row is computed against everything, so no minimum.
        return (samples, steps, self.layout.first_step, bucket(objects), bucket(self.layout.num_evaluated, 1),
                fine_bucket(len(self.maps["start"])), bucket(len(self.maps["signal_lane_id"]), 1),
                fine_bucket(len(self.maps["lane_start"])), fine_bucket(len(self.maps["cell_clearance"])))


def _segment_arrays(table: road_edge.SegmentTable, cells: bool = True) -> dict:
    """The valid road-edge segments, in official order, with their neighbours' geometry, and their cell
    table (`cells`; else a one-cell table that settles nothing, for a scene the device never searches)."""
    idx = np.flatnonzero(table.valid)
    cells = road_edge.cell_candidate_table(table.start[idx], table.delta[idx]) if cells \
        else road_edge.unsettling_cell_table()
    # And the official pick for points with a NaN or infinite coordinate, which may be a padding segment.
    fallback = _segments_at(table, np.array([non_finite_pick(table.valid)]))
    return {**{f"cell_{k}": v for k, v in cells.items()}, **_segments_at(table, idx),
            **{dense.NON_FINITE_PREFIX + k: v for k, v in fallback.items()}}


def _segments_at(table: road_edge.SegmentTable, idx: np.ndarray) -> dict:
    """Segments `idx` of the table with their neighbours' geometry, `(len(idx), ...)`."""
    prior, nxt = table.prior[idx], table.next[idx]
    return {"start": table.start[idx], "delta": table.delta[idx],
            "prior_start": table.start[prior], "prior_delta": table.delta[prior],
            "next_start": table.start[nxt], "next_delta": table.delta[nxt],
            "valid": table.valid[idx], "prior_valid": table.prior_valid[idx],
            "next_valid": table.next_valid[idx], "convex_before": table.convex_before[idx],
            "convex_after": table.convex_after[idx]}


def _red_light_arrays(signals, lanes: traffic_lights.LaneTable | None, num_steps: int) -> dict:
    """Stop lines `(num_steps, num_signals, ...)` of the signals that can be violated, and the lane segments."""
    none = {"stop_start": np.zeros((num_steps, 0, 2), _F), "stop_delta": np.zeros((num_steps, 0, 2), _F),
            "stop_point": np.zeros((num_steps, 0, 2), _F), "stopping": np.zeros((num_steps, 0), bool),
            "signal_lane_id": np.zeros(0, np.int32), "lane_start": np.zeros((0, 2), _F),
            "lane_delta": np.zeros((0, 2), _F), "lane_valid": np.zeros(0, bool), "lane_id": np.zeros(0, np.int32)}
    if lanes is None or signals is None:
        return none
    if signals.state.shape[0] != num_steps:
        raise ValueError(f"the scenario has {signals.state.shape[0]} dynamic map states, "
                         f"expected one per step ({num_steps})")
    start, delta, lane_known = traffic_lights.stop_point_segments(lanes, signals)
    seg = np.flatnonzero(lanes.valid)
    # The device only compares lane ids: their ranks among the scene's ids fit int32 (x64 off).
    signal_lane, segment_lane = np.split(
        np.unique(np.concatenate([signals.lane_id, lanes.lane_ids[seg // lanes.num_segments]]),
                  return_inverse=True)[1].astype(np.int32), [len(signals.lane_id)])
    return {"stop_start": start.astype(_F), "stop_delta": delta.astype(_F),
            "stop_point": signals.stop_point.astype(_F),
            "stopping": np.isin(signals.state, traffic_lights.LANE_STATE_STOP_VALUES) & lane_known,
            "signal_lane_id": signal_lane,
            "lane_start": lanes.start[seg], "lane_delta": lanes.delta[seg], "lane_valid": np.ones(len(seg), bool),
            "lane_id": segment_lane}


def map_arrays(scenario: ScenarioArrays, context: mf.MapContext, layout: mf.FeatureLayout, num_steps: int,
               cells: bool = True) -> dict:
    """The dense search's unpadded map arrays of a scenario: road-edge segments (with their cell table
    unless `cells` is False), stop lines, lane segments."""
    signals = mf.signals_from(scenario.signals, layout.first_red_light_step)
    return {**_segment_arrays(context.road_edges, cells),
            **_red_light_arrays(signals, context.lanes, num_steps - layout.first_red_light_step)}


def prepare(scenario: ScenarioArrays, rollouts: RolloutArrays, context: mf.MapContext | None = None,
            challenge=challenges.Challenge.SIM_AGENTS) -> PreparedScenario:
    """Host-side inputs of one scenario: the log as sample 0, then one sample per rollout."""
    context = context or mf.map_context(scenario)
    batch = sample_batch(scenario, rollouts, challenge)
    layout = mf.feature_layout(batch.spec, batch.num_evaluated)
    num_objects, num_steps = batch.trajectories.num_objects, batch.trajectories.num_steps
    return PreparedScenario(scenario_id=scenario.scenario_id, batch=batch, traj=mf.trajectory_arrays(batch),
                            maps=map_arrays(scenario, context, layout, num_steps), layout=layout,
                            tails=mf.official_tails(num_objects, batch.num_evaluated, num_steps, layout.first_step))


def _pad_axis(a: np.ndarray, size: int, axis: int, value=0) -> np.ndarray:
    a = np.asarray(a)
    if a.shape[axis] == size:
        return a
    widths = [(0, 0)] * a.ndim
    widths[axis] = (0, size - a.shape[axis])
    return np.pad(a, widths, constant_values=value)


_NO_LANE = -2  # the lane rank of padded signals: neither a lane's nor a point's without lane (-1)


def padded_inputs(traj: dict, tails: dict, maps: dict, key: tuple) -> tuple[dict, dict, dict]:
    """A scenario's `traj`, `tails` and `maps` (as in `PreparedScenario`) padded to the bucket `key`
    (see `PreparedScenario.bucket_key`); padding is invalid everywhere."""
    _, _, _, n_obj, n_eval, n_seg, n_sig, n_lane, n_cell = key

    def pad_map(name: str, a: np.ndarray) -> np.ndarray:
        if name in ("cell_origin", "cell_shape") or name.startswith(dense.NON_FINITE_PREFIX):
            return a
        if name.startswith("cell"):  # rows past the grid are never looked up
            return _pad_axis(a, n_cell, 0)
        if name.startswith("stop"):
            return _pad_axis(a, n_sig, 1)
        if name == "signal_lane_id":
            return _pad_axis(a, n_sig, 0, _NO_LANE)
        return _pad_axis(a, n_lane if name.startswith("lane") else n_seg, 0)

    return ({name: _pad_axis(a, n_obj, 1) for name, a in traj.items()},
            {"heading_tail": _pad_axis(tails["heading_tail"], n_obj, 0),
             "ego_tail": _pad_axis(tails["ego_tail"], n_eval, 1),
             "pair_tail": _pad_axis(_pad_axis(tails["pair_tail"], n_eval, 1), n_obj, 2)},
            {name: pad_map(name, a) for name, a in maps.items()})


# --- Compiled functions ----------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def _features_fn(layout: mf.FeatureLayout):
    """Jitted features of a stack of scenarios (leading axis) of one bucket."""
    def one_scene(traj, tails, maps):
        return mf.per_step_features(traj, layout, dense.DenseSearch(maps), tails)

    return jax.jit(jax.vmap(one_scene))


def _per_call(key: tuple, max_batch: int) -> int:
    """Scenarios of one bucket per call: at most `max_batch`, fewer for big scenes; a power of two."""
    samples, steps, _, n_obj, n_eval = key[:5]
    fit = max(1, PAIRS_PER_BATCH // (samples * steps * n_obj * n_eval))
    return 1 << (min(max(max_batch, 1), fit).bit_length() - 1)


class FeaturePipeline:
    """Features of a stream of prepared scenarios, the device kept busy while the host works.

    Scenarios are grouped by bucket; a group's batch is dispatched to the device as soon as it is
    full (JAX returns at once: the computation runs asynchronously), and results are collected one
    batch behind, so that the host prepares the next scenarios and finishes the previous ones while
    the device computes. Each scenario's features are the same however it was batched.

    Usage: `for tag, (log, sim) in pipeline.add(tag, p)` ... then `pipeline.finish()` likewise.
    """

    def __init__(self, max_batch: int = 8, min_bucket: tuple | None = None, in_flight: int = 1):
        self.max_batch, self.min_bucket, self.in_flight = max_batch, min_bucket, in_flight
        self.groups: dict[tuple, list] = {}
        self.dispatched: list = []

    def _key(self, p: PreparedScenario) -> tuple:
        key = p.bucket_key
        # A shorter lower bound (no grid cells, say) leaves the other sizes as they are.
        return key if self.min_bucket is None else key[:3] + tuple(map(max, key[3:], (*self.min_bucket, 0, 0, 0, 0, 0, 0)))

    def add(self, tag, p: PreparedScenario) -> list:
        """Queues a scenario; returns the (tag, (log, sim)) of the batches now collected."""
        _warn_if_inexact()
        key = self._key(p)
        group = self.groups.setdefault(key, [])
        group.append((tag, p))
        if len(group) == _per_call(key, self.max_batch):
            self._dispatch(key, self.groups.pop(key))
        return self._collect(self.in_flight)

    def finish(self) -> list:
        """Dispatches the partial batches and collects everything."""
        for key in list(self.groups):
            self._dispatch(key, self.groups.pop(key))
        return self._collect(0)

    def _dispatch(self, key: tuple, items: list) -> None:
        layout = dataclasses.replace(items[0][1].layout, num_evaluated=key[4])
        padded = [padded_inputs(p.traj, p.tails, p.maps, key) for _, p in items]
        size = min(bucket(len(items), 1), _per_call(key, self.max_batch))
        padded += [padded[0]] * (size - len(padded))  # a partial batch repeats its first scenario
        stacked = [{k: np.stack([part[j][k] for part in padded]) for k in padded[0][j]} for j in range(3)]
        with jax.enable_x64(True):
            self.dispatched.append((items, _features_fn(layout)(*stacked)))

    def _collect(self, keep: int) -> list:
        done = []
        while len(self.dispatched) > keep:
            items, out = self.dispatched.pop(0)
            out = jax.device_get(out)
            for j, (tag, p) in enumerate(items):
                e = slice(0, p.layout.num_evaluated)
                done.append((tag, mf.metric_features(p.batch, {k: np.asarray(v[j])[:, e] for k, v in out.items()})))
        return done


def prepared_features(prepared: list[PreparedScenario], max_batch: int = 8,
                      min_bucket: tuple | None = None) -> list[tuple[mf.MetricFeatures, mf.MetricFeatures]]:
    """(log features, simulated features) of each prepared scenario, in order (`FeaturePipeline`).

    Args:
      min_bucket: optional lower bound of the bucket sizes (objects,
        evaluated objects, road-edge segments, signals, lane segments, road-edge grid cells), to pad
        more than needed.
    """
    pipeline = FeaturePipeline(max_batch=max_batch, min_bucket=min_bucket)
    results: list = [None] * len(prepared)
    for i, p in enumerate(prepared):
        for tag, features in pipeline.add(i, p):
            results[tag] = features
    for tag, features in pipeline.finish():
        results[tag] = features
    return results


def scenario_features(scenario: ScenarioArrays, rollouts: RolloutArrays, context: mf.MapContext | None = None,
                      challenge=challenges.Challenge.SIM_AGENTS) -> tuple[mf.MetricFeatures, mf.MetricFeatures]:
    """JAX counterpart of `metric_features.scenario_features` (same results on CPU)."""
    return prepared_features([prepare(scenario, rollouts, context, challenge)])[0]


def scenarios_features(pairs, max_batch: int = 8, min_bucket: tuple | None = None,
                       challenge=challenges.Challenge.SIM_AGENTS) -> list[tuple[mf.MetricFeatures, mf.MetricFeatures]]:
    """Features of many (ScenarioArrays, RolloutArrays) pairs, batched by bucket."""
    return prepared_features([prepare(s, r, challenge=challenge) for s, r in pairs], max_batch=max_batch,
                             min_bucket=min_bucket)
