"""Scenario features under `jax.jit` / `vmap`, batched over scenarios padded to buckets.

Host side (numpy, `prepare`): the samples in the official object order
(`arrays.samples`), the road-edge segments, stop lines and lane segments, and
everything that depends on the official tensor shapes (the trailing-packet
masks of `float32_math`) are prepared from the real shapes, then padded to a
bucket: the next power of two of the object, evaluated-object and signal
counts, and the next multiple of a quarter of the next power of two of the
road-edge and lane segment counts (`bucket`, `fine_bucket`). The inputs,
sizes, bucket keys, padding and device features are `jax_driver`'s, shared
with `jax_realism`; the map arrays and their padding are those of the
registered features (`features.registry`). Scenarios of one bucket share one
compiled function and are stacked and `vmap`ped. The device
runs the same orchestration as numpy (`metric_features.per_step_features`)
with the dense search (`features.dense.DenseSearch`), the red-light lane
search included, so features are bit-identical on CPU. Each program traced is kept
between runs (`program_cache`: read back, it skips the 3-4 s of tracing and lowering).

Exactness on any device: XLA fuses a multiply followed by an add into one fused
multiply-add (one rounding instead of two) on a GPU and on a CPU with FMA, and GPU
compilers approximate float32 division and square root. The official float32
arithmetic rounds each operation, so the features' program is rewritten
(`exact_rounding.exactly_rounded`) so that no compiler can do either: no flag is
needed. `exact_cpu()` (XLA's CPU code restricted to AVX, no FMA) predates that
rewrite and stays for programs that call it.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable, Iterable
from typing import Any

import jax
import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.rollouts import RolloutArrays
from wosac_eval.arrays.samples import SampleBatch, sample_batch
from wosac_eval.arrays.scenario import ScenarioArrays
from wosac_eval.backends import program_cache
from wosac_eval.backends.exact_rounding import exactly_rounded
from wosac_eval.backends.jax_driver import (  # noqa: F401
    MIN_BUCKET,
    BucketKey,
    SceneInputs,
    Sizes,
    bucket,
    device_features,
    drop_programs_near_map_limit,
    fine_bucket,
    padded_inputs,
    scene_inputs,
    stacked,
    vmap_scenes,
)
from wosac_eval.features import metric_features as mf
from wosac_eval.features.registry import scene_map_arrays

EXACT_CPU_FLAG = "--xla_cpu_max_isa=AVX"  # XLA's CPU code without FMA: every float32 op rounded alone

_F = np.float32
# Object pairs (samples x steps x evaluated x objects) of one batched call, summed over its
# scenarios: big scenes are batched fewer at a time so that memory stays bounded.
PAIRS_PER_BATCH = 1 << 23


def exact_cpu() -> None:
    """Restricts XLA's CPU code to AVX (no fused multiply-adds); no longer needed for exact features.

    Adds `EXACT_CPU_FLAG` to `XLA_FLAGS` unless it already names a CPU instruction set, then checks
    that XLA's CPU compiler honours it. It applies to every JAX computation of the process on CPU
    (the caller's own model too: no FMA, no AVX-512), so it is the program's choice, made before its
    first JAX computation; the CLI makes it for `--backend jax`.

    Raises:
      RuntimeError: XLA's CPU backend had already started with fused multiply-adds.
    """
    flags = os.environ.get("XLA_FLAGS")
    if "xla_cpu_max_isa" not in (flags or ""):
        os.environ["XLA_FLAGS"] = f"{flags or ''} {EXACT_CPU_FLAG}".strip()
    if fma_contraction(jax.devices("cpu")[0]):
        # The flags back as they were: the running compiler ignores them, while a child process and JAX's
        # compilation cache key (which hashes XLA_FLAGS) would take them for the compiler's settings.
        if flags is None:
            os.environ.pop("XLA_FLAGS", None)
        else:
            os.environ["XLA_FLAGS"] = flags
        raise RuntimeError(
            "XLA's CPU backend already started with fused multiply-adds: set "
            f"XLA_FLAGS={EXACT_CPU_FLAG} in the environment (or call exact_cpu()) before "
            "the program's first JAX computation"
        )


def fma_contraction(device: jax.Device | None = None) -> bool:
    """True when XLA fuses `a * b + c` into one rounding on `device` (default: JAX's default device).

    With fusion, float32 results differ from numpy (and the official code) in
    the last bit; the features are then close, not bit-identical.
    """
    device = device or jax.devices()[0]
    if device not in _FMA_PROBED:
        a = np.float32(1 + 2.0**-12)
        c = np.float32(-(1 + 2.0**-11))
        # a * a = 1 + 2**-11 + 2**-24 rounds (ties to even) to 1 + 2**-11, so
        # separate roundings give exactly 0 and a fused one gives 2**-24.
        put = lambda v: jax.device_put(np.array([v]), device)  # noqa: E731
        out = jax.jit(lambda a, b, c: a * b + c)(put(a), put(a), put(c))
        _FMA_PROBED[device] = bool(np.asarray(out)[0] != 0)
    return _FMA_PROBED[device]


_FMA_PROBED: dict = {}


# --- Host preparation ----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class PreparedScenario:
    """One scenario's inputs for the jitted features, unpadded.

    Attributes:
      scenario_id: the scenario's id.
      batch: the samples (kept on the host to assemble `MetricFeatures`).
      inputs: the host arrays (`jax_driver.SceneInputs`: trajectories, tails, map arrays, layout).
    """

    scenario_id: str
    batch: SampleBatch
    inputs: SceneInputs

    @property
    def layout(self) -> mf.FeatureLayout:
        return self.inputs.layout

    @property
    def bucket_key(self) -> BucketKey:
        """The padded sizes (`jax_driver.BucketKey`): scenarios with one key share a compiled function."""
        return self.inputs.bucket_key()


def map_arrays(
    scenario: ScenarioArrays, context: mf.MapContext, layout: mf.FeatureLayout, num_steps: int, cells: bool = True
) -> dict:
    """The dense search's unpadded map arrays of a scenario (`features.registry.scene_map_arrays`)."""
    return scene_map_arrays(scenario, context, layout, num_steps, cells)


def prepare(
    scenario: ScenarioArrays,
    rollouts: RolloutArrays,
    context: mf.MapContext | None = None,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
) -> PreparedScenario:
    """Host-side inputs of one scenario: the log as sample 0, then one sample per rollout."""
    context = context or mf.map_context(scenario)
    batch = sample_batch(scenario, rollouts, challenge)
    layout = mf.feature_layout(batch.spec, batch.num_evaluated)
    return PreparedScenario(
        scenario_id=scenario.scenario_id,
        batch=batch,
        inputs=scene_inputs(scenario, mf.trajectory_arrays(batch), layout, context),
    )


# --- Compiled functions ----------------------------------------------------------------------------


@functools.cache
def _features_fn(layout: mf.FeatureLayout, features: tuple) -> Any:
    """Jitted features (`features`, registry entries) of a stack of scenarios (leading axis) of one bucket."""

    def one_scene(traj: Any, tails: Any, maps: Any) -> Any:
        return device_features(traj, tails, maps, layout, features)

    # Traced under x64: every float32 product, quotient, root and transcendental rounded once from
    # float64, so no compiler (a GPU's, or a CPU's with FMA) can fuse or approximate it; `zero` is 0,
    # an argument so that the compiler cannot see it (`exact_rounding`). The rewrite wraps the `vmap`: it
    # reads the batched program, traced faster than a rewritten one batched.
    return jax.jit(exactly_rounded(vmap_scenes(one_scene)))


def _features_program(layout: mf.FeatureLayout, features: tuple, args: Any) -> Callable:
    """`_features_fn(layout, features)` for `args`, kept between runs (`program_cache`) when every kernel
    is this package's."""
    jitted = _features_fn(layout, features)
    if not all(program_cache.is_ours(f.kernel) for f in features):
        return jitted
    static = repr(layout) + "".join(
        f"|{f.name}:{f.kernel.__module__}.{f.kernel.__qualname__}:{f.dtype}:{','.join(f.needs)}" for f in features
    )
    return program_cache.kept("features", static, jitted, args)


def _per_call(key: BucketKey, max_batch: int) -> int:
    """Scenarios of one bucket per call: at most `max_batch`, fewer for big scenes; a power of two."""
    fit = max(1, PAIRS_PER_BATCH // (key.samples * key.steps * key.sizes.objects * key.sizes.evaluated))
    return 1 << (min(max(max_batch, 1), fit).bit_length() - 1)


class FeaturePipeline:
    """Features of a stream of prepared scenarios, the device kept busy while the host works.

    Scenarios are grouped by bucket; a group's batch is dispatched to the device as soon as it is
    full (JAX returns at once: the computation runs asynchronously), and results are collected one
    batch behind, so that the host prepares the next scenarios and finishes the previous ones while
    the device computes. Each scenario's features are the same however it was batched.

    Usage: `for tag, (log, sim) in pipeline.add(tag, p)` ... then `pipeline.finish()` likewise.
    """

    def __init__(self, max_batch: int = 8, min_bucket: Sizes | tuple | None = None, in_flight: int = 1) -> None:
        self.max_batch, self.min_bucket, self.in_flight = max_batch, min_bucket, in_flight
        self.groups: dict[BucketKey, list] = {}
        self.dispatched: list = []
        self.compiled: set = set()  # the (bucket, layout, batch size) of the programs compiled here

    def _key(self, p: PreparedScenario) -> BucketKey:
        # A shorter lower bound (no grid cells, say) leaves the other sizes as they are.
        return p.inputs.bucket_key(self.min_bucket)

    def add(self, tag: Any, p: PreparedScenario) -> list:
        """Queues a scenario; returns the (tag, (log, sim)) of the batches now collected."""
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

    def _dispatch(self, key: BucketKey, items: list) -> None:
        layout = dataclasses.replace(items[0][1].layout, num_evaluated=key.sizes.evaluated)
        padded = [padded_inputs(p.inputs, key.sizes) for _, p in items]
        size = min(bucket(len(items), 1), _per_call(key, self.max_batch))
        padded += [padded[0]] * (size - len(padded))  # a partial batch repeats its first scenario
        program = (key, layout, size)
        # A new program is compiled: within the process's memory-map limit (`drop_programs_near_map_limit`).
        if program not in self.compiled and drop_programs_near_map_limit([out for _, out in self.dispatched]):
            self.compiled.clear()
        self.compiled.add(program)
        with jax.enable_x64(True):
            args = (np.zeros((), np.int32), *stacked(padded))  # the exact mode's run-time zero
            self.dispatched.append((items, _features_program(layout, key.features, args)(*args)))

    def _collect(self, keep: int) -> list:
        done = []
        while len(self.dispatched) > keep:
            items, out = self.dispatched.pop(0)
            out = jax.device_get(out)
            for j, (tag, p) in enumerate(items):
                e = slice(0, p.layout.num_evaluated)
                done.append((tag, mf.metric_features(p.batch, {k: np.asarray(v[j])[:, e] for k, v in out.items()})))
        return done


def prepared_features(
    prepared: list[PreparedScenario], max_batch: int = 8, min_bucket: Sizes | tuple | None = None
) -> list[tuple[mf.MetricFeatures, mf.MetricFeatures]]:
    """(log features, simulated features) of each prepared scenario, in order (`FeaturePipeline`).

    Args:
      min_bucket: optional lower bound of the bucket sizes (a `jax_driver.Sizes`, or a tuple in its
        `as_tuple()` order: objects, evaluated objects, road-edge segments, signals, lane segments,
        road-edge grid cells), to pad more than needed.
    """
    pipeline = FeaturePipeline(max_batch=max_batch, min_bucket=min_bucket)
    results: list = [None] * len(prepared)
    for i, p in enumerate(prepared):
        for tag, features in pipeline.add(i, p):
            results[tag] = features
    for tag, features in pipeline.finish():
        results[tag] = features
    return results


def scenario_features(
    scenario: ScenarioArrays,
    rollouts: RolloutArrays,
    context: mf.MapContext | None = None,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
) -> tuple[mf.MetricFeatures, mf.MetricFeatures]:
    """JAX counterpart of `metric_features.scenario_features` (same results on CPU)."""
    return prepared_features([prepare(scenario, rollouts, context, challenge)])[0]


def scenarios_features(
    pairs: Iterable[tuple[ScenarioArrays, RolloutArrays]],
    max_batch: int = 8,
    min_bucket: Sizes | tuple | None = None,
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
) -> list[tuple[mf.MetricFeatures, mf.MetricFeatures]]:
    """Features of many (ScenarioArrays, RolloutArrays) pairs, batched by bucket."""
    return prepared_features(
        [prepare(s, r, challenge=challenge) for s, r in pairs], max_batch=max_batch, min_bucket=min_bucket
    )
