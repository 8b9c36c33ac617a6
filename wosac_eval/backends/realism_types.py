"""What `jax_realism.realism` takes and gives: the prepared scenes (`PreparedScenes`, made once by
`realism_prepare.prepare`) and the metrics of a call (`Realism`), both pytrees that cross a `jax.jit`."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import jax
import numpy as np

from wosac_eval import challenges
from wosac_eval.backends.host_search import HostSearches
from wosac_eval.features import metric_features as mf


@jax.tree_util.register_pytree_node_class
@dataclasses.dataclass(frozen=True)
class Realism(Mapping):
    """What `realism` returns: field name -> `(num_scenes,)` array, and the precision it ran in.

    A read-only mapping (`out["metametric"]`, `dict(out)`) and a pytree (it leaves `jit`, `vmap`,
    `tree_map` with its mode), so a training step returns it or any of its values.

    Attributes:
      metrics: every `SimAgentMetrics` field (`metrics.scenario_metrics.SCENARIO_FIELDS`) -> array.
      mode: "exact" or "float32" (see the module).
      per_object: with `realism(..., per_object=True)`, every likelihood field -> float32
        `(num_scenes, max_agents)` in the rollouts' column order (`prepared.sim_agent_ids`): each
        evaluated object's likelihood (`scenario_metrics.per_object_likelihoods`), NaN in the other
        columns; else None.
      per_object_counts: the same fields -> int32 `(num_scenes, max_agents)`: each object's counted
        samples, 0 in the other columns (the scene's field is the count-weighted geometric mean of
        `per_object`); else None.
    """

    metrics: dict
    mode: str
    per_object: dict | None = None
    per_object_counts: dict | None = None

    def __getitem__(self, name: str) -> Any:
        return self.metrics[name]

    def __iter__(self) -> Any:
        return iter(self.metrics)

    def __len__(self) -> int:
        return len(self.metrics)

    def tree_flatten(self) -> Any:
        return (self.metrics, self.per_object, self.per_object_counts), (self.mode,)

    @classmethod
    def tree_unflatten(cls, aux: Any, children: Any) -> Any:
        metrics, per_object, counts = children
        (mode,) = aux
        return cls(metrics, mode, per_object=per_object, per_object_counts=counts)


@jax.tree_util.register_pytree_node_class
@dataclasses.dataclass(frozen=True)
class PreparedScenes:
    """Scenes ready for `realism`: a pytree whose leaves are device arrays.

    Scenes of similar sizes form a group (`groups`): the scenes of a group are padded to the group's
    largest and run as one `vmap`ped computation, so a small scene does not pay for the largest one.

    Attributes:
      arrays: per group, the device arrays (log, map, masks, column order) with a leading scene axis.
      groups: per group, (indices of its scenes in `scenario_ids`, its padded `FeatureLayout`).
      scenario_ids: the scenes' ids, in order.
      agent_ids: per scene, the sim agents' ids in the column order `realism` expects.
      challenge: "sim_agents" or "scenario_gen".
      config: the metrics config preset or textproto path.
      host_searches: the scenes' numpy searches where the searches run on the host (`prepare`'s
        `search`), else None.
    """

    arrays: tuple
    groups: tuple
    scenario_ids: tuple
    agent_ids: tuple
    challenge: str
    config: str
    host_searches: HostSearches | None = None

    @property
    def search(self) -> str:
        """Where the nearest-thing searches run: "host" (compiled, pruned) or "device" (fixed shapes)."""
        return "device" if self.host_searches is None else "host"

    def tree_flatten(self) -> Any:
        return (self.arrays,), (
            self.groups,
            self.scenario_ids,
            self.agent_ids,
            self.challenge,
            self.config,
            self.host_searches,
        )

    @classmethod
    def tree_unflatten(cls, aux: Any, children: Any) -> Any:
        return cls(children[0], *aux)

    @property
    def layout(self) -> mf.FeatureLayout:
        """The layout of the group with the most evaluated rows."""
        return max((layout for _, layout in self.groups), key=lambda g: g.num_evaluated)

    @property
    def num_scenes(self) -> int:
        return len(self.scenario_ids)

    @property
    def max_agents(self) -> int:
        return max((len(ids) for ids in self.agent_ids), default=0)

    @property
    def num_steps(self) -> int:
        return challenges.spec(self.challenge).num_simulation_steps

    @property
    def sim_agent_ids(self) -> np.ndarray:
        """int64 `(num_scenes, max_agents)`: the object of each column of the rollout arrays, -1 for padding."""
        out = np.full((self.num_scenes, self.max_agents), -1, dtype=np.int64)
        for row, ids in zip(out, self.agent_ids):
            row[: len(ids)] = ids
        return out

    @property
    def rollout_shape(self) -> tuple:
        """`(num_scenes, num_rollouts, max_agents, num_steps)` of the arrays `realism` takes."""
        return (self.num_scenes, challenges.spec(self.challenge).num_rollouts, self.max_agents, self.num_steps)
