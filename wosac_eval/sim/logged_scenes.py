"""A scene recipe simulated into its logged world, in the local frame of its network.

Closed-loop traffic (`engine`) with every unscripted collision removed, occlusions (invalid
steps, late appearances, early exits) and the evaluated objects (the SDC and up to 8
`tracks_to_predict`): `build_scene(seed, index)` -> `LoggedScene`.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from numpy.typing import DTypeLike

from wosac_eval.arrays.object_types import TYPE_CYCLIST, TYPE_PEDESTRIAN, TYPE_VEHICLE
from wosac_eval.challenges import CURRENT_TIME_INDEX
from wosac_eval.sim import engine
from wosac_eval.sim import geometry as geo
from wosac_eval.sim.scene_recipes import RECIPES, SCENE_KINDS
from wosac_eval.sim.scene_specs import (
    DT,
    NUM_STEPS,
    PATH_SPACING_M,
    AgentSpec,
    SceneSpec,
)


@dataclass
class LoggedScene:
    """A simulated scene in the local frame.

    x, y, heading, speed, valid: `(num_objects, 91)`.
    """

    spec: SceneSpec
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    valid: np.ndarray
    sdc: int
    tracks_to_predict: list[int]


def simulate_agents(
    agents: list[AgentSpec], signal_states: dict[str, np.ndarray], blind_pairs: Iterable[tuple[int, int]] = ()
) -> engine.Rollout:
    """Runs the logged world: one batch entry, every agent of the scene."""
    n = len(agents)
    lengths = [geo.arc_lengths(a.path)[-1] for a in agents]
    min_length = max(max(lengths), max(a.s_init for a in agents) + 20.0 * NUM_STEPS * DT + 60.0)
    paths = engine.Paths.from_polylines([[a.path for a in agents]], PATH_SPACING_M, min_length)

    def col(attr: str, dtype: DTypeLike = float) -> np.ndarray:
        return np.array([[getattr(a, attr) for a in agents]], dtype=dtype)

    blind = np.zeros((1, n, n), bool)
    for i, j in blind_pairs:
        blind[0, i, j] = True
    crash = blind | np.swapaxes(blind, 1, 2)
    drivers = engine.Drivers(
        length=col("length"),
        width=col("width"),
        v0=np.stack([a.v0 for a in agents])[None],
        a_max=col("a_max"),
        b_comf=col("b_comf"),
        headway=col("headway"),
        s0=col("s0"),
        margin=col("margin"),
        max_brake=col("max_brake"),
        moving=col("moving", bool),
        ignore_signals=col("ignore_signals", bool),
        blind=blind,
        crash_pairs=crash,
    )
    states = np.stack(list(signal_states.values()), axis=1) if signal_states else np.zeros((NUM_STEPS, 0), np.int64)
    stop_lines = engine.StopLines.of([[a.stops for a in agents]], states)
    return engine.simulate(paths, drivers, col("s_init"), col("v_init"), stop_lines, NUM_STEPS, DT)


def colliding_pairs(
    x: np.ndarray,
    y: np.ndarray,
    heading: np.ndarray,
    length: np.ndarray,
    width: np.ndarray,
    valid: np.ndarray | None = None,
) -> list[tuple[int, int]]:
    """Pairs (i < j) of objects whose boxes overlap at some step where both are valid.

    x, y, heading, valid: `(num_objects, num_steps)`; length, width: `(num_objects,)`.
    """
    n, t = x.shape
    corners = geo.box_corners(x, y, heading, length[:, None], width[:, None])  # (n, t, 4, 2)
    if valid is None:
        valid = np.ones((n, t), bool)
    pairs = []
    centre = np.stack([x, y], -1)
    radius = 0.5 * np.hypot(length, width)
    for i in range(n - 1):
        near = np.linalg.norm(centre[i + 1 :] - centre[i], axis=-1) < (radius[i] + radius[i + 1 :])[:, None]
        near &= valid[i] & valid[i + 1 :]
        for jj in np.nonzero(near.any(axis=1))[0]:
            j = i + 1 + jj
            steps = np.nonzero(near[jj])[0]
            if geo.boxes_overlap(corners[i, steps], corners[j, steps]).any():
                pairs.append((i, int(j)))
    return pairs


def _simulate_without_collisions(spec: SceneSpec) -> engine.Rollout:
    """Simulates; drops unscripted agents involved in a collision until none remains."""
    for _ in range(30):
        index = {id(a): i for i, a in enumerate(spec.agents)}
        blind = [(index[id(follower)], index[id(leader)]) for follower, leader in spec.blind_pairs]
        out = simulate_agents(spec.agents, spec.signal_states, blind)
        length = np.array([a.length for a in spec.agents])
        width = np.array([a.width for a in spec.agents])
        scripted = {tuple(sorted(p)) for p in blind}
        bad = [p for p in colliding_pairs(out.x[0], out.y[0], out.heading[0], length, width) if p not in scripted]
        if not bad:
            return out
        drop = set()
        for i, j in bad:
            if i in drop or j in drop:
                continue
            candidates = [k for k in (j, i) if not spec.agents[k].tags]
            if not candidates:
                raise RuntimeError(f"scene {spec.scenario_id}: scripted agents {i} and {j} collide")
            drop.add(candidates[0])
        spec.agents = [a for k, a in enumerate(spec.agents) if k not in drop]
    raise RuntimeError(f"scene {spec.scenario_id}: could not remove collisions")


def _occlusions(rng: np.random.Generator, n: int, protected: set[int], level: float) -> np.ndarray:
    """(n, NUM_STEPS) validity: random gaps, late appearances and early exits.

    Protected objects (the evaluated ones) stay valid at the current step.
    """
    valid = np.ones((n, NUM_STEPS), bool)
    for i in range(n):
        u = rng.random()
        if u < level:  # a gap (e.g. hidden behind a truck)
            start = int(rng.integers(0, NUM_STEPS - 5))
            valid[i, start : start + int(rng.integers(3, 25))] = False
        elif u < 1.5 * level:  # enters the sensor range late
            valid[i, : int(rng.integers(3, 60))] = False
        elif u < 2.0 * level:  # leaves early
            valid[i, int(rng.integers(5, 80)) :] = False
        if i in protected:
            if not valid[i, CURRENT_TIME_INDEX]:
                valid[i] = True
            # Evaluated objects keep a valid history around the current step, as in WOMD.
            valid[i, CURRENT_TIME_INDEX - 2 : CURRENT_TIME_INDEX + 1] = True
    return valid


def _choose_evaluated(spec: SceneSpec, out: engine.Rollout, rng: np.random.Generator) -> tuple[int, list[int]]:
    """SDC (a moving vehicle near the centre) and up to 8 `tracks_to_predict`."""
    x, y, v = out.x[0], out.y[0], out.speed[0]
    c = CURRENT_TIME_INDEX
    moving = v[:, c:].max(axis=1) > 1.0
    types = np.array([a.object_type for a in spec.agents])
    dist = np.hypot(x[:, c], y[:, c])
    untagged = np.array([not a.tags for a in spec.agents])
    for pool in ((types == TYPE_VEHICLE) & moving & untagged, (types == TYPE_VEHICLE) & untagged, untagged):
        vehicles = np.nonzero(pool)[0]
        if len(vehicles):
            break
    sdc = int(vehicles[np.argmin(dist[vehicles] + rng.uniform(0, 15, len(vehicles)))])
    tagged = [i for i, a in enumerate(spec.agents) if a.tags and i != sdc]
    d_sdc = np.hypot(x[:, c] - x[sdc, c], y[:, c] - y[sdc, c])
    order = np.argsort(d_sdc + rng.uniform(0, 10, len(d_sdc)) - 20.0 * moving)
    chosen = list(tagged)
    # WOMD's tracks_to_predict are mostly vehicles: at most one pedestrian and one cyclist here.
    for wanted in (TYPE_PEDESTRIAN, TYPE_CYCLIST):
        of_type = [int(i) for i in order if types[i] == wanted and moving[i] and d_sdc[i] < 60]
        if of_type and len(chosen) < 8 and not any(types[c] == wanted for c in chosen):
            chosen.append(of_type[0])
    target = int(rng.integers(4, 9))
    for i in order:
        if len(chosen) >= target:
            break
        if i != sdc and int(i) not in chosen and d_sdc[i] < 60 and types[i] == TYPE_VEHICLE and spec.agents[i].moving:
            chosen.append(int(i))
    return sdc, chosen


def build_scene(seed: int, index: int, kind: str | None = None) -> LoggedScene:
    """Builds and simulates scene `index` of the set drawn from `seed`."""
    rng = np.random.default_rng([seed, index])
    kind = kind or SCENE_KINDS[index % len(SCENE_KINDS)]
    builder = RECIPES[kind](rng)
    scenario_id = f"synthetic-{seed}-{index:03d}-{kind.replace('_', '-')}"
    if kind == "large_coordinates":
        rotation, translation = rng.uniform(-np.pi, np.pi), np.array([8000.0, -6000.0]) + rng.uniform(-300, 300, 2)
    elif kind == "heading_wrap":
        rotation, translation = 0.0, rng.uniform(-300, 300, 2)
    else:
        rotation, translation = rng.uniform(-np.pi, np.pi), rng.uniform(-2000, 2000, 2)
    spec = SceneSpec(
        scenario_id=scenario_id,
        kind=kind,
        network=builder.network,
        signal_states=builder.signal_states,
        agents=builder.agents,
        rotation=float(rotation),
        translation=translation,
        ground_z=float(rng.uniform(-150.0, 150.0)),
        slope=rng.uniform(-0.01, 0.01, 2),
        occlusion_level=0.3 if kind == "occlusion" else 0.06,
    )
    if kind == "collision":
        pair = [a for a in spec.agents if "collision" in a.tags]
        follower, leader = sorted(pair, key=lambda a: a.s_init)
        spec.blind_pairs = [(follower, leader)]
    out = _simulate_without_collisions(spec)
    sdc, ttp = _choose_evaluated(spec, out, rng)
    valid = _occlusions(rng, len(spec.agents), {sdc, *ttp}, spec.occlusion_level)
    return LoggedScene(spec, out.x[0], out.y[0], out.heading[0], out.speed[0], valid, sdc, ttp)
