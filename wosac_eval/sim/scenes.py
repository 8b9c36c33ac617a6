"""Deterministic synthetic WOMD-like scenarios (`Scenario` protos) for demos and tests.

`generate_scenes(n, seed)` returns `n` scenarios; the same `(n, seed)` always
gives byte-identical serialised protos. Scene `i` draws all its randomness from
`numpy.random.default_rng([seed, i])` and cycles through the recipes in
`scene_recipes.SCENE_KINDS`; `logged_scenes` simulates it (closed loop, see `engine.py`)
and this module writes it as a `Scenario` proto in world coordinates, and as TFRecord shards.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from wosac_eval.challenges import CURRENT_TIME_INDEX
from wosac_eval.parse.tfrecord import write_records
from wosac_eval.protos import map_pb2, scenario_pb2
from wosac_eval.sim import geometry as geo
from wosac_eval.sim.logged_scenes import LoggedScene, build_scene
from wosac_eval.sim.scene_specs import NUM_STEPS, TIMES, SceneSpec

# Bump when the generated scenes change, so that cached demo scenes are regenerated.
GENERATOR_VERSION = 5


def _to_world(spec: SceneSpec, xy: np.ndarray) -> np.ndarray:
    return xy @ geo.rotation(spec.rotation).T + spec.translation


def _ground(spec: SceneSpec, xy_local: np.ndarray) -> np.ndarray:
    return spec.ground_z + xy_local @ spec.slope


def _map_points(spec: SceneSpec, xy_local: np.ndarray, target: Any) -> None:
    world = np.round(_to_world(spec, xy_local), 4).tolist()
    z = np.round(_ground(spec, xy_local), 4).tolist()
    for (x, y), zz in zip(world, z):
        p = target.add()
        p.x, p.y, p.z = x, y, zz


def assemble(scene: LoggedScene, rng: np.random.Generator) -> scenario_pb2.Scenario:
    """The `Scenario` proto of a simulated scene, in world coordinates."""
    spec = scene.spec
    sc = scenario_pb2.Scenario()
    sc.scenario_id = spec.scenario_id
    sc.timestamps_seconds.extend(np.round(TIMES, 6).tolist())
    sc.current_time_index = CURRENT_TIME_INDEX
    _add_map(sc, spec)
    _add_signal_states(sc, spec)
    _add_tracks(sc, scene, rng)
    return sc


def _add_map(sc: Any, spec: SceneSpec) -> None:
    """The network's lanes, road lines, road edges and crosswalks, as map features."""
    net = spec.network
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


def _add_signal_states(sc: Any, spec: SceneSpec) -> None:
    """Every step's state of every signalised lane, with its stop point (the lane's first point)."""
    signal_lanes = spec.network.signal_lanes()
    for t in range(NUM_STEPS):
        dms = sc.dynamic_map_states.add()
        for lane in signal_lanes:
            ls = dms.lane_states.add()
            ls.lane = lane.id
            ls.state = (
                int(spec.signal_states[lane.signal_group][t])
                if lane.signal_group in spec.signal_states
                else map_pb2.TrafficSignalLaneState.LANE_STATE_UNKNOWN
            )
            _map_points(spec, lane.polyline[:1], _Single(ls.stop_point))


def _add_tracks(sc: Any, scene: LoggedScene, rng: np.random.Generator) -> None:
    """The agents' tracks in a random order (as WOMD lists them), the SDC, the tracks to predict and the
    objects of interest."""
    spec = scene.spec
    n = len(spec.agents)
    order = rng.permutation(n)  # WOMD lists tracks in no particular order
    first_id = int(rng.integers(100, 3000))
    world_xy = np.round(
        _to_world(spec, np.stack([scene.x, scene.y], axis=-1).reshape(-1, 2)).reshape(n, NUM_STEPS, 2), 4
    ).tolist()
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


class _Single:
    """Adapter so that `_map_points` can fill one MapPoint like a repeated field."""

    def __init__(self, point: map_pb2.MapPoint) -> None:
        self.point = point

    def add(self) -> map_pb2.MapPoint:
        return self.point


def generate_scene(seed: int, index: int, kind: str | None = None) -> scenario_pb2.Scenario:
    """Scenario proto number `index` of the synthetic set `seed`."""
    scene = build_scene(seed, index, kind)
    return assemble(scene, np.random.default_rng([seed, index, 1]))


def generate_scenes(n: int, seed: int = 0) -> list[scenario_pb2.Scenario]:
    """`n` synthetic `Scenario` protos, identical for identical `(n, seed)`."""
    return [generate_scene(seed, i) for i in range(n)]


def write_scenario_shards(
    scenarios: list, directory: str | Path, num_shards: int = 1, prefix: str = "synthetic"
) -> list[Path]:
    """Writes scenarios as TFRecord shards named `<prefix>.tfrecord-0000k-of-0000n`."""
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
