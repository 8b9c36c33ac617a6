"""Scene recipes: a road network populated with logged objects, one recipe per kind of scene.

Each kind of `SCENE_KINDS` exercises something the metrics must handle:

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

A recipe (`RECIPES[kind](rng)`) returns a `SceneBuilder`: the network, its signal programs and
the `AgentSpec`s placed on it; `logged_scenes` simulates it closed-loop (see `engine.py`), so
the logged motion is physically plausible and collision-free unless the recipe scripts a collision.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from wosac_eval.arrays.object_types import TYPE_CYCLIST, TYPE_PEDESTRIAN, TYPE_VEHICLE
from wosac_eval.sim import engine, roads, signals
from wosac_eval.sim import geometry as geo
from wosac_eval.sim.scene_specs import (
    NUM_STEPS,
    PATH_SPACING_M,
    TIMES,
    AgentSpec,
)

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
    pieces: list[np.ndarray] = []
    stops: list[tuple[float, str]] = []
    s0 = 0.0
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


def _route_from(
    network: roads.RoadNetwork, lane_id: int, rng: np.random.Generator, weights: dict[str, float]
) -> list[int]:
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
class SceneBuilder:
    """A scene being populated: the network, its signal programs and the objects placed so far."""

    rng: np.random.Generator
    network: roads.RoadNetwork
    signal_states: dict[str, np.ndarray]
    agents: list[AgentSpec] = field(default_factory=list)

    @property
    def columns(self) -> dict[str, int]:
        return {g: i for i, g in enumerate(self.signal_states)}

    def vehicle(
        self, path: Any, s_init: Any, v_init: Any, v_des: Any, stops: Any = (), *, cyclist: bool = False, **kw: Any
    ) -> AgentSpec:
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

    def lane_queue(
        self,
        lane_ids: list[int],
        count: int,
        *,
        v_des: float,
        stopped_front: bool,
        weave: float = 0.12,
        cyclist: bool = False,
        lateral: float = 0.0,
        min_s: float = 0.0,
    ) -> list[AgentSpec]:
        """Spawns `count` vehicles in one lane chain, front to back, spaced like IDM traffic."""
        path, stops = _chain(self.network, lane_ids)
        path = _weave(_offset_path(geo.resample(path, PATH_SPACING_M), lateral), self.rng, weave)
        first_stop = stops[0][0] if stops else geo.arc_lengths(path)[-1] - 10.0
        s_front = first_stop - self.rng.uniform(1.5, 6.0 if stopped_front else 30.0)
        spawned: list[AgentSpec] = []
        for i in range(count):
            spec = self.vehicle(path, 0.0, 0.0, v_des * self.rng.uniform(0.85, 1.1), stops, cyclist=cyclist)
            if i == 0:
                spec.s_init = s_front - spec.length / 2
                room = first_stop - s_front  # nose to the first stop line
                # Fast enough to look natural, slow enough to stop comfortably if the light is red.
                spec.v_init = (
                    0.0
                    if stopped_front
                    else float(min(spec.v0[0], 0.8 * np.sqrt(2 * spec.b_comf * max(room + 8.0, 0.0))))
                )
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

    def pedestrian(self, path: np.ndarray, s_init: float, v_des: float, stops: Any = (), **kw: Any) -> AgentSpec:
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

    def sidewalk_walkers(self, count: int) -> None:
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

    def crossing_walkers(self, count: int) -> None:
        columns = self.columns
        for _ in range(count):
            crossing = self.network.crossings[self.rng.integers(len(self.network.crossings))]
            path = _offset_path(crossing.path, -self.rng.uniform(0.3, 1.6))  # keep right on the crosswalk
            stops = [(crossing.wait_s, columns[crossing.signal_group])] if crossing.signal_group in columns else []
            self.pedestrian(path, self.rng.uniform(0.0, crossing.wait_s - 0.5), self.rng.uniform(1.1, 1.6), stops)

    def parked(self, path: np.ndarray, count: int) -> None:
        total = geo.arc_lengths(path)[-1]
        slots = np.sort(self.rng.choice(np.arange(8.0, total - 8.0, 7.5), size=count, replace=False))
        for s in slots:
            spec = self.vehicle(path, float(s), 0.0, 0.0, moving=False)
            spec.length = min(spec.length, 5.2)
            spec.width = min(spec.width, 2.0)


# --------------------------------------------------------------------------------------
# Recipes.


def _intersection_traffic(
    b: SceneBuilder, density: float, stopped_bias: float = 0.4, skip: frozenset = frozenset()
) -> None:
    net = b.network
    weights = {"through": 0.6, "left": 0.2, "right": 0.2}
    approaches = [ln for ln in net.lanes_of_turn("approach") if ln.id not in skip]
    busy = b.rng.choice(len(approaches), size=max(3, int(round(density * len(approaches)))), replace=False)
    for lane in [approaches[i] for i in sorted(busy)]:
        route = _route_from(net, lane.id, b.rng, weights)
        group = net.lanes[route[1]].signal_group
        if group is None:
            raise ValueError(f"lane {route[1]} after approach {lane.id} is not a signalised connector")
        red_now = signals.is_stop(b.signal_states[group][0]) or signals.is_caution(b.signal_states[group][0])
        b.lane_queue(
            route,
            int(b.rng.integers(2, 6)),
            v_des=b.rng.uniform(9.0, 14.0),
            stopped_front=bool(red_now and b.rng.random() < 0.5 + stopped_bias),
        )
    for lane in net.lanes_of_turn("departure"):
        if b.rng.random() > density * 0.6 or lane.id in skip:
            continue
        b.lane_queue(
            [lane.id], int(b.rng.integers(1, 3)), v_des=b.rng.uniform(10.0, 14.0), stopped_front=False, min_s=20.0
        )


def _corridor_traffic(
    b: SceneBuilder,
    per_lane: tuple[int, int],
    v_range: tuple[float, float],
    stopped_front_p: float = 0.3,
    skip: frozenset = frozenset(),
) -> None:
    net = b.network
    for lane in [ln for ln in net.lanes_of_turn("approach") if ln.id not in skip]:
        route = _route_from(net, lane.id, b.rng, {})
        red = signals.is_stop(b.signal_states["PED"][0])
        b.lane_queue(
            route,
            int(b.rng.integers(*per_lane)),
            v_des=b.rng.uniform(*v_range),
            stopped_front=bool(red and b.rng.random() < 0.5 + stopped_front_p),
        )
    for lane in net.lanes_of_turn("departure"):
        if b.rng.random() < 0.6 and lane.id not in skip:
            b.lane_queue(
                [lane.id], int(b.rng.integers(1, 3)), v_des=b.rng.uniform(*v_range), stopped_front=False, min_s=25.0
            )


def _signal_states(network: roads.RoadNetwork, rng: np.random.Generator, require: Any = None) -> dict[str, np.ndarray]:
    """Draws signal programs until `require(states)` holds (so recipes get the phase they need)."""
    program = signals.intersection_program if network.kind == "intersection" else signals.midblock_program
    for _ in range(200):
        states = program(TIMES, rng)
        if require is None or require(states):
            return states
    raise RuntimeError("no signal program satisfies the recipe")


def _new_scene(kind: str, rng: np.random.Generator, network: roads.RoadNetwork, require: Any = None) -> SceneBuilder:
    return SceneBuilder(rng, network, _signal_states(network, rng, require))


def _recipe_intersection(
    rng: np.random.Generator, *, density: float = 0.55, lanes: Any = None, peds: Any = (3, 8)
) -> SceneBuilder:
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


def _recipe_red_light(rng: np.random.Generator) -> SceneBuilder:
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


def _recipe_dense_following(rng: np.random.Generator) -> SceneBuilder:
    net = roads.corridor(
        lanes_per_direction=int(rng.integers(2, 4)),
        length=rng.uniform(200.0, 240.0),
        curvature=rng.uniform(-0.002, 0.002),
    )
    b = _new_scene("dense_following", rng, net)
    _corridor_traffic(b, (4, 7), (8.0, 13.0), stopped_front_p=0.5)
    # Stop-and-go: the front vehicle of each queue modulates its desired speed.
    firsts: dict[int, AgentSpec] = {}
    for a in b.agents:
        key = id(a.path)
        if key not in firsts or a.s_init > firsts[key].s_init:
            firsts[key] = a
    for a in firsts.values():
        phase, period = rng.uniform(0, 2 * np.pi), rng.uniform(5.0, 9.0)
        a.v0 = np.maximum(a.v0[0] * (0.55 + 0.45 * np.cos(2 * np.pi * TIMES / period + phase)), 0.5)
    b.sidewalk_walkers(int(rng.integers(2, 6)))
    return b


def _recipe_offroad(rng: np.random.Generator) -> SceneBuilder:
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


def _recipe_occlusion(rng: np.random.Generator) -> SceneBuilder:
    b = _recipe_intersection(rng, density=0.7, peds=(4, 9))
    return b


def _recipe_collision(rng: np.random.Generator) -> SceneBuilder:
    net = roads.corridor(lanes_per_direction=2, length=rng.uniform(200.0, 230.0))
    b = _new_scene("collision", rng, net, require=lambda st: not signals.is_stop(st["PED"][:70]).any())
    approach = [ln for ln in net.lanes_of_turn("approach") if ln.polyline[0, 0] < 0]
    lane = approach[0]
    route = _route_from(net, lane.id, rng, {})
    path, stops = _chain(net, route)
    path = _weave(path, rng, 0.08)
    v = rng.uniform(10.0, 13.0)
    leader = b.vehicle(path, 60.0, v, v, stops)
    leader.v0 = np.where(rng.uniform(3.0, 4.5) > TIMES, v, 0.0)
    leader.b_comf = 6.0
    follower = b.vehicle(path, 60.0 - leader.length / 2 - 5.0 - v * 1.2, v, v, stops)
    follower.length, follower.width = min(follower.length, 5.0), min(follower.width, 2.0)
    leader.tags.add("collision")
    follower.tags.add("collision")
    _corridor_traffic(b, (2, 5), (9.0, 13.0), skip=frozenset(route))
    b.sidewalk_walkers(int(rng.integers(3, 7)))
    return b


def _recipe_large_coordinates(rng: np.random.Generator) -> SceneBuilder:
    return _recipe_intersection(rng, density=0.9, lanes=2)


def _recipe_heading_wrap(rng: np.random.Generator) -> SceneBuilder:
    net = roads.corridor(lanes_per_direction=2, length=rng.uniform(200.0, 230.0), parking_width=2.4)
    b = _new_scene("heading_wrap", rng, net)
    _corridor_traffic(b, (2, 5), (9.0, 14.0))
    for edge_sign in (1.0, -1.0):
        lat = edge_sign * (net.half_width - 1.2)
        ref = np.stack([np.linspace(-100, 100, 201), np.full(201, lat)], axis=1)
        b.parked(ref if edge_sign < 0 else ref[::-1], int(rng.integers(2, 5)))
    b.sidewalk_walkers(int(rng.integers(2, 5)))
    return b


def _recipe_pedestrians(rng: np.random.Generator) -> SceneBuilder:
    b = _recipe_intersection(rng, density=0.35, lanes=2, peds=(10, 16))
    b.crossing_walkers(int(rng.integers(6, 12)))
    return b


def _recipe_cyclists(rng: np.random.Generator) -> SceneBuilder:
    net = roads.corridor(
        lanes_per_direction=1,
        length=rng.uniform(200.0, 230.0),
        bike_lane_width=1.8,
        parking_width=2.4,
        speed_limit_mph=25.0,
    )
    b = _new_scene("cyclists", rng, net)
    _corridor_traffic(b, (2, 4), (8.0, 11.0))
    for lane in net.lanes_of_turn("bike"):
        b.lane_queue(
            [lane.id],
            int(rng.integers(2, 4)),
            v_des=rng.uniform(4.0, 6.5),
            stopped_front=False,
            cyclist=True,
            weave=0.1,
        )
    for edge_sign in (1.0, -1.0):
        lat = edge_sign * (net.half_width - 1.2)
        ref = np.stack([np.linspace(-100, 100, 201), np.full(201, lat)], axis=1)
        b.parked(ref if edge_sign < 0 else ref[::-1], int(rng.integers(2, 5)))
    b.sidewalk_walkers(int(rng.integers(2, 5)))
    return b


RECIPES = {
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
