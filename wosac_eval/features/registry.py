"""The per-step feature registry: each feature declared once, with what it needs.

A `Feature` entry names a per-step feature, its kernel (a function of a
`FeatureContext`: the batch's trajectories, the search strategy, the shared
intermediates), the map parts its search reads on the device (`MapPart`:
the arrays, how each is padded, the bucket sizes they count), and, for a
feature registered beside the official ones, its metric (a
`metric_table.Metric` carrying its config, a row of the metric table that the
metrics read too). Everything that computes or lists per-step features reads
this module: `metric_features.per_step_features` (numpy and JAX alike), the
JAX drivers' map arrays, padding and bucket keys, and the scorer.

Adding a feature is one `register(Feature(...))` call (see docs/extending.md);
an official one is an entry in `OFFICIAL_FEATURES` (and its config field in
the official proto and presets).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
from collections.abc import Callable, Iterator, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from wosac_eval.features import interaction, kinematics, map_arrays, road_edge
from wosac_eval.features.float32_math import sincos32
from wosac_eval.features.search_strategy import TimeToCollisionInputs
from wosac_eval.features.spatial import NON_FINITE_PREFIX
from wosac_eval.features.xp import array_namespace
from wosac_eval.metric_table import Metric, register_metric, unregister_metric

if TYPE_CHECKING:  # the scene's arrays, read by the builders
    from wosac_eval.arrays.scenario import ScenarioArrays

# The map context and the layout are `metric_features`' `MapContext` and `FeatureLayout` (Any below):
# `metric_features` imports this module, and an import back would close a circle.

_F = np.float32


# --- Map parts: what the dense (device) searches read, and how it is padded -----------------------


@dataclasses.dataclass(frozen=True)
class Pad:
    """How one map array is padded to a bucket.

    Attributes:
      size: the `Size` it is padded to; None: never padded (a grid's origin, a fixed fallback row).
      axis: the padded axis.
      fill: the padding value (invalid everywhere it is read).
    """

    size: str | None
    axis: int = 0
    fill: int | float | bool = 0


@dataclasses.dataclass(frozen=True)
class Size:
    """One padded size of a bucket: the length of `axis` of the array `counted_by`.

    Attributes:
      fine: rounded to a multiple of a quarter of the next power of two (`fine_bucket`), for the
        large map counts that dominate the dense searches' work; else to the next power of two.
    """

    name: str
    counted_by: str
    axis: int = 0
    fine: bool = False

    def count(self, arrays: Mapping[str, np.ndarray]) -> int:
        return int(np.shape(arrays[self.counted_by])[self.axis])


@dataclasses.dataclass(frozen=True)
class MapPart:
    """Map arrays of one scene for the dense searches, built on the host.

    Attributes:
      name: what a `Feature.needs` names.
      build: (scenario, `metric_features.MapContext`, `metric_features.FeatureLayout`, num_steps,
        cells) -> the unpadded arrays by name (`cells`: False where the searches run on the host,
        which need no road-edge cell table).
      arrays: every array's `Pad`.
      sizes: the bucket sizes the part counts.
    """

    name: str
    build: Callable
    arrays: tuple[tuple[str, Pad], ...]
    sizes: tuple[Size, ...]

    @property
    def padding(self) -> dict[str, Pad]:
        return dict(self.arrays)


_SEGMENT_ARRAYS = (
    "start",
    "delta",
    "prior_start",
    "prior_delta",
    "next_start",
    "next_delta",
    "valid",
    "prior_valid",
    "next_valid",
    "convex_before",
    "convex_after",
)

MAP_PARTS: tuple[MapPart, ...] = (
    MapPart(
        name="road_edges",
        build=map_arrays.road_edge_segments,
        arrays=tuple((name, Pad(size="road_edge_segments")) for name in _SEGMENT_ARRAYS)
        + tuple((NON_FINITE_PREFIX + name, Pad(size=None)) for name in _SEGMENT_ARRAYS),
        sizes=(Size(name="road_edge_segments", counted_by="start", fine=True),),
    ),
    MapPart(
        name="red_lights",
        build=map_arrays.red_light_arrays,
        arrays=(
            ("stop_start", Pad(size="signals", axis=1)),
            ("stop_delta", Pad(size="signals", axis=1)),
            ("stop_point", Pad(size="signals", axis=1)),
            ("stopping", Pad(size="signals", axis=1)),
            # Padded signals' lane rank is neither a lane's nor a point's without lane (-1).
            ("signal_lane_id", Pad(size="signals", axis=0, fill=-2)),
            ("lane_start", Pad(size="lane_segments")),
            ("lane_delta", Pad(size="lane_segments")),
            ("lane_valid", Pad(size="lane_segments")),
            ("lane_id", Pad(size="lane_segments")),
        ),
        sizes=(
            Size(name="signals", counted_by="signal_lane_id"),
            Size(name="lane_segments", counted_by="lane_start", fine=True),
        ),
    ),
    # Rows past the grid are never looked up; its origin and shape are not padded.
    MapPart(
        name="road_edge_cells",
        build=map_arrays.road_edge_cells,
        arrays=(
            ("cell_origin", Pad(size=None)),
            ("cell_shape", Pad(size=None)),
            ("cell_candidates", Pad(size="road_edge_cells")),
            ("cell_clearance", Pad(size="road_edge_cells")),
            ("cell_near_clearance", Pad(size="road_edge_cells")),
        ),
        sizes=(Size(name="road_edge_cells", counted_by="cell_clearance", fine=True),),
    ),
)


# --- Features ------------------------------------------------------------------------------------


class FeatureContext:
    """What a kernel reads: the batch, the search strategy, and intermediates shared by kernels.

    Attributes:
      traj: x, y, z, heading, length, width, height float32 and valid bool, each
        `(num_samples, num_objects, num_steps)`, evaluated objects first.
      layout: the `metric_features.FeatureLayout`.
      search: the search strategy (`PrunedSearch`, `DenseSearch` or `HostSearch`).
      tails: `metric_features.official_tails` of the real shapes.
    Kernels return `(num_samples, num_evaluated, reported steps)`; `context[name]` is another
    feature's value, computed once.
    """

    def __init__(self, traj: dict, layout: Any, search: Any, tails: dict, features: tuple[Feature, ...]) -> None:
        self.traj, self.layout, self.search, self.tails = traj, layout, search, tails
        self.xp = array_namespace(traj["x"])
        self._features = {f.name: f for f in features}
        self._values: dict = {}

    def __getitem__(self, name: str) -> Any:
        if name not in self._values:
            self._values[name] = self._features[name].kernel(self)
        return self._values[name]

    def reported(self, a: Any) -> Any:
        """`a`'s reported steps (its last axis)."""
        return a[..., self.layout.reported]

    def evaluated(self, a: Any) -> Any:
        """`a`'s evaluated objects (axis 1 of `(num_samples, num_objects, ...)`)."""
        return a[:, : self.layout.num_evaluated]

    @functools.cached_property
    def kinematics(self) -> tuple:
        """(speed, acceleration, angular speed, angular acceleration) of the evaluated objects, all steps."""
        x, y, z, heading = (self.evaluated(self.traj[f]) for f in ("x", "y", "z", "heading"))
        return kinematics.kinematic_features(x, y, z, heading, self.layout.seconds_per_step)

    @functools.cached_property
    def heading_sincos(self) -> tuple:
        """(sin, cos) of every object's heading at the reported steps, as the official op rounds them."""
        return sincos32(self.reported(self.traj["heading"]), self.tails["heading_tail"])

    @functools.cached_property
    def box_centres(self) -> tuple:
        """(x, y) with NaN for boxes of non-finite height: the official corners come from a 3D rotation,
        where a NaN or inf height turns every corner NaN (0 * inf)."""
        t, xp = self.traj, self.xp
        finite_height = xp.isfinite(t["height"])
        return xp.where(finite_height, t["x"], _F(np.nan)), xp.where(finite_height, t["y"], _F(np.nan))


@dataclasses.dataclass(frozen=True)
class Feature:
    """One per-step feature.

    Attributes:
      name: its `MetricFeatures` field (an official one), or its key in `MetricFeatures.extra`.
      kernel: `FeatureContext` -> `(num_samples, num_evaluated, reported steps)`, numpy or JAX (written
        with `xp = context.xp`, it serves both).
      dtype: "float32" or "bool".
      needs: the `MAP_PARTS` its search reads on the device (their arrays are built, padded and
        counted in bucket keys only when a registered feature needs them).
      metric: a registered feature's metric (`metric_table.Metric` with `official=False` and its
        `config_default`), or None (an official feature: its metric is a row of `metric_table.METRICS`).
    """

    name: str
    kernel: Callable
    dtype: str = "float32"
    needs: tuple[str, ...] = ()
    metric: Metric | None = None


# Kernels are module functions, never lambdas or `functools.partial`s: entries travel to worker processes
# (pickled by name, they come back as the same function), and the JAX programs are found by the entries'
# equality, which a partial loses in the round trip (each batch a worker prepared was traced anew).
def _linear_speed(c: FeatureContext) -> Any:
    return c.reported(c.kinematics[0])


def _linear_acceleration(c: FeatureContext) -> Any:
    return c.reported(c.kinematics[1])


def _angular_speed(c: FeatureContext) -> Any:
    return c.reported(c.kinematics[2])


def _angular_acceleration(c: FeatureContext) -> Any:
    return c.reported(c.kinematics[3])


def _collision_per_step(c: FeatureContext) -> bool:
    return c["distance_to_nearest_object"] < _F(interaction.COLLISION_DISTANCE_THRESHOLD)


def _offroad_per_step(c: FeatureContext) -> bool:
    return c["distance_to_road_edge"] > _F(road_edge.OFFROAD_DISTANCE_THRESHOLD)


def _nearest_object(c: FeatureContext) -> Any:
    sin_h, cos_h = c.heading_sincos
    x, y = c.box_centres
    t = c.traj
    return c.search.nearest_object(
        c.reported(x),
        c.reported(y),
        c.reported(t["length"]),
        c.reported(t["width"]),
        cos_h,
        sin_h,
        c.reported(t["valid"]),
        c.layout.num_evaluated,
    )


def _time_to_collision(c: FeatureContext) -> Any:
    t = c.traj
    planar_speed = kinematics.linear_speed(t["x"], t["y"], c.xp.zeros_like(t["x"]), c.layout.seconds_per_step)
    return c.search.time_to_collision(
        TimeToCollisionInputs(
            x=t["x"],
            y=t["y"],
            length=t["length"],
            width=t["width"],
            heading=t["heading"],
            speed=planar_speed,
            valid=t["valid"],
            num_evaluated=c.layout.num_evaluated,
            steps=c.layout.reported,
            ego_tail=c.tails["ego_tail"],
            pair_tail=c.tails["pair_tail"],
        )
    )


def _road_edge_distance(c: FeatureContext) -> Any:
    t = c.traj
    pick = lambda a: c.reported(c.evaluated(a))  # noqa: E731
    sin_h, cos_h = (c.evaluated(a) for a in c.heading_sincos)
    x, y = c.box_centres
    bottom = pick(t["z"]) + (-pick(t["height"]) * _F(0.5))
    return c.search.road_edge_distance(
        pick(x), pick(y), bottom, pick(t["length"]), pick(t["width"]), cos_h, sin_h, pick(t["valid"])
    )


def _red_light_violation(c: FeatureContext) -> Any:
    t, n = c.traj, c.layout.num_evaluated
    # A crossing is found between a step and the one before: one step earlier where there is one.
    lights = slice(c.layout.first_red_light_step, None)
    red = c.search.red_light_violation(t["x"][:, :n, lights], t["y"][:, :n, lights], t["valid"][:, :n, lights])
    return red[..., 1:] if c.layout.first_step > 0 else red


OFFICIAL_FEATURES: tuple[Feature, ...] = (
    Feature(name="linear_speed", kernel=_linear_speed),
    Feature(name="linear_acceleration", kernel=_linear_acceleration),
    Feature(name="angular_speed", kernel=_angular_speed),
    Feature(name="angular_acceleration", kernel=_angular_acceleration),
    Feature(name="distance_to_nearest_object", kernel=_nearest_object),
    Feature(name="collision_per_step", kernel=_collision_per_step, dtype="bool"),
    Feature(name="time_to_collision", kernel=_time_to_collision),
    Feature(name="distance_to_road_edge", kernel=_road_edge_distance, needs=("road_edges", "road_edge_cells")),
    Feature(name="offroad_per_step", kernel=_offroad_per_step, dtype="bool", needs=("road_edges", "road_edge_cells")),
    Feature(name="traffic_light_violation_per_step", kernel=_red_light_violation, dtype="bool", needs=("red_lights",)),
)
OFFICIAL_FEATURE_NAMES = tuple(f.name for f in OFFICIAL_FEATURES)

_REGISTERED: list[Feature] = []


def register(feature: Feature) -> None:
    """Adds a per-step feature (and its metric, if it has one) after the official ones.

    Raises:
      ValueError: the name is taken, the kernel is a lambda or a `functools.partial`, a need is not a
        `MAP_PARTS` name, or the metric is refused
        (`metric_table.register_metric`).
    """
    if feature.name in {f.name for f in features()}:
        raise ValueError(f"feature {feature.name!r} is already registered")
    unknown = set(feature.needs) - {p.name for p in MAP_PARTS}
    if unknown:
        raise ValueError(f"feature {feature.name!r} needs unknown map parts {sorted(unknown)}")
    if isinstance(feature.kernel, functools.partial) or getattr(feature.kernel, "__name__", "") == "<lambda>":
        raise ValueError(
            f"feature {feature.name!r}: its kernel must be a module-level function, not a lambda or a "
            "functools.partial (worker processes receive entries pickled, and a partial unpickled no longer "
            "equals its entry: the JAX backend would trace its program again for every batch)"
        )
    if feature.dtype not in ("float32", "bool"):
        raise ValueError(f"feature {feature.name!r}: dtype must be 'float32' or 'bool', got {feature.dtype!r}")
    if feature.metric is not None:
        if feature.metric.feature != feature.name:
            raise ValueError(f"feature {feature.name!r}: its metric scores {feature.metric.feature!r}")
        register_metric(feature.metric)
    _REGISTERED.append(feature)


def unregister(name: str) -> None:
    """Removes a feature added by `register`, and its metric (KeyError if there is none of that name)."""
    index = next((k for k, f in enumerate(_REGISTERED) if f.name == name), None)
    if index is None:
        raise KeyError(name)
    feature = _REGISTERED.pop(index)
    if feature.metric is not None:
        unregister_metric(feature.metric.name)


@contextlib.contextmanager
def registered(feature: Feature) -> Iterator[Feature]:
    """`register(feature)` for the duration of a `with` block (tests, experiments)."""
    register(feature)
    try:
        yield feature
    finally:
        unregister(feature.name)


def features() -> tuple[Feature, ...]:
    """The official features, then the registered ones, in computation and output order."""
    return OFFICIAL_FEATURES + tuple(_REGISTERED)


def feature_names() -> tuple[str, ...]:
    return tuple(f.name for f in features())


def map_parts(selected: tuple[Feature, ...] | None = None) -> tuple[MapPart, ...]:
    """The map parts the features need, in `MAP_PARTS` order."""
    needed = {need for f in (features() if selected is None else selected) for need in f.needs}
    return tuple(p for p in MAP_PARTS if p.name in needed)


def size_names(selected: tuple[Feature, ...] | None = None) -> tuple[str, ...]:
    """The map sizes of a bucket key, in order (objects and evaluated objects come before them)."""
    return tuple(s.name for p in map_parts(selected) for s in p.sizes)


def map_sizes(selected: tuple[Feature, ...] | None = None) -> tuple[Size, ...]:
    return tuple(s for p in map_parts(selected) for s in p.sizes)


def map_padding(selected: tuple[Feature, ...] | None = None) -> dict[str, Pad]:
    """Every map array's `Pad`, by name."""
    return {name: pad for p in map_parts(selected) for name, pad in p.arrays}


def scene_map_arrays(
    scenario: ScenarioArrays,
    context: Any,
    layout: Any,
    num_steps: int,
    cells: bool = True,
    selected: tuple[Feature, ...] | None = None,
) -> dict:
    """Every array of the map parts the features need (`map_parts`), unpadded: the parts' builders
    (`features.map_arrays`) of one scene."""
    out: dict = {}
    for part in map_parts(features() if selected is None else selected):
        out.update(part.build(scenario, context, layout, num_steps, cells))
    return out
