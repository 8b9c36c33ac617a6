"""The host side of `jax_realism`: `prepare(scenarios)`, once per scene set.

The log in the official object order, the map (road-edge segments, stop lines, lane segments) and the
trailing-packet masks of the official float32 ops of each scene (`RealismScene`), padded to common sizes
per group of similar scenes and stacked into the device arrays of a `PreparedScenes`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from wosac_eval import challenges
from wosac_eval.arrays.samples import log_sample, official_object_order
from wosac_eval.arrays.scenario import ScenarioArrays, scenario_arrays
from wosac_eval.arrays.trajectories import index_of_ids
from wosac_eval.backends.host_search import HostSearches
from wosac_eval.backends.jax_driver import SceneInputs, Sizes, padded_inputs, scene_inputs, stacked
from wosac_eval.backends.realism_types import PreparedScenes
from wosac_eval.features import metric_features as mf
from wosac_eval.features.search import PrunedSearch
from wosac_eval.metrics.config import load_config
from wosac_eval.options import Search
from wosac_eval.protos import scenario_pb2


@dataclasses.dataclass(frozen=True)
class RealismScene:
    """One scene's host inputs for `realism`, unpadded.

    Attributes:
      inputs: the log as one sample, tails and map arrays (`jax_driver.SceneInputs`).
      search: the scene's numpy search (`prepare`'s "host" search calls it back).
      feature_valid: bool `(num_evaluated, num_steps)`, the log's feature validity.
      object_type: int32 `(num_objects,)`, in the official order.
      columns: int `(num_objects,)`, each object's column among the sim agents.
    """

    inputs: SceneInputs
    search: PrunedSearch
    feature_valid: np.ndarray
    object_type: np.ndarray
    columns: np.ndarray


def _scene_inputs(scenario: ScenarioArrays, spec: challenges.ChallengeSpec, search: str) -> RealismScene:
    """The unpadded host arrays of one scene (see `prepare`)."""
    evaluated = scenario.evaluated_ids(spec)
    order = official_object_order(scenario.sim_agent_ids, evaluated)
    log, feature_valid = log_sample(scenario, spec)
    layout = mf.feature_layout(spec, len(evaluated))
    context = mf.map_context(scenario)
    pruned = PrunedSearch(
        context.road_edges, context.lanes, mf.signals_from(scenario.signals, layout.first_red_light_step)
    )
    # The host search needs no cell tables (0.1-0.5 s per real scene to build).
    inputs = scene_inputs(
        scenario, {f: getattr(log, f) for f in mf.TRAJECTORY_FIELDS}, layout, context, cells=search == "device"
    )
    return RealismScene(
        inputs=inputs,
        search=pruned,
        feature_valid=feature_valid[0],
        object_type=np.asarray(log.object_type[0], np.int32),
        columns=index_of_ids(scenario.sim_agent_ids, order),
    )


def prepare(
    scenarios: Iterable[scenario_pb2.Scenario | ScenarioArrays],
    challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS,
    config: str | None = None,
    min_sizes: tuple | None = None,
    grouped: bool = True,
    search: str = "auto",
) -> PreparedScenes:
    """Scenes (Scenario messages or `ScenarioArrays`) as a device-resident `PreparedScenes`, once.

    Args:
      challenge: "sim_agents" (80 future steps; SDC and tracks_to_predict evaluated) or "scenario_gen".
      config: the metrics config (default: the challenge's leaderboard config, "2025" or
        "scenario_gen_2025").
      min_sizes: optional lower bounds of the padded sizes (objects, evaluated objects, road-edge
        segments, signals, lane segments, road-edge grid cells; a shorter tuple bounds the first
        ones): to share compiled functions between scene sets.
      grouped: scenes of similar sizes are padded together, a program per group (the least padded
        work per call); False pads every scene to the largest: one program, which compiles several
        times faster and does more work per call (7 scenes of 6 to 9 evaluated objects on this
        2-core CPU: 6 groups compile in 72 s and run a call in 2.5 s, one group in 14 s and 5.1 s).
      search: where `realism` runs the nearest-thing searches (nearest object, followed object,
        nearest road edge, lane of a red-light crossing). "host": the numpy file path's compiled,
        pruned search, called back from the trace (`host_search.HostSearch`), the fast choice when
        JAX runs on the CPU; "device": fixed-size candidate sets on the device (`dense.DenseSearch`),
        the choice for an accelerator; "auto" (default): "host" when JAX's default backend is the
        CPU, else "device". The features are the same either way (bit-identical in exact mode).
    """
    search = Search.parse(search).value
    spec = challenges.spec(challenge)
    config = config or spec.default_config
    load_config(config)  # refused now if unknown
    scenes = [s if isinstance(s, ScenarioArrays) else scenario_arrays(s) for s in scenarios]
    if not scenes:
        raise ValueError("prepare needs at least one scenario")
    if search == "auto":
        search = "host" if jax.default_backend() == "cpu" else "device"
    inputs = [_scene_inputs(s, spec, search) for s in scenes]
    max_agents = max(len(s.sim_agent_ids) for s in scenes)
    floor = tuple(min_sizes or ())
    members: dict[Sizes | None, list[int]] = {}
    for k, scene in enumerate(inputs):
        members.setdefault(_group_key(scene.inputs.sizes, floor) if grouped else None, []).append(k)
    groups, arrays = [], []
    for indices in members.values():
        group_arrays, layout = _prepare_group(indices, [inputs[k] for k in indices], spec, floor, max_agents)
        groups.append((tuple(indices), layout))
        arrays.append(group_arrays)
    host = HostSearches(tuple(scene.search for scene in inputs)) if search == "host" else None
    return PreparedScenes(
        arrays=tuple(arrays),
        groups=tuple(groups),
        scenario_ids=tuple(s.scenario_id for s in scenes),
        agent_ids=tuple(tuple(int(i) for i in s.sim_agent_ids) for s in scenes),
        challenge=spec.challenge.value,
        config=str(config),
        host_searches=host,
    )


def _group_key(sizes: Sizes, floor: tuple) -> Sizes:
    """Scenes whose sizes round to the same powers of two (finer for map segments) share a group."""
    return sizes.at_least(floor).rounded(minimum_objects=1, minimum_fine=1)


def _prepare_group(
    indices: list[int], scenes: list[RealismScene], spec: challenges.ChallengeSpec, floor: tuple, max_agents: int
) -> Any:
    """The stacked device arrays of a group's scenes, padded to the group's largest, and its layout."""
    # Exact maxima (at least 1): a training loop compiles once per scene set, and every padded row costs.
    exact = [scene.inputs.sizes for scene in scenes]
    sizes = exact[0].with_counts(max(max(column), 1) for column in zip(*(s.as_tuple() for s in exact)))
    sizes = sizes.at_least(floor)
    sizes = dataclasses.replace(sizes, evaluated=min(sizes.evaluated, sizes.objects))  # the first object rows
    n_obj, n_eval = sizes.objects, sizes.evaluated
    layout = mf.feature_layout(spec, n_eval)
    per_scene = []
    for index, scene in zip(indices, scenes):
        traj, tails, maps = padded_inputs(scene.inputs, sizes)
        n, e = scene.inputs.num_objects, scene.inputs.layout.num_evaluated
        columns = np.full(n_obj, max_agents, dtype=np.int32)  # padding reads the appended zero column
        columns[:n] = scene.columns
        feature_valid = np.zeros((n_eval, challenges.NUM_LOGGED_STEPS), bool)
        feature_valid[:e] = scene.feature_valid
        object_type = np.zeros(n_eval, np.int32)
        object_type[: min(n, n_eval)] = scene.object_type[:n_eval]
        per_scene.append(
            {
                "log": {f: a[0] for f, a in traj.items()},
                "tails": tails,
                "maps": maps,
                "columns": columns,
                "real": np.arange(n_obj) < n,
                "evaluated": np.arange(n_eval) < e,
                "feature_valid": feature_valid,
                "object_type": object_type,
                "scene": np.int32(index),  # the index of its host search
                # 0, read at run time: the exact mode's rounding barriers (`exact_rounding`)
                "opaque_zero": np.int32(0),
            }
        )
    # 32-bit leaves only (lane ids are ranks): the same arrays serve x64 on and off.
    arrays = jax.tree_util.tree_map(jnp.asarray, stacked(per_scene))
    return arrays, layout
