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

from dataclasses import dataclass, field

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

    def __init__(self, start: int):
        self.next = start

    def __call__(self) -> int:
        self.next += 1
        return self.next - 1


def _link(a: Lane, b: Lane) -> None:
    a.exit_lanes.append(b.id)
    b.entry_lanes.append(a.id)


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
    ids = _Ids(first_id)
    n, w = lanes_per_direction, lane_width
    half = n * w  # half width of each road
    cw_near, cw_far = half + corner_radius + 0.5, half + corner_radius + 4.5
    r_stop = cw_far + 1.5
    r_end = r_stop + arm_length
    lanes: dict[int, Lane] = {}

    def frame(a: int):
        theta = a * np.pi / 2
        return np.array([np.cos(theta), np.sin(theta)]), np.array([-np.sin(theta), np.cos(theta)])

    def at(a: int, r: float, lat: float) -> np.ndarray:
        u, nrm = frame(a)
        return r * u + lat * nrm

    approach: dict[tuple[int, int], Lane] = {}
    departure: dict[tuple[int, int], Lane] = {}
    for a in range(4):
        for k in range(n):
            lat = (k + 0.5) * w
            ap = Lane(
                ids(),
                geo.segment(at(a, r_end, lat), at(a, r_stop, lat), LANE_SPACING_M),
                speed_limit_mph,
                turn="approach",
            )
            de = Lane(
                ids(),
                geo.segment(at(a, r_stop, -lat), at(a, r_end, -lat), LANE_SPACING_M),
                speed_limit_mph,
                turn="departure",
            )
            approach[a, k], departure[a, k] = ap, de
            lanes[ap.id], lanes[de.id] = ap, de

    for a in range(4):
        group = "EW" if a % 2 == 0 else "NS"
        u_in = -frame(a)[0]
        moves = [(k, (a + 2) % 4, k, "through") for k in range(n)]
        moves.append((n - 1, (a + 1) % 4, n - 1, "right"))
        moves.append((0, (a + 3) % 4, 0, "left"))
        for k_in, b, k_out, turn in moves:
            start = approach[a, k_in].polyline[-1]
            end = departure[b, k_out].polyline[0]
            if turn == "through":
                poly = geo.segment(start, end, LANE_SPACING_M)
            else:
                poly = geo.bezier(start, u_in, end, frame(b)[0], LANE_SPACING_M)
            conn = Lane(ids(), poly, speed_limit_mph, signal_group=group, turn=turn, interpolating=True)
            lanes[conn.id] = conn
            _link(approach[a, k_in], conn)
            _link(conn, departure[b, k_out])

    road_lines: list[tuple[int, int, np.ndarray]] = []
    for a in range(4):
        road_lines.append(
            (ids(), ROAD_LINE_SOLID_DOUBLE_YELLOW, geo.segment(at(a, r_stop, 0.0), at(a, r_end, 0.0), LANE_SPACING_M))
        )
        for k in range(1, n):
            for side in (1.0, -1.0):
                line = geo.segment(at(a, r_stop, side * k * w), at(a, r_end, side * k * w), LANE_SPACING_M)
                road_lines.append((ids(), ROAD_LINE_BROKEN_SINGLE_WHITE, line))

    # Stop bars across the approach lanes, where the signalised connectors start.
    for a in range(4):
        road_lines.append(
            (ids(), ROAD_LINE_SOLID_SINGLE_WHITE, geo.segment(at(a, r_stop, 0.0), at(a, r_stop, half), 0.5))
        )

    # One curb per quadrant, between arm a (its left side) and arm a+1 (its right side).
    road_edges = []
    rc = corner_radius
    canonical = np.concatenate(
        [
            geo.segment([r_end, half], [half + rc, half], LANE_SPACING_M)[:-1],
            geo.arc([half + rc, half + rc], rc, -np.pi / 2, -np.pi, LANE_SPACING_M)[:-1],
            geo.segment([half, half + rc], [half, r_end], LANE_SPACING_M),
        ]
    )
    for a in range(4):
        road_edges.append((ids(), ROAD_EDGE_BOUNDARY, canonical @ geo.rotation(a * np.pi / 2).T))

    crosswalks, crossings = [], []
    for a in range(4):
        poly = np.stack([at(a, cw_near, -half), at(a, cw_far, -half), at(a, cw_far, half), at(a, cw_near, half)])
        crosswalks.append((ids(), poly))
        mid = 0.5 * (cw_near + cw_far)
        walk_group = "NS" if a % 2 == 0 else "EW"  # pedestrians walk with the parallel traffic
        for sign in (1.0, -1.0):
            path = geo.segment(at(a, mid, -sign * (half + 12.0)), at(a, mid, sign * (half + 12.0)), 0.5)
            crossings.append(Crossing(path, wait_s=12.0 - 0.6, signal_group=walk_group))

    sidewalks = []
    for _, _, edge in road_edges:
        offset = edge - 3.0 * geo.left_normals(edge)  # 3 m off the curb, on the right of the edge
        sidewalks.append(geo.resample(offset, 0.5))

    return RoadNetwork(
        kind="intersection",
        lanes=lanes,
        road_lines=road_lines,
        road_edges=road_edges,
        crosswalks=crosswalks,
        crossings=crossings,
        sidewalks=sidewalks,
        signal_groups=["EW", "NS"],
        half_width=half,
    )


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
    ids = _Ids(first_id)
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
    stop_gap = 1.5
    lanes: dict[int, Lane] = {}

    def split(poly: np.ndarray, s_cuts: list[float]) -> list[np.ndarray]:
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

    for direction in (1, -1):
        for k in range(n):
            lat = -direction * (k + 0.5) * w
            poly = offset_line(lat)
            if direction < 0:
                poly = poly[::-1]
            # In travel coordinates the crosswalk spans [cw_near, cw_far] either way (it is centred).
            cuts = [cw_near - stop_gap, cw_far + 0.5]
            ap_poly, cross_poly, de_poly = split(poly, cuts)
            ap = Lane(ids(), ap_poly, speed_limit_mph, turn="approach")
            cr = Lane(ids(), cross_poly, speed_limit_mph, signal_group="PED", turn="through", interpolating=True)
            de = Lane(ids(), de_poly, speed_limit_mph, turn="departure")
            for lane in (ap, cr, de):
                lanes[lane.id] = lane
            _link(ap, cr)
            _link(cr, de)
        if bike_lane_width > 0:
            lat = -direction * (half_lanes + bike_lane_width / 2)
            poly = offset_line(lat)
            if direction < 0:
                poly = poly[::-1]
            bike = Lane(ids(), poly, 15.0, lane_type=LANE_TYPE_BIKE_LANE, turn="bike")
            lanes[bike.id] = bike

    road_lines = [(ids(), ROAD_LINE_SOLID_DOUBLE_YELLOW, offset_line(0.0))]
    for k in range(1, n):
        for side in (1.0, -1.0):
            road_lines.append((ids(), ROAD_LINE_BROKEN_SINGLE_WHITE, offset_line(side * k * w)))
    if bike_lane_width > 0 or parking_width > 0:
        for side in (1.0, -1.0):
            road_lines.append((ids(), ROAD_LINE_SOLID_SINGLE_WHITE, offset_line(side * half_lanes)))

    # Stop bars across each direction's lanes, through the first points of its signalised lanes.
    for direction in (1, -1):
        starts = np.array(
            [
                lane.polyline[0]
                for lane in lanes.values()
                if lane.signal_group and np.sign(lane.polyline[-1, 0] - lane.polyline[0, 0]) == direction
            ]
        )
        across = starts[-1] - starts[0] if len(starts) > 1 else np.array([0.0, -direction])
        across = across / np.linalg.norm(across)
        inner, outer = starts[0] - across * w / 2, starts[-1] + across * w / 2
        road_lines.append((ids(), ROAD_LINE_SOLID_SINGLE_WHITE, geo.segment(inner, outer, 0.5)))

    # Right edge runs along +s (road on its left); the left edge runs back along -s.
    road_edges = [
        (ids(), ROAD_EDGE_BOUNDARY, offset_line(-half)),
        (ids(), ROAD_EDGE_BOUNDARY, offset_line(half)[::-1]),
    ]

    s_cw = geo.arc_lengths(ref)
    c_near = np.array([np.interp(cw_near, s_cw, ref[:, k]) for k in range(2)])
    c_far = np.array([np.interp(cw_far, s_cw, ref[:, k]) for k in range(2)])
    nrm = normal[int(round(s_mid / LANE_SPACING_M))]
    polygon = np.stack([c_near - half * nrm, c_far - half * nrm, c_far + half * nrm, c_near + half * nrm])
    crosswalks = [(ids(), polygon)]
    centre = 0.5 * (c_near + c_far)
    crossings = []
    for sign in (1.0, -1.0):
        path = geo.segment(centre - sign * (half + 12.0) * nrm, centre + sign * (half + 12.0) * nrm, 0.5)
        crossings.append(Crossing(path, wait_s=12.0 - 0.6, signal_group="WALK"))

    sidewalks = [geo.resample(offset_line(-half - 3.0), 0.5), geo.resample(offset_line(half + 3.0)[::-1], 0.5)]
    return RoadNetwork(
        kind="corridor",
        lanes=lanes,
        road_lines=road_lines,
        road_edges=road_edges,
        crosswalks=crosswalks,
        crossings=crossings,
        sidewalks=sidewalks,
        signal_groups=["PED", "WALK"],
        half_width=half,
    )
