"""The pruned search inside a JAX trace on the CPU: `PrunedSearch` called through `jax.pure_callback`.

On an accelerator the searches run on the device over fixed-size candidate
sets (`features.dense.DenseSearch`). On XLA's CPU the device is the host, and
fixed shapes still cost several times the work of the pruned search (4 boxes
and 64 road-edge segments per query, against 1-2 exact evaluations). There
`HostSearch` hands the four searches to the numpy strategy
(`features.search.PrunedSearch`: the same float32 kernels, compiled loops over
proven bounds) of the scene being traced, so a training step on the CPU costs
less than the numpy file path. Given the same inputs, the features are the
numpy path's bit for bit; in float32 mode the inputs (box headings' sines, speeds)
may differ from it in the last bit, as the rest of the trace may.

The callbacks are pure (no state, same inputs, same outputs): they work under
the caller's `jit`, `vmap` (one call per batch element) and `lax.scan`. They
have no derivative, as the features a nearest search picks have none.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from wosac_eval.features.search import PrunedSearch
from wosac_eval.features.search_strategy import TimeToCollisionInputs

_F = np.float32


class HostSearches:
    """The numpy searches of a scene set, by scene index. Compared by identity (static data of a jit)."""

    def __init__(self, searches: tuple[PrunedSearch, ...]) -> None:
        self.searches = tuple(searches)


def _host(searches: HostSearches, method: str, dtype: Any, arguments: Any) -> Callable[..., Any]:
    """The host side of a callback: the scene's `PrunedSearch.method` of `arguments(numpy arrays)`."""

    def call(scene: Any, *arrays: Any) -> np.ndarray:
        search = searches.searches[int(scene)]
        # NaN and inf in a submission are scored as given, as officially: they spread without warnings.
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            out = getattr(search, method)(*arguments([np.asarray(a) for a in arrays]))
        return np.asarray(out, dtype)

    return call


class HostSearch:
    """The search strategy of `metric_features.per_step_features` for one traced scene, on the host (a
    `SearchStrategy`).

    Args:
      searches: the scene set's numpy searches.
      scene: int32 scalar (traced): the index of this scene's search.
    """

    def __init__(self, searches: HostSearches, scene: Any) -> None:
        self.searches = searches
        self.scene = scene

    def _call(self, method: str, shape: tuple, dtype: Any, arrays: tuple, arguments: Any = tuple) -> Any:
        host = _host(self.searches, method, dtype, arguments)
        return jax.pure_callback(
            host, jax.ShapeDtypeStruct(shape, dtype), self.scene, *arrays, vmap_method="sequential"
        )

    def nearest_object(
        self, x: Any, y: Any, length: Any, width: Any, cos_h: Any, sin_h: Any, valid: Any, num_evaluated: int
    ) -> Any:
        """float32 `(num_samples, num_evaluated, num_steps)` (see `PrunedSearch.nearest_object`)."""
        shape = x.shape[:-2] + (num_evaluated,) + x.shape[-1:]
        return self._call(
            "nearest_object",
            shape,
            _F,
            (x, y, length, width, cos_h, sin_h, valid),
            lambda arrays: (*arrays, num_evaluated),
        )

    def time_to_collision(self, inputs: TimeToCollisionInputs) -> Any:
        """float32 `(samples, num_evaluated, len(steps))` (see `PrunedSearch.time_to_collision`)."""
        i = inputs
        shape = i.x.shape[:-2] + (i.num_evaluated, len(range(*i.steps.indices(i.x.shape[-1]))))
        # The evaluated count and the slice are static; the tails are arrays of the prepared scene.
        arrays = (i.x, i.y, i.length, i.width, i.heading, i.speed, i.valid, i.ego_tail, i.pair_tail)

        def on_host(host: Any) -> Any:
            x, y, length, width, heading, speed, valid, ego_tail, pair_tail = host
            return (
                TimeToCollisionInputs(
                    x=x,
                    y=y,
                    length=length,
                    width=width,
                    heading=heading,
                    speed=speed,
                    valid=valid,
                    num_evaluated=i.num_evaluated,
                    steps=i.steps,
                    ego_tail=ego_tail,
                    pair_tail=pair_tail,
                ),
            )

        return self._call("time_to_collision", shape, _F, arrays, on_host)

    def road_edge_distance(
        self, x: Any, y: Any, bottom: Any, length: Any, width: Any, cos_h: Any, sin_h: Any, valid: Any
    ) -> Any:
        """float32 `x.shape`, -1e10 where invalid (see `PrunedSearch.road_edge_distance`)."""
        return self._call("road_edge_distance", x.shape, _F, (x, y, bottom, length, width, cos_h, sin_h, valid))

    def red_light_violation(self, x: Any, y: Any, valid: Any) -> Any:
        """bool `x.shape` (see `PrunedSearch.red_light_violation`)."""
        return self._call("red_light_violation", x.shape, np.bool_, (x, y, valid))
