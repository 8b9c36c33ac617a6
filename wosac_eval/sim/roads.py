"""Road networks for synthetic scenes: lanes, road lines, road edges, crosswalks, signals.

Everything is built in a local frame (metres, x East, y North) and moved to
world coordinates by the scene assembler. Conventions follow WOMD:

* lane centre lines are sampled every ~1 m in the direction of travel, and the
  lanes that cross an intersection (connectors) carry the traffic signal, with
  the stop point at their first vertex;
* road edges are oriented with the drivable area on their left (port side),
  i.e. counter-clockwise around the road, as the official off-road metric needs;
* traffic is right-hand.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from wosac_eval.sim import geometry as geo

LANE_SPACING_M = 1.0

# Enum values of the WOMD protos, kept here so that this module stays pure numpy.
LANE_TYPE_SURFACE_STREET = 2
LANE_TYPE_BIKE_LANE = 3
ROAD_LINE_BROKEN_SINGLE_WHITE = 1
ROAD_LINE_SOLID_SINGLE_WHITE = 2
ROAD_LINE_SOLID_DOUBLE_YELLOW = 7
ROAD_EDGE_BOUNDARY = 1


@dataclass
class Lane:
    id: int
    polyline: np.ndarray  # (num_points, 2)
    speed_limit_mph: float
    lane_type: int = LANE_TYPE_SURFACE_STREET
    entry_lanes: list[int] = field(default_factory=list)
    exit_lanes: list[int] = field(default_factory=list)
    signal_group: str | None = None  # the signal phase that controls this lane (connectors only)
    turn: str = "through"  # through / left / right / approach / departure / bike
    interpolating: bool = False


@dataclass
class Crossing:
    """A pedestrian crossing path over a crosswalk, with its curb-side waiting point."""

    path: np.ndarray  # (num_points, 2), direction of walking
    wait_s: float  # arc length of the curb point where pedestrians wait for the walk phase
    signal_group: str | None  # vehicles' phase during which pedestrians may walk


@dataclass
class RoadNetwork:
    kind: str
    lanes: dict[int, Lane]
    road_lines: list[tuple[int, int, np.ndarray]]  # (id, RoadLineType, polyline)
    road_edges: list[tuple[int, int, np.ndarray]]  # (id, RoadEdgeType, polyline)
    crosswalks: list[tuple[int, np.ndarray]]  # (id, polygon (4, 2))
    crossings: list[Crossing]
    sidewalks: list[np.ndarray]  # pedestrian paths off the road, (num_points, 2) each
    signal_groups: list[str]
    half_width: float  # lateral extent of the carriageway from its centre line (m)

    def signal_lanes(self) -> list[Lane]:
        return [lane for lane in self.lanes.values() if lane.signal_group is not None]

    def lanes_of_turn(self, turn: str) -> list[Lane]:
        return [lane for lane in self.lanes.values() if lane.turn == turn]


class _Ids:
    """Sequential map-feature ids, so that every feature id in a scene is unique."""

    def __init__(self, start: int) -> None:
        self.next = start

    def __call__(self) -> int:
        self.next += 1
        return self.next - 1


def _link(a: Lane, b: Lane) -> None:
    a.exit_lanes.append(b.id)
    b.entry_lanes.append(a.id)


# A line of the road at a lateral offset (m, positive to the left of the direction it runs in).
LineAt = Callable[[float], np.ndarray]


class _NetworkBuilder:
    """The shape every road network shares, built in order: lanes, then the painted lines (lane markings,
    stop bars), the road edges, the crosswalks with their pedestrian crossings, the sidewalks. Every map
    feature takes the next id, in the order it is added."""

    def __init__(self, first_id: int) -> None:
        self.ids = _Ids(first_id)
        self.lanes: dict[int, Lane] = {}
        self.road_lines: list[tuple[int, int, np.ndarray]] = []
        self.road_edges: list[tuple[int, int, np.ndarray]] = []
        self.crosswalks: list[tuple[int, np.ndarray]] = []
        self.crossings: list[Crossing] = []
        self.sidewalks: list[np.ndarray] = []

    def lane(self, polyline: np.ndarray, speed_limit_mph: float, **kind: Any) -> Lane:
        """A new lane (`kind`: Lane's lane_type, signal_group, turn, interpolating)."""
        lane = Lane(self.ids(), polyline, speed_limit_mph, **kind)
        self.lanes[lane.id] = lane
        return lane

    def line(self, line_type: int, polyline: np.ndarray) -> None:
        self.road_lines.append((self.ids(), line_type, polyline))

    def lane_markings(self, line_at: LineAt, lanes_per_direction: int, lane_width: float) -> None:
        """The double yellow between the directions and the broken white lines between lanes of one."""
        self.line(ROAD_LINE_SOLID_DOUBLE_YELLOW, line_at(0.0))
        for k in range(1, lanes_per_direction):
            for side in (1.0, -1.0):
                self.line(ROAD_LINE_BROKEN_SINGLE_WHITE, line_at(side * k * lane_width))

    def stop_bar(self, inner: np.ndarray, outer: np.ndarray) -> None:
        """A stop bar across the lanes of one approach, where their signalised lanes start."""
        self.line(ROAD_LINE_SOLID_SINGLE_WHITE, geo.segment(inner, outer, 0.5))

    def edge(self, polyline: np.ndarray) -> None:
        """A road edge, the drivable area on its left."""
        self.road_edges.append((self.ids(), ROAD_EDGE_BOUNDARY, polyline))

    def crosswalk(self, polygon: np.ndarray, across: LineAt, half_width: float, signal_group: str | None) -> None:
        """A crosswalk and its two crossings, one each way: from 12 m beyond the road's edge on one side to
        as far on the other, along `across` (a point at a lateral offset from the crosswalk's centre),
        pedestrians waiting 0.6 m before the road, during `signal_group`."""
        self.crosswalks.append((self.ids(), polygon))
        for sign in (1.0, -1.0):
            path = geo.segment(across(-sign * (half_width + 12.0)), across(sign * (half_width + 12.0)), 0.5)
            self.crossings.append(Crossing(path, wait_s=12.0 - 0.6, signal_group=signal_group))

    def network(self, kind: str, signal_groups: list[str], half_width: float) -> RoadNetwork:
        return RoadNetwork(
            kind=kind,
            lanes=self.lanes,
            road_lines=self.road_lines,
            road_edges=self.road_edges,
            crosswalks=self.crosswalks,
            crossings=self.crossings,
            sidewalks=self.sidewalks,
            signal_groups=signal_groups,
            half_width=half_width,
        )


def _arm_frame(a: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors along arm `a` of a four-way intersection (pointing out, East-North-West-South for
    a = 0..3) and to its left."""
    theta = a * np.pi / 2
    return np.array([np.cos(theta), np.sin(theta)]), np.array([-np.sin(theta), np.cos(theta)])


def _on_arm(a: int, r: float, lat: float) -> np.ndarray:
    """The point `r` metres out along arm `a`, `lat` metres to its left."""
    u, nrm = _arm_frame(a)
    return r * u + lat * nrm


def _arm_line(a: int, r_from: float, r_to: float) -> LineAt:
    """Arm `a`'s lines between `r_from` and `r_to` metres out, at any lateral offset."""

    def line_at(lat: float) -> np.ndarray:
        return geo.segment(_on_arm(a, r_from, lat), _on_arm(a, r_to, lat), LANE_SPACING_M)

    return line_at


def four_way_intersection(
    *,
    lanes_per_direction: int = 2,
    lane_width: float = 3.6,
    arm_length: float = 70.0,
    corner_radius: float = 6.0,
    speed_limit_mph: float = 30.0,
    first_id: int = 100,
) -> RoadNetwork:
    """A signalised four-way intersection centred at the origin.

    Arms point East, North, West, South. Each arm has `lanes_per_direction`
    approach lanes (towards the centre) and as many departure lanes. Through and
    turning connector lanes cross the box; E-W connectors belong to signal group
    "EW", N-S connectors to "NS". Crosswalks lie between the box and the stop line.
    """
    build = _NetworkBuilder(first_id)
    n, w = lanes_per_direction, lane_width
    half = n * w  # half width of each road
    cw_near, cw_far = half + corner_radius + 0.5, half + corner_radius + 4.5
    r_stop = cw_far + 1.5
    r_end = r_stop + arm_length
    approach, departure = _arm_lanes(build, n, w, (r_stop, r_end), speed_limit_mph)
    _connectors(build, n, approach, departure, speed_limit_mph)
    for a in range(4):
        build.lane_markings(_arm_line(a, r_stop, r_end), n, w)
    for a in range(4):  # across the approach lanes, where the signalised connectors start
        build.stop_bar(_on_arm(a, r_stop, 0.0), _on_arm(a, r_stop, half))
    # One curb per quadrant, between arm a (its left side) and arm a+1 (its right side).
    rc = corner_radius
    canonical = np.concatenate(
        [
            geo.segment([r_end, half], [half + rc, half], LANE_SPACING_M)[:-1],
            geo.arc([half + rc, half + rc], rc, -np.pi / 2, -np.pi, LANE_SPACING_M)[:-1],
            geo.segment([half, half + rc], [half, r_end], LANE_SPACING_M),
        ]
    )
    for a in range(4):
        build.edge(canonical @ geo.rotation(a * np.pi / 2).T)
    mid = 0.5 * (cw_near + cw_far)
    for a in range(4):
        polygon = np.stack(
            [_on_arm(a, cw_near, -half), _on_arm(a, cw_far, -half), _on_arm(a, cw_far, half), _on_arm(a, cw_near, half)]
        )
        walk_group = "NS" if a % 2 == 0 else "EW"  # pedestrians walk with the parallel traffic
        build.crosswalk(polygon, functools.partial(_on_arm, a, mid), half, walk_group)
    for _, _, edge in build.road_edges:
        offset = edge - 3.0 * geo.left_normals(edge)  # 3 m off the curb, on the right of the edge
        build.sidewalks.append(geo.resample(offset, 0.5))
    return build.network("intersection", ["EW", "NS"], half)


def _arm_lanes(
    build: _NetworkBuilder, n: int, w: float, span: tuple[float, float], speed_limit_mph: float
) -> tuple[dict[tuple[int, int], Lane], dict[tuple[int, int], Lane]]:
    """Each arm's `n` approach lanes (towards the centre, on its left) and `n` departure lanes, between
    the stop line and the arm's end (`span`), by (arm, lane from the centre line)."""
    r_stop, r_end = span
    approach: dict[tuple[int, int], Lane] = {}
    departure: dict[tuple[int, int], Lane] = {}
    for a in range(4):
        for k in range(n):
            lat = (k + 0.5) * w
            approach[a, k] = build.lane(
                geo.segment(_on_arm(a, r_end, lat), _on_arm(a, r_stop, lat), LANE_SPACING_M),
                speed_limit_mph,
                turn="approach",
            )
            departure[a, k] = build.lane(
                geo.segment(_on_arm(a, r_stop, -lat), _on_arm(a, r_end, -lat), LANE_SPACING_M),
                speed_limit_mph,
                turn="departure",
            )
    return approach, departure


def _connectors(
    build: _NetworkBuilder,
    n: int,
    approach: dict[tuple[int, int], Lane],
    departure: dict[tuple[int, int], Lane],
    speed_limit_mph: float,
) -> None:
    """The signalised lanes across the box: each approach lane straight on, the outer one right, the inner
    one left, linked to their approach and departure lanes (E-W arms in group "EW", N-S in "NS")."""
    for a in range(4):
        group = "EW" if a % 2 == 0 else "NS"
        u_in = -_arm_frame(a)[0]
        moves = [(k, (a + 2) % 4, k, "through") for k in range(n)]
        moves.append((n - 1, (a + 1) % 4, n - 1, "right"))
        moves.append((0, (a + 3) % 4, 0, "left"))
        for k_in, b, k_out, turn in moves:
            start = approach[a, k_in].polyline[-1]
            end = departure[b, k_out].polyline[0]
            if turn == "through":
                poly = geo.segment(start, end, LANE_SPACING_M)
            else:
                poly = geo.bezier(start, u_in, end, _arm_frame(b)[0], LANE_SPACING_M)
            conn = build.lane(poly, speed_limit_mph, signal_group=group, turn=turn, interpolating=True)
            _link(approach[a, k_in], conn)
            _link(conn, departure[b, k_out])


def corridor(
    *,
    lanes_per_direction: int = 2,
    lane_width: float = 3.6,
    length: float = 220.0,
    curvature: float = 0.0,
    parking_width: float = 0.0,
    bike_lane_width: float = 0.0,
    speed_limit_mph: float = 35.0,
    first_id: int = 100,
) -> RoadNetwork:
    """A two-way arterial along +x with a signalised mid-block pedestrian crossing.

    The reference line runs from x = -length/2 to +length/2 and bends with
    constant `curvature` (1/m, positive turns left). Eastbound lanes are on the
    right of the reference line. Each lane is split into an approach lane, a
    short signalised lane over the crosswalk (signal group "PED" for vehicles:
    it is red while pedestrians walk) and a departure lane. Optional parking
    strips and bike lanes lie between the outer lane and the road edge.
    """
    build = _NetworkBuilder(first_id)
    n, w = lanes_per_direction, lane_width
    s_ref = np.arange(0.0, length + 1e-9, LANE_SPACING_M)
    if abs(curvature) < 1e-9:
        ref = np.stack([s_ref - length / 2, np.zeros_like(s_ref)], axis=1)
    else:
        ang = (s_ref - length / 2) * curvature
        ref = np.stack([np.sin(ang) / curvature, (1 - np.cos(ang)) / curvature], axis=1)
    normal = geo.left_normals(ref)

    def offset_line(lat: float) -> np.ndarray:
        return ref + lat * normal

    half_lanes = n * w
    half = half_lanes + bike_lane_width + parking_width
    s_mid = length / 2
    cw_near, cw_far = s_mid - 2.0, s_mid + 2.0
    _corridor_lanes(build, offset_line, (n, w, bike_lane_width), (cw_near, cw_far), speed_limit_mph)
    build.lane_markings(offset_line, n, w)
    if bike_lane_width > 0 or parking_width > 0:
        for side in (1.0, -1.0):
            build.line(ROAD_LINE_SOLID_SINGLE_WHITE, offset_line(side * half_lanes))
    for direction in (1, -1):  # across each direction's lanes, through the first points of its signalised lanes
        starts = np.array(
            [
                lane.polyline[0]
                for lane in build.lanes.values()
                if lane.signal_group and np.sign(lane.polyline[-1, 0] - lane.polyline[0, 0]) == direction
            ]
        )
        across = starts[-1] - starts[0] if len(starts) > 1 else np.array([0.0, -direction])
        across = across / np.linalg.norm(across)
        build.stop_bar(starts[0] - across * w / 2, starts[-1] + across * w / 2)
    # Right edge runs along +s (road on its left); the left edge runs back along -s.
    build.edge(offset_line(-half))
    build.edge(offset_line(half)[::-1])
    s_cw = geo.arc_lengths(ref)
    c_near = np.array([np.interp(cw_near, s_cw, ref[:, k]) for k in range(2)])
    c_far = np.array([np.interp(cw_far, s_cw, ref[:, k]) for k in range(2)])
    nrm = normal[int(round(s_mid / LANE_SPACING_M))]
    polygon = np.stack([c_near - half * nrm, c_far - half * nrm, c_far + half * nrm, c_near + half * nrm])
    centre = 0.5 * (c_near + c_far)
    build.crosswalk(polygon, lambda lat: centre + lat * nrm, half, "WALK")
    build.sidewalks += [geo.resample(offset_line(-half - 3.0), 0.5), geo.resample(offset_line(half + 3.0)[::-1], 0.5)]
    return build.network("corridor", ["PED", "WALK"], half)


def _split(poly: np.ndarray, s_cuts: list[float]) -> list[np.ndarray]:
    """A polyline cut at arc lengths `s_cuts`, each piece with the cut points at its ends."""
    s = geo.arc_lengths(poly)
    pieces, bounds = [], [0.0, *s_cuts, s[-1]]
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        keep = (s > lo) & (s < hi)
        pts = np.concatenate(
            [
                [np.array([np.interp(lo, s, poly[:, k]) for k in range(2)])],
                poly[keep],
                [np.array([np.interp(hi, s, poly[:, k]) for k in range(2)])],
            ]
        )
        pieces.append(pts)
    return pieces


def _corridor_lanes(
    build: _NetworkBuilder,
    offset_line: LineAt,
    widths: tuple[int, float, float],
    crosswalk: tuple[float, float],
    speed_limit_mph: float,
) -> None:
    """Each direction's lanes, each an approach, a signalised lane over the crosswalk (group "PED") and a
    departure, linked; then its bike lane (when `widths`' bike lane width is not 0).

    widths: lanes per direction, lane width and bike lane width; crosswalk: its near and far arc lengths.
    """
    n, w, bike_lane_width = widths
    cw_near, cw_far = crosswalk
    stop_gap = 1.5
    for direction in (1, -1):
        for k in range(n):
            poly = offset_line(-direction * (k + 0.5) * w)
            if direction < 0:
                poly = poly[::-1]
            # In travel coordinates the crosswalk spans [cw_near, cw_far] either way (it is centred).
            ap_poly, cross_poly, de_poly = _split(poly, [cw_near - stop_gap, cw_far + 0.5])
            ap = build.lane(ap_poly, speed_limit_mph, turn="approach")
            cr = build.lane(cross_poly, speed_limit_mph, signal_group="PED", turn="through", interpolating=True)
            de = build.lane(de_poly, speed_limit_mph, turn="departure")
            _link(ap, cr)
            _link(cr, de)
        if bike_lane_width > 0:
            poly = offset_line(-direction * (n * w + bike_lane_width / 2))
            if direction < 0:
                poly = poly[::-1]
            build.lane(poly, 15.0, lane_type=LANE_TYPE_BIKE_LANE, turn="bike")
