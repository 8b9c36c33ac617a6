"""Deterministic synthetic WOMD-like scenarios (`Scenario` protos) for demos and tests.

`generate_scenes(n, seed)` returns `n` scenarios; the same `(n, seed)` always
gives byte-identical serialised protos. Scene `i` draws all its randomness from
`numpy.random.default_rng([seed, i])` and cycles through the recipes in
`SCENE_KINDS`, each of which exercises something the metrics must handle:

* ``intersection``: signalised four-way intersection, mixed traffic;
* ``red_light``: a logged vehicle runs a red light;
* ``dense_following``: stop-and-go queues on a multi-lane arterial;
* ``offroad``: a logged vehicle leaves the road and stops beyond the curb;
* ``occlusion``: tracks with invalid steps, late appearances, early exits;
* ``collision``: a logged rear-end collision (the only scene with one);
* ``large_coordinates``: an intersection placed near x = 8000 m, y = -6000 m;
* ``heading_wrap``: a westbound flow whose headings cross +-pi;
* ``pedestrians``: crowds on sidewalks and crosswalks;
* ``cyclists``: an arterial with bike lanes and parked cars.

Traffic is simulated closed-loop (see `engine.py`) so that the logged motion is
physically plausible and collision-free unless the recipe scripts a collision.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from wosac_eval.challenges import CURRENT_TIME_INDEX, NUM_LOGGED_STEPS, STEP_SECONDS
from wosac_eval.sim import engine
from wosac_eval.sim import geometry as geo
from wosac_eval.sim import roads, signals

# Bump when the generated scenes change, so that cached demo scenes are regenerated.
GENERATOR_VERSION = 5

NUM_STEPS = NUM_LOGGED_STEPS  # 91
DT = STEP_SECONDS
TIMES = np.arange(NUM_STEPS) * DT

TYPE_VEHICLE, TYPE_PEDESTRIAN, TYPE_CYCLIST = 1, 2, 3

SCENE_KINDS = (
    "intersection",
    "red_light",
    "dense_following",
    "offroad",
    "occlusion",
    "collision",
    "large_coordinates",
    "heading_wrap",
    "pedestrians",
    "cyclists",
)

PATH_SPACING_M = 0.5


@dataclass
class AgentSpec:
    """One logged object before simulation. `path` is in the local frame of the network."""

    object_type: int
    length: float
    width: float
    height: float
    path: np.ndarray
    s_init: float
    v_init: float
    v0: np.ndarray  # (NUM_STEPS,) desired speed
    a_max: float = 1.5
    b_comf: float = 2.5
    headway: float = 1.3
    s0: float = 2.0
    margin: float = 0.3
    max_brake: float = engine.MAX_BRAKE
    moving: bool = True
    ignore_signals: bool = False
    stops: list[tuple[float, int]] = field(default_factory=list)  # (arc length, signal column)
    tags: set[str] = field(default_factory=set)


@dataclass
class SceneSpec:
    """Everything a scene recipe decides; `assemble` turns it into a Scenario proto."""

    scenario_id: str
    kind: str
    network: roads.RoadNetwork
    signal_states: dict[str, np.ndarray]  # group -> (NUM_STEPS,) states
    agents: list[AgentSpec]
    rotation: float
    translation: np.ndarray
    ground_z: float
    slope: np.ndarray
    blind_pairs: list[tuple[AgentSpec, AgentSpec]] = field(default_factory=list)  # (follower, leader)
    occlusion_level: float = 0.1


# --------------------------------------------------------------------------------------
# Object sizes (metres), loosely matching WOMD's distributions.


def _vehicle_size(rng: np.random.Generator) -> tuple[float, float, float]:
    if rng.random() < 0.08:  # box truck or bus
        return rng.uniform(7.5, 12.0), rng.uniform(2.4, 2.6), rng.uniform(2.8, 3.4)
    return rng.uniform(4.2, 5.3), rng.uniform(1.8, 2.1), rng.uniform(1.45, 1.9)


def _pedestrian_size(rng: np.random.Generator) -> tuple[float, float, float]:
    return rng.uniform(0.5, 0.95), rng.uniform(0.5, 0.95), rng.uniform(1.5, 1.95)


def _cyclist_size(rng: np.random.Generator) -> tuple[float, float, float]:
    return rng.uniform(1.6, 1.95), rng.uniform(0.55, 0.85), rng.uniform(1.6, 1.9)


# --------------------------------------------------------------------------------------
# Paths.


def _chain(network: roads.RoadNetwork, lane_ids: list[int]) -> tuple[np.ndarray, list[tuple[float, str]]]:
    """Concatenated centre line of consecutive lanes, and the (arc length, group) of its signals."""
    pieces, stops, s0 = [], [], 0.0
    for lid in lane_ids:
        poly = network.lanes[lid].polyline
        if pieces:
            poly = poly[1:]
            start = pieces[-1][-1]
        else:
            start = poly[0]
        lane = network.lanes[lid]
        if lane.signal_group is not None:
            stops.append((s0, lane.signal_group))
        pieces.append(poly)
        s0 += float(geo.arc_lengths(np.concatenate([[start], poly]))[-1])
    return np.concatenate(pieces), stops


def _route_from(network: roads.RoadNetwork, lane_id: int, rng: np.random.Generator, weights: dict[str, float]) -> list[int]:
    """Follows exits from `lane_id` to the end of the network, picking turns by `weights`."""
    route = [lane_id]
    while network.lanes[route[-1]].exit_lanes:
        exits = network.lanes[route[-1]].exit_lanes
        p = np.array([weights.get(network.lanes[e].turn, 1.0) for e in exits], float)
        route.append(int(exits[rng.choice(len(exits), p=p / p.sum())]))
    return route


def _offset_path(path: np.ndarray, offset: np.ndarray | float) -> np.ndarray:
    """Shifts `path` by `offset` metres to its left (negative: right), per vertex or constant."""
    return path + np.asarray(offset, float).reshape(-1, 1) * geo.left_normals(path)


def _weave(path: np.ndarray, rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """Lane-keeping wander: a slow lateral sine along the path (zero when stopped, so no sliding)."""
    dense = geo.resample(path, PATH_SPACING_M)
    s = geo.arc_lengths(dense)
    wavelength = rng.uniform(60.0, 140.0)
    offset = amplitude * np.sin(2 * np.pi * s / wavelength + rng.uniform(0, 2 * np.pi)) + rng.uniform(-0.15, 0.15)
    return _offset_path(dense, offset)


def _stops_for(stops: list[tuple[float, str]], columns: dict[str, int]) -> list[tuple[float, int]]:
    return [(s, columns[g]) for s, g in stops if g in columns]


# --------------------------------------------------------------------------------------
# Populating a network.


@dataclass
class _Builder:
    rng: np.random.Generator
    network: roads.RoadNetwork
    signal_states: dict[str, np.ndarray]
    agents: list[AgentSpec] = field(default_factory=list)

    @property
    def columns(self) -> dict[str, int]:
        return {g: i for i, g in enumerate(self.signal_states)}

    def vehicle(self, path, s_init, v_init, v_des, stops=(), *, cyclist=False, **kw) -> AgentSpec:
        rng = self.rng
        length, width, height = _cyclist_size(rng) if cyclist else _vehicle_size(rng)
        v0 = np.full(NUM_STEPS, v_des)
        spec = AgentSpec(
            object_type=TYPE_CYCLIST if cyclist else TYPE_VEHICLE,
            length=length,
            width=width,
            height=height,
            path=path,
            s_init=s_init,
            v_init=v_init,
            v0=v0,
            a_max=rng.uniform(1.0, 2.0),
            b_comf=rng.uniform(2.0, 3.0),
            headway=rng.uniform(1.0, 1.8) if not cyclist else 1.0,
            s0=rng.uniform(1.5, 2.5),
            stops=_stops_for(list(stops), self.columns),
        )
        for key, value in kw.items():
            setattr(spec, key, value)
        self.agents.append(spec)
        return spec

    def lane_queue(self, lane_ids: list[int], count: int, *, v_des: float, stopped_front: bool, weave=0.12, cyclist=False, lateral=0.0, min_s=0.0):
        """Spawns `count` vehicles in one lane chain, front to back, spaced like IDM traffic."""
        path, stops = _chain(self.network, lane_ids)
        path = _weave(_offset_path(geo.resample(path, PATH_SPACING_M), lateral), self.rng, weave)
        first_stop = stops[0][0] if stops else geo.arc_lengths(path)[-1] - 10.0
        s_front = first_stop - self.rng.uniform(1.5, 6.0 if stopped_front else 30.0)
        spawned = []
        for i in range(count):
            spec = self.vehicle(path, 0.0, 0.0, v_des * self.rng.uniform(0.85, 1.1), stops, cyclist=cyclist)
            if i == 0:
                spec.s_init = s_front - spec.length / 2
                room = first_stop - s_front  # nose to the first stop line
                # Fast enough to look natural, slow enough to stop comfortably if the light is red.
                spec.v_init = 0.0 if stopped_front else float(min(spec.v0[0], 0.8 * np.sqrt(2 * spec.b_comf * max(room + 8.0, 0.0))))
            else:
                prev = spawned[-1]
                if stopped_front and prev.v_init == 0.0 and self.rng.random() < 0.7:
                    v, gap = 0.0, spec.s0 + self.rng.uniform(0.3, 2.0)
                else:
                    v = float(min(spec.v0[0], prev.v_init + self.rng.uniform(0.0, 3.0)))
                    gap = spec.s0 + v * spec.headway * self.rng.uniform(1.0, 1.4) + self.rng.uniform(0.0, 12.0)
                spec.s_init = prev.s_init - prev.length / 2 - spec.length / 2 - gap
                spec.v_init = v
            if spec.s_init < min_s:
                self.agents.remove(spec)
                break
            spawned.append(spec)
        return spawned

    def pedestrian(self, path, s_init, v_des, stops=(), **kw) -> AgentSpec:
        length, width, height = _pedestrian_size(self.rng)
        spec = AgentSpec(
            object_type=TYPE_PEDESTRIAN,
            length=length,
            width=width,
            height=height,
            path=path,
            s_init=s_init,
            v_init=v_des * self.rng.uniform(0.6, 1.0),
            v0=np.full(NUM_STEPS, v_des),
            a_max=1.0,
            b_comf=1.5,
            headway=0.8,
            s0=0.6,
            margin=0.05,
            max_brake=3.0,
            stops=list(stops),
        )
        for key, value in kw.items():
            setattr(spec, key, value)
        self.agents.append(spec)
        return spec

    def sidewalk_walkers(self, count: int):
        for _ in range(count):
            walk = self.network.sidewalks[self.rng.integers(len(self.network.sidewalks))]
            if self.rng.random() < 0.5:
                walk = walk[::-1]
            path = _offset_path(walk, -self.rng.uniform(0.3, 1.2))  # keep right
            total = geo.arc_lengths(path)[-1]
            v_des = self.rng.uniform(1.0, 1.6)
            if self.rng.random() < 0.2:  # someone standing and chatting
                spec = self.pedestrian(path, self.rng.uniform(0, total - 5), 0.0, moving=False)
                spec.v_init = 0.0
            else:
                self.pedestrian(path, self.rng.uniform(0, max(total - 20.0, 1.0)), v_des)

    def crossing_walkers(self, count: int):
        columns = self.columns
        for _ in range(count):
            crossing = self.network.crossings[self.rng.integers(len(self.network.crossings))]
            path = _offset_path(crossing.path, -self.rng.uniform(0.3, 1.6))  # keep right on the crosswalk
            stops = [(crossing.wait_s, columns[crossing.signal_group])] if crossing.signal_group in columns else []
            self.pedestrian(path, self.rng.uniform(0.0, crossing.wait_s - 0.5), self.rng.uniform(1.1, 1.6), stops)

    def parked(self, path: np.ndarray, count: int):
        total = geo.arc_lengths(path)[-1]
        slots = np.sort(self.rng.choice(np.arange(8.0, total - 8.0, 7.5), size=count, replace=False))
        for s in slots:
            spec = self.vehicle(path, float(s), 0.0, 0.0, moving=False)
            spec.length = min(spec.length, 5.2)
            spec.width = min(spec.width, 2.0)


# --------------------------------------------------------------------------------------
# Recipes.


def _intersection_traffic(b: _Builder, density: float, stopped_bias: float = 0.4, skip: frozenset = frozenset()):
    net = b.network
    weights = {"through": 0.6, "left": 0.2, "right": 0.2}
    approaches = [ln for ln in net.lanes_of_turn("approach") if ln.id not in skip]
    busy = b.rng.choice(len(approaches), size=max(3, int(round(density * len(approaches)))), replace=False)
    for lane in [approaches[i] for i in sorted(busy)]:
        route = _route_from(net, lane.id, b.rng, weights)
        group = net.lanes[route[1]].signal_group
        red_now = signals.is_stop(b.signal_states[group][0]) or signals.is_caution(b.signal_states[group][0])
        b.lane_queue(route, int(b.rng.integers(2, 6)), v_des=b.rng.uniform(9.0, 14.0), stopped_front=bool(red_now and b.rng.random() < 0.5 + stopped_bias))
    for lane in net.lanes_of_turn("departure"):
        if b.rng.random() > density * 0.6 or lane.id in skip:
            continue
        b.lane_queue([lane.id], int(b.rng.integers(1, 3)), v_des=b.rng.uniform(10.0, 14.0), stopped_front=False, min_s=20.0)


def _corridor_traffic(b: _Builder, per_lane: tuple[int, int], v_range: tuple[float, float], stopped_front_p: float = 0.3, skip: frozenset = frozenset()):
    net = b.network
    for lane in [ln for ln in net.lanes_of_turn("approach") if ln.id not in skip]:
        route = _route_from(net, lane.id, b.rng, {})
        red = signals.is_stop(b.signal_states["PED"][0])
        b.lane_queue(route, int(b.rng.integers(*per_lane)), v_des=b.rng.uniform(*v_range), stopped_front=bool(red and b.rng.random() < 0.5 + stopped_front_p))
    for lane in net.lanes_of_turn("departure"):
        if b.rng.random() < 0.6 and lane.id not in skip:
            b.lane_queue([lane.id], int(b.rng.integers(1, 3)), v_des=b.rng.uniform(*v_range), stopped_front=False, min_s=25.0)


def _signal_states(network: roads.RoadNetwork, rng: np.random.Generator, require=None) -> dict[str, np.ndarray]:
    """Draws signal programs until `require(states)` holds (so recipes get the phase they need)."""
    program = signals.intersection_program if network.kind == "intersection" else signals.midblock_program
    for _ in range(200):
        states = program(TIMES, rng)
        if require is None or require(states):
            return states
    raise RuntimeError("no signal program satisfies the recipe")


def _new_scene(kind: str, rng: np.random.Generator, network: roads.RoadNetwork, require=None) -> _Builder:
    return _Builder(rng, network, _signal_states(network, rng, require))


def _recipe_intersection(rng, *, density=0.55, lanes=None, peds=(3, 8)) -> _Builder:
    net = roads.four_way_intersection(
        lanes_per_direction=int(lanes or rng.integers(1, 3)),
        arm_length=rng.uniform(55.0, 75.0),
        speed_limit_mph=float(rng.choice([25.0, 30.0, 35.0])),
    )
    b = _new_scene("intersection", rng, net)
    _intersection_traffic(b, density)
    b.sidewalk_walkers(int(rng.integers(*peds)))
    b.crossing_walkers(int(rng.integers(1, 4)))
    return b


def _recipe_red_light(rng) -> _Builder:
    net = roads.four_way_intersection(lanes_per_direction=2, arm_length=rng.uniform(60.0, 75.0))
    red_window = (TIMES > 1.5) & (TIMES < 6.0)
    b = _new_scene("red_light", rng, net, require=lambda st: signals.is_stop(st["EW"][red_window]).all())
    # The runner approaches from the East on a red, fast enough that it does not stop.
    approach = [ln for ln in net.lanes_of_turn("approach") if ln.polyline[0, 0] > 20 and ln.polyline[0, 1] > 0]
    route = _route_from(net, approach[-1].id, rng, {"through": 1.0, "left": 0.0, "right": 0.0})
    path, stops = _chain(net, route)
    path = _weave(path, rng, 0.1)
    v = rng.uniform(11.0, 13.0)
    stop_s = stops[0][0]
    runner = b.vehicle(path, stop_s - v * rng.uniform(2.5, 3.5), v, v, stops, ignore_signals=True)
    runner.tags.add("red_light_runner")
    _intersection_traffic(b, 0.75, skip=frozenset(route))
    b.sidewalk_walkers(int(rng.integers(4, 8)))
    return b


def _recipe_dense_following(rng) -> _Builder:
    net = roads.corridor(lanes_per_direction=int(rng.integers(2, 4)), length=rng.uniform(200.0, 240.0), curvature=rng.uniform(-0.002, 0.002))
    b = _new_scene("dense_following", rng, net)
    _corridor_traffic(b, (4, 7), (8.0, 13.0), stopped_front_p=0.5)
    # Stop-and-go: the front vehicle of each queue modulates its desired speed.
    firsts = {}
    for a in b.agents:
        key = id(a.path)
        if key not in firsts or a.s_init > firsts[key].s_init:
            firsts[key] = a
    for a in firsts.values():
        phase, period = rng.uniform(0, 2 * np.pi), rng.uniform(5.0, 9.0)
        a.v0 = np.maximum(a.v0[0] * (0.55 + 0.45 * np.cos(2 * np.pi * TIMES / period + phase)), 0.5)
    b.sidewalk_walkers(int(rng.integers(2, 6)))
    return b


def _recipe_offroad(rng) -> _Builder:
    net = roads.corridor(lanes_per_direction=2, length=rng.uniform(250.0, 280.0))
    b = _new_scene("offroad", rng, net)
    approach = [ln for ln in net.lanes_of_turn("approach") if ln.polyline[0, 0] < 0]  # eastbound
    outer = max(approach, key=lambda ln: -ln.polyline[0, 1])  # southmost = rightmost lane
    route = _route_from(net, outer.id, rng, {})
    base, _ = _chain(net, route)
    base = geo.resample(base, PATH_SPACING_M)
    s = geo.arc_lengths(base)
    v = rng.uniform(9.0, 12.0)
    s_start = rng.uniform(5.0, 15.0)
    s_leave = s_start + v * rng.uniform(1.5, 2.5)
    lateral_now = -(net.lanes[outer.id].polyline[0, 1])  # distance of the lane centre from the reference line
    beyond = net.half_width - abs(lateral_now) + 2.5 + rng.uniform(0.5, 2.0)
    ramp = np.clip((s - s_leave) / 30.0, 0.0, 1.0)
    offset = -beyond * ramp * ramp * (3 - 2 * ramp)
    path = _offset_path(base, offset)
    leaver = b.vehicle(path, s_start, v, v, [])
    leaver.stops = [(s_leave + 45.0, engine.ALWAYS_RED)]  # comes to rest beyond the curb
    leaver.tags.add("leaves_road")
    _corridor_traffic(b, (3, 7), (9.0, 13.0), skip=frozenset(route))
    b.sidewalk_walkers(int(rng.integers(5, 9)))
    return b


def _recipe_occlusion(rng) -> _Builder:
    b = _recipe_intersection(rng, density=0.7, peds=(4, 9))
    return b


def _recipe_collision(rng) -> _Builder:
    net = roads.corridor(lanes_per_direction=2, length=rng.uniform(200.0, 230.0))
    b = _new_scene("collision", rng, net, require=lambda st: not signals.is_stop(st["PED"][:70]).any())
    approach = [ln for ln in net.lanes_of_turn("approach") if ln.polyline[0, 0] < 0]
    lane = approach[0]
    route = _route_from(net, lane.id, rng, {})
    path, stops = _chain(net, route)
    path = _weave(path, rng, 0.08)
    v = rng.uniform(10.0, 13.0)
    leader = b.vehicle(path, 60.0, v, v, stops)
    leader.v0 = np.where(TIMES < rng.uniform(3.0, 4.5), v, 0.0)
    leader.b_comf = 6.0
    follower = b.vehicle(path, 60.0 - leader.length / 2 - 5.0 - v * 1.2, v, v, stops)
    follower.length, follower.width = min(follower.length, 5.0), min(follower.width, 2.0)
    leader.tags.add("collision")
    follower.tags.add("collision")
    _corridor_traffic(b, (2, 5), (9.0, 13.0), skip=frozenset(route))
    b.sidewalk_walkers(int(rng.integers(3, 7)))
    return b


def _recipe_large_coordinates(rng) -> _Builder:
    return _recipe_intersection(rng, density=0.9, lanes=2)


def _recipe_heading_wrap(rng) -> _Builder:
    net = roads.corridor(lanes_per_direction=2, length=rng.uniform(200.0, 230.0), parking_width=2.4)
    b = _new_scene("heading_wrap", rng, net)
    _corridor_traffic(b, (2, 5), (9.0, 14.0))
    for edge_sign in (1.0, -1.0):
        lat = edge_sign * (net.half_width - 1.2)
        ref = np.stack([np.linspace(-100, 100, 201), np.full(201, lat)], axis=1)
        b.parked(ref if edge_sign < 0 else ref[::-1], int(rng.integers(2, 5)))
    b.sidewalk_walkers(int(rng.integers(2, 5)))
    return b


def _recipe_pedestrians(rng) -> _Builder:
    b = _recipe_intersection(rng, density=0.35, lanes=2, peds=(10, 16))
    b.crossing_walkers(int(rng.integers(6, 12)))
    return b


def _recipe_cyclists(rng) -> _Builder:
    net = roads.corridor(lanes_per_direction=1, length=rng.uniform(200.0, 230.0), bike_lane_width=1.8, parking_width=2.4, speed_limit_mph=25.0)
    b = _new_scene("cyclists", rng, net)
    _corridor_traffic(b, (2, 4), (8.0, 11.0))
    for lane in net.lanes_of_turn("bike"):
        b.lane_queue([lane.id], int(rng.integers(2, 4)), v_des=rng.uniform(4.0, 6.5), stopped_front=False, cyclist=True, weave=0.1)
    for edge_sign in (1.0, -1.0):
        lat = edge_sign * (net.half_width - 1.2)
        ref = np.stack([np.linspace(-100, 100, 201), np.full(201, lat)], axis=1)
        b.parked(ref if edge_sign < 0 else ref[::-1], int(rng.integers(2, 5)))
    b.sidewalk_walkers(int(rng.integers(2, 5)))
    return b


_RECIPES = {
    "intersection": _recipe_intersection,
    "red_light": _recipe_red_light,
    "dense_following": _recipe_dense_following,
    "offroad": _recipe_offroad,
    "occlusion": _recipe_occlusion,
    "collision": _recipe_collision,
    "large_coordinates": _recipe_large_coordinates,
    "heading_wrap": _recipe_heading_wrap,
    "pedestrians": _recipe_pedestrians,
    "cyclists": _recipe_cyclists,
}


# --------------------------------------------------------------------------------------
# Simulation, occlusion, evaluated objects, proto assembly.


@dataclass
class LoggedScene:
    """A simulated scene in the local frame.

    x, y, heading, speed, valid: (num_objects, NUM_STEPS).
    """

    spec: SceneSpec
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    valid: np.ndarray
    sdc: int
    tracks_to_predict: list[int]


def simulate_agents(agents: list[AgentSpec], signal_states: dict[str, np.ndarray], blind_pairs=()) -> engine.Rollout:
    """Runs the logged world: one batch entry, every agent of the scene."""
    n = len(agents)
    lengths = [geo.arc_lengths(a.path)[-1] for a in agents]
    min_length = max(max(lengths), max(a.s_init for a in agents) + 20.0 * NUM_STEPS * DT + 60.0)
    paths = engine.Paths.from_polylines([[a.path for a in agents]], PATH_SPACING_M, min_length)

    def col(attr, dtype=float):
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
    k = max(1, max(len(a.stops) for a in agents))
    stop_s = np.full((1, n, k), np.nan)
    stop_signal = np.full((1, n, k), engine.NO_SIGNAL, np.int64)
    for i, a in enumerate(agents):
        for j, (s, c) in enumerate(a.stops):
            stop_s[0, i, j], stop_signal[0, i, j] = s, c
    states = np.stack(list(signal_states.values()), axis=1) if signal_states else np.zeros((NUM_STEPS, 0), np.int64)
    return engine.simulate(paths, drivers, col("s_init"), col("v_init"), stop_s, stop_signal, states, NUM_STEPS, DT)


def colliding_pairs(x, y, heading, length, width, valid=None) -> list[tuple[int, int]]:
    """Pairs (i < j) of objects whose boxes overlap at some step where both are valid.

    x, y, heading, valid: (num_objects, num_steps); length, width: (num_objects,).
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
        blind = [(index[id(f)], index[id(l)]) for f, l in spec.blind_pairs]
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
    builder = _RECIPES[kind](rng)
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


def _to_world(spec: SceneSpec, xy: np.ndarray) -> np.ndarray:
    return xy @ geo.rotation(spec.rotation).T + spec.translation


def _ground(spec: SceneSpec, xy_local: np.ndarray) -> np.ndarray:
    return spec.ground_z + xy_local @ spec.slope


def _map_points(spec: SceneSpec, xy_local: np.ndarray, target) -> None:
    world = np.round(_to_world(spec, xy_local), 4).tolist()
    z = np.round(_ground(spec, xy_local), 4).tolist()
    for (x, y), zz in zip(world, z):
        p = target.add()
        p.x, p.y, p.z = x, y, zz


def assemble(scene: LoggedScene, rng: np.random.Generator):
    """The `Scenario` proto of a simulated scene, in world coordinates."""
    from wosac_eval.protos import map_pb2, scenario_pb2

    spec = scene.spec
    net = spec.network
    sc = scenario_pb2.Scenario()
    sc.scenario_id = spec.scenario_id
    sc.timestamps_seconds.extend(np.round(TIMES, 6).tolist())
    sc.current_time_index = CURRENT_TIME_INDEX

    for lane in net.lanes.values():
        f = sc.map_features.add()
        f.id = lane.id
        f.lane.speed_limit_mph = lane.speed_limit_mph
        f.lane.type = lane.lane_type
        f.lane.interpolating = lane.interpolating
        _map_points(spec, lane.polyline, f.lane.polyline)
        f.lane.entry_lanes.extend(lane.entry_lanes)
        f.lane.exit_lanes.extend(lane.exit_lanes)
    for fid, line_type, poly in net.road_lines:
        f = sc.map_features.add()
        f.id = fid
        f.road_line.type = line_type
        _map_points(spec, poly, f.road_line.polyline)
    for fid, edge_type, poly in net.road_edges:
        f = sc.map_features.add()
        f.id = fid
        f.road_edge.type = edge_type
        _map_points(spec, poly, f.road_edge.polyline)
    for fid, polygon in net.crosswalks:
        f = sc.map_features.add()
        f.id = fid
        _map_points(spec, polygon, f.crosswalk.polygon)

    signal_lanes = net.signal_lanes()
    for t in range(NUM_STEPS):
        dms = sc.dynamic_map_states.add()
        for lane in signal_lanes:
            ls = dms.lane_states.add()
            ls.lane = lane.id
            ls.state = int(spec.signal_states[lane.signal_group][t]) if lane.signal_group in spec.signal_states else map_pb2.TrafficSignalLaneState.LANE_STATE_UNKNOWN
            _map_points(spec, lane.polyline[:1], _Single(ls.stop_point))

    n = len(spec.agents)
    order = rng.permutation(n)  # WOMD lists tracks in no particular order
    first_id = int(rng.integers(100, 3000))
    world_xy = np.round(_to_world(spec, np.stack([scene.x, scene.y], axis=-1).reshape(-1, 2)).reshape(n, NUM_STEPS, 2), 4).tolist()
    heading = geo.wrap_angle(scene.heading + spec.rotation)
    ground = _ground(spec, np.stack([scene.x, scene.y], axis=-1).reshape(-1, 2)).reshape(n, NUM_STEPS)
    heading_r = np.round(heading, 5).tolist()
    vx = np.round(scene.speed * np.cos(heading), 4).tolist()
    vy = np.round(scene.speed * np.sin(heading), 4).tolist()
    valid = scene.valid.tolist()
    position_of = {}
    for pos, i in enumerate(order):
        a = spec.agents[i]
        position_of[i] = pos
        track = sc.tracks.add()
        track.id = first_id + pos
        track.object_type = a.object_type
        z = np.round(ground[i] + a.height / 2, 4).tolist()
        length, width, height = (float(np.round(d, 3)) for d in (a.length, a.width, a.height))
        for t in range(NUM_STEPS):
            st = track.states.add()
            if not valid[i][t]:
                st.valid = False
                continue
            st.center_x, st.center_y = world_xy[i][t]
            st.center_z = z[t]
            st.length, st.width, st.height = length, width, height
            st.heading = heading_r[i][t]
            st.velocity_x, st.velocity_y = vx[i][t], vy[i][t]
            st.valid = True
    sc.sdc_track_index = position_of[scene.sdc]
    for k, i in enumerate(scene.tracks_to_predict):
        req = sc.tracks_to_predict.add()
        req.track_index = position_of[i]
        req.difficulty = 1 + k % 2
    interesting = [position_of[i] for i, a in enumerate(spec.agents) if a.tags]
    sc.objects_of_interest.extend(sorted(interesting))
    return sc


class _Single:
    """Adapter so that `_map_points` can fill one MapPoint like a repeated field."""

    def __init__(self, point):
        self.point = point

    def add(self):
        return self.point


def generate_scene(seed: int, index: int, kind: str | None = None):
    """Scenario proto number `index` of the synthetic set `seed`."""
    scene = build_scene(seed, index, kind)
    return assemble(scene, np.random.default_rng([seed, index, 1]))


def generate_scenes(n: int, seed: int = 0) -> list:
    """`n` synthetic `Scenario` protos, identical for identical `(n, seed)`."""
    return [generate_scene(seed, i) for i in range(n)]


def write_scenario_shards(scenarios: list, directory: str | Path, num_shards: int = 1, prefix: str = "synthetic") -> list[Path]:
    """Writes scenarios as TFRecord shards named `<prefix>.tfrecord-0000k-of-0000n`."""
    from wosac_eval.parse.tfrecord import write_records

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    num_shards = max(1, min(num_shards, len(scenarios)))
    paths = []
    for k in range(num_shards):
        path = directory / f"{prefix}.tfrecord-{k:05d}-of-{num_shards:05d}"
        write_records(path, (s.SerializeToString() for s in scenarios[k::num_shards]))
        paths.append(path)
    return paths


def scenario_fingerprint(scenarios: list) -> str:
    """SHA-256 over the serialised protos (used to check determinism and cache freshness)."""
    h = hashlib.sha256()
    for s in scenarios:
        h.update(s.SerializeToString(deterministic=True))
    return h.hexdigest()
