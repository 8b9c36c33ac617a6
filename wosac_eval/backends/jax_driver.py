"""The host side shared by the JAX paths: one scene's inputs, their sizes, buckets and padding.

`--backend jax` (`jax_backend`: features of files of scenarios, batched by
bucket) and `jax_realism` (realism on device arrays in a training loop) both
prepare a scene as a `SceneInputs` (trajectories, the trailing-packet masks of
the official float32 ops, the map arrays of `features.registry`'s map parts),
measure it as `Sizes`, round sizes to a `BucketKey` or a group's maximum, and
pad to it with `padded_inputs`: every map array as its `registry.Pad` says,
never by its name, stack scenes (`stacked`), and compute their features on the
device with `device_features`. Scenes with one key share one compiled function.
"""

from __future__ import annotations

import dataclasses
import gc
from collections.abc import Iterable
from typing import Any

import jax
import numpy as np

from wosac_eval.arrays.scenario import ScenarioArrays
from wosac_eval.backends.host_search import HostSearch
from wosac_eval.features import dense, dense_road_edge, registry
from wosac_eval.features import metric_features as mf
from wosac_eval.features.registry import scene_map_arrays
from wosac_eval.features.search_strategy import SearchStrategy

MIN_BUCKET = 8


def memory_maps() -> tuple[int, int] | None:
    """(memory mappings of this process, the kernel's limit per process `vm.max_map_count`), where Linux
    says; None elsewhere."""
    try:
        with open("/proc/self/maps", "rb") as maps, open("/proc/sys/vm/max_map_count") as limit:
            return sum(1 for _ in maps), int(limit.read())
    except (OSError, ValueError):
        return None


def drop_programs_near_map_limit(pending: Any = (), share: float = 0.5) -> bool:
    """Drops JAX's compiled programs (`jax.clear_caches()`) once this process's memory mappings pass `share`
    of the kernel's limit, after `pending` (arrays still computing) is ready; True if it did.

    A program XLA compiles for the CPU holds 1,000-2,000 mappings while cached (a realism program about
    1,200): a process that compiles many shapes (a run over many buckets) reaches `vm.max_map_count`
    (65,530 by default), where the next compile's mmap fails and XLA crashes with a segmentation fault.
    A program used again is compiled again."""
    counted = memory_maps()
    if counted is None or counted[0] <= share * counted[1]:
        return False
    jax.block_until_ready(pending)
    jax.clear_caches()
    gc.collect()
    return True


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


@dataclasses.dataclass(frozen=True)
class Sizes:
    """The counts a scene is padded by: objects, evaluated objects, and the map sizes of the registry's
    map parts (`registry.Size`), by name in registry order.

    `as_tuple()` is (objects, evaluated, *map sizes): with the official features (objects, evaluated
    objects, road-edge segments, signals, lane segments, road-edge grid cells), the order of the
    `min_bucket` / `min_sizes` tuples the drivers take.
    """

    objects: int
    evaluated: int
    map: tuple[tuple[str, int], ...] = ()

    def __getitem__(self, name: str) -> int:
        return dict(self.map)[name]

    def as_tuple(self) -> tuple[int, ...]:
        return (self.objects, self.evaluated, *(n for _, n in self.map))

    def with_counts(self, counts: Iterable[int]) -> Sizes:
        """These names with `counts` in `as_tuple()` order."""
        counts = tuple(counts)
        return Sizes(counts[0], counts[1], tuple((name, n) for (name, _), n in zip(self.map, counts[2:])))

    def at_least(self, floor: Sizes | Iterable[int]) -> Sizes:
        """Each size at least `floor`'s (a `Sizes`, or a tuple in `as_tuple()` order; a shorter tuple
        bounds the first sizes only)."""
        floor = floor.as_tuple() if isinstance(floor, Sizes) else tuple(floor)
        mine = self.as_tuple()
        return self.with_counts(map(max, mine, floor + mine[len(floor) :]))

    def rounded(self, minimum_objects: int = MIN_BUCKET, minimum_fine: int = 64) -> Sizes:
        """Rounded up to bucket sizes: the next power of two of the objects (at least `minimum_objects`),
        of the evaluated objects (every padded row is computed against everything, so no minimum) and
        of the coarse map sizes; `fine_bucket` (at least `minimum_fine`) of the fine ones."""
        fine = {s.name: s.fine for part in registry.MAP_PARTS for s in part.sizes}
        return Sizes(
            bucket(self.objects, minimum_objects),
            bucket(self.evaluated, 1),
            tuple((name, fine_bucket(n, minimum_fine) if fine[name] else bucket(n, 1)) for name, n in self.map),
        )


@dataclasses.dataclass(frozen=True)
class BucketKey:
    """What a compiled function is specialised to: scenes with one key share it.

    Attributes:
      samples: the log's samples and the rollouts.
      steps: every step of a sample (91).
      first_step: the first reported step.
      sizes: the padded sizes.
      features: the registry's features computed.
    """

    samples: int
    steps: int
    first_step: int
    sizes: Sizes
    features: tuple[registry.Feature, ...] = ()


@dataclasses.dataclass(frozen=True)
class SceneInputs:
    """One scene's host arrays for the jitted features, unpadded.

    Attributes:
      traj: `per_step_features`' trajectory arrays `(num_samples, num_objects, num_steps)` (`num_samples`
        is 1 where the rollouts join on the device).
      tails: `metric_features.official_tails` of the real shapes.
      maps: the arrays of the features' map parts (`registry.map_parts`), by name.
      layout: the unpadded feature layout.
      features: the registry's features the maps were built for.
    """

    traj: dict
    tails: dict
    maps: dict
    layout: mf.FeatureLayout
    features: tuple[registry.Feature, ...]

    @property
    def num_objects(self) -> int:
        return int(self.traj["x"].shape[1])

    @property
    def sizes(self) -> Sizes:
        """The exact counts (`Sizes`)."""
        return Sizes(
            self.num_objects,
            self.layout.num_evaluated,
            tuple((s.name, s.count(self.maps)) for s in registry.map_sizes(self.features)),
        )

    def bucket_key(self, minimum: Sizes | tuple | None = None) -> BucketKey:
        """The scene's `BucketKey`: its sizes rounded (`Sizes.rounded`), then at least `minimum`."""
        samples, _, steps = self.traj["x"].shape
        sizes = self.sizes.rounded()
        return BucketKey(
            samples, steps, self.layout.first_step, sizes if minimum is None else sizes.at_least(minimum), self.features
        )


def scene_inputs(
    scenario: ScenarioArrays,
    traj: dict,
    layout: mf.FeatureLayout,
    context: mf.MapContext,
    cells: bool = True,
    features: tuple[registry.Feature, ...] | None = None,
) -> SceneInputs:
    """A scene's `SceneInputs` from its trajectory arrays (evaluated objects first).

    cells: build the road-edge cell table (the device search's; the host search needs none).
    """
    features = registry.features() if features is None else tuple(features)
    _, num_objects, num_steps = traj["x"].shape
    return SceneInputs(
        traj=traj,
        layout=layout,
        features=features,
        tails=mf.official_tails(num_objects, layout.num_evaluated, num_steps, layout.first_step),
        maps=scene_map_arrays(scenario, context, layout, num_steps, cells, features),
    )


def pad_axis(a: np.ndarray, size: int, axis: int, value: float = 0) -> np.ndarray:
    a = np.asarray(a)
    if a.shape[axis] == size:
        return a
    widths = [(0, 0)] * a.ndim
    widths[axis] = (0, size - a.shape[axis])
    return np.pad(a, widths, constant_values=value)


def padded_inputs(inputs: SceneInputs, sizes: Sizes) -> tuple[dict, dict, dict]:
    """A scene's (traj, tails, maps) padded to `sizes`; padding is invalid everywhere.

    Trajectories pad their object axis; the map arrays as their `registry.Pad` says.
    """
    n_obj, n_eval = sizes.objects, sizes.evaluated
    tails = inputs.tails
    padding = registry.map_padding(inputs.features)

    def pad_map(name: str, a: np.ndarray) -> np.ndarray:
        pad = padding[name]
        return a if pad.size is None else pad_axis(a, sizes[pad.size], pad.axis, pad.fill)

    return (
        {name: pad_axis(a, n_obj, 1) for name, a in inputs.traj.items()},
        {
            "heading_tail": pad_axis(tails["heading_tail"], n_obj, 0),
            "ego_tail": pad_axis(tails["ego_tail"], n_eval, 1),
            "pair_tail": pad_axis(pad_axis(tails["pair_tail"], n_eval, 1), n_obj, 2),
        },
        {name: pad_map(name, a) for name, a in inputs.maps.items()},
    )


def stacked(scenes: list) -> Any:
    """Per-scene pytrees (dicts of numpy arrays, or tuples of them) with a leading scene axis (numpy)."""
    return jax.tree_util.tree_map(lambda *leaves: np.stack(leaves), *scenes)


def vmap_scenes(one: Any) -> Any:
    """`jax.vmap` of `one` over the leading scene axis of every argument, where each stack of padded
    map arrays (a dict with road-edge cell tables) enters with its segments shared
    (`dense_road_edge.shared_segments`): the same result, fewer bytes moved. Call it inside the `jit`."""

    def batched(*args: Any) -> Any:
        shared, axes = zip(*map(_shared_maps, args))
        return jax.vmap(one, in_axes=axes)(*shared)

    return batched


def _shared_maps(tree: Any) -> Any:
    """(tree, its `in_axes`): 0 for every leaf, but `dense_road_edge.shared_segments` for map arrays."""
    if not isinstance(tree, dict):
        return tree, 0
    if "cell_candidates" in tree:
        return dense_road_edge.shared_segments(tree)
    pairs = {k: _shared_maps(v) for k, v in tree.items()}
    return {k: v for k, (v, _) in pairs.items()}, {k: axes for k, (_, axes) in pairs.items()}


def device_features(
    traj: dict,
    tails: dict,
    maps: dict,
    layout: mf.FeatureLayout,
    features: tuple[registry.Feature, ...],
    host: Any = None,
    scene: SceneInputs | None = None,
) -> dict:
    """`metric_features.per_step_features` of one padded scene on the device (traced).

    The searches run on the device over fixed shapes (`dense.DenseSearch` over `maps`), or, given
    `host` (`host_search.HostSearches`) and the traced `scene` index, in the numpy search called back
    from the trace (`host_search.HostSearch`).
    """
    search: SearchStrategy
    if host is None:
        search = dense.DenseSearch(maps)
    else:
        search = HostSearch(host, scene)
    return mf.per_step_features(traj, layout, search, tails, features)
