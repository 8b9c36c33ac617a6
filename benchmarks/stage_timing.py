"""One scenario's scoring timed stage by stage, with each search's operation count and share of its floor.

Shared by `score_speed.py` (Sim Agents) and `scenario_gen_speed.py` (Scenario Generation).

The stages are the pipeline's (parse, arrays, samples, map index, the four searches of the
features, the rest of the features, estimators and metrics); the end-to-end figure is what a
scoring worker does with a scenario (protobuf bytes in: the rollouts parsed and their arrays read from
the same bytes, the scenario's arrays read from its record's bytes, `score_scenario`; metrics out),
timed apart.

For the two searches that look for a nearest thing, the floor is the arithmetic alone: one exact
float32 evaluation per query (a box corner against one road-edge segment; an evaluated box
against one other box), compiled as the search's own kernels are, with no search at all.
`share of floor` is that time over the stage's time: 100% would mean the search costs nothing
beyond computing the answer once.
"""

from __future__ import annotations

import statistics
import time

import numba
import numpy as np

from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.samples import sample_batch
from wosac_eval.arrays.scenario import record_arrays
from wosac_eval.features import box_geometry, interaction, metric_features as mf, road_edge
from wosac_eval.features.compiled import compiled
from wosac_eval.features.search import PrunedSearch
from wosac_eval.metrics.scenario_metrics import scenario_metrics
from wosac_eval.protos import sim_agents_submission_pb2
from wosac_eval.scoring.scenario import score_scenario

SEARCHES = ("nearest_object", "time_to_collision", "road_edge_distance", "red_light_violation")


class TimedSearch:
    """Delegates to a `PrunedSearch`, adding each method's wall time to `seconds[name]`."""

    def __init__(self, search: PrunedSearch, seconds: dict):
        self.search, self.seconds, self.arguments = search, seconds, {}

    def __getattr__(self, name):
        method = getattr(self.search, name)
        if name not in SEARCHES:
            return method

        def timed(*args, **kwargs):
            start = time.perf_counter()
            out = method(*args, **kwargs)
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start
            self.arguments[name] = args
            return out

        return timed


_selection_distance = compiled(road_edge.segment_distances)
_rounded_box_distance = compiled(interaction.rounded_box_distance)


@numba.njit(error_model="numpy")
def _one_selection_each(queries, segment, start, delta):
    """The road-edge floor: one selection distance per query (compiled, as the search's own)."""
    out = np.empty(queries.shape[0], np.float32)
    for i in range(queries.shape[0]):
        k = segment[i]
        out[i] = _selection_distance(
            queries[i, 0],
            queries[i, 1],
            queries[i, 2],
            start[k, 0],
            start[k, 1],
            start[k, 2],
            delta[k, 0],
            delta[k, 1],
            delta[k, 2],
        )[1]
    return out


@numba.njit(error_model="numpy")
def _one_box_distance_each(boxes, mine, partner):
    """The nearest-object floor: one exact rounded-box distance per query box (compiled)."""
    out = np.empty(mine.shape[0], np.float32)
    for i in range(mine.shape[0]):
        a, b = mine[i], partner[i]
        out[i] = _rounded_box_distance(
            (boxes[a, 0], boxes[a, 1], boxes[a, 2], boxes[a, 3], boxes[a, 4], boxes[a, 5], boxes[a, 6]),
            (boxes[b, 0], boxes[b, 1], boxes[b, 2], boxes[b, 3], boxes[b, 4], boxes[b, 5], boxes[b, 6]),
        )
    return out


def median_time(fn, repeat: int):
    fn()
    runs = []
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        runs.append(time.perf_counter() - start)
    return statistics.median(runs), out


def _road_edge_counts(table: road_edge.SegmentTable, boxes: tuple, repeat: int) -> dict:
    """Queries (valid box corners), pairs the search evaluates exactly, and the floor's seconds.

    boxes: the arguments the road-edge search was called with (x, y, bottom, length, width, cos_h,
    sin_h, valid), as `TimedSearch` kept them."""
    x, y, bottom, length, width, cos_h, sin_h, valid = boxes
    corners = box_geometry.box_bottom_corners(x, y, bottom, length, width, cos_h, sin_h)
    queries = np.asarray(corners, np.float32)[np.asarray(valid)].reshape(-1, 3)
    queries = np.ascontiguousarray(queries[np.isfinite(queries).all(axis=1)])
    counts = {}
    road_edge.box_distance_to_road_edge(x, y, bottom, length, width, cos_h, sin_h, valid, table, counts)
    valid_segments = np.flatnonzero(table.valid)
    segment = valid_segments[np.arange(len(queries)) % len(valid_segments)]  # any segment costs the same
    floor, _ = median_time(lambda: _one_selection_each(queries, segment, table.start, table.delta), repeat)
    return {"queries": len(queries), "pairs evaluated": counts["pairs evaluated"], "floor seconds": floor}


def _nearest_object_counts(boxes: tuple, repeat: int) -> dict:
    """Queries (valid evaluated boxes), pairs evaluated exactly (counted), and the floor's seconds.

    boxes: the arguments the nearest-object search was called with (x, y, length, width, cos_h, sin_h,
    valid, num_evaluated), as `TimedSearch` kept them."""
    x, y, length, width, cos_h, sin_h, valid, num_evaluated = boxes
    counts = {}
    interaction.distance_to_nearest_object(x, y, length, width, cos_h, sin_h, valid, num_evaluated, counts)
    num_objects, num_steps = x.shape[-2:]
    radius = interaction.corner_radius(length, width)
    boxes = np.stack(
        [x, y, length - 2 * radius, width - 2 * radius, cos_h, sin_h, radius], axis=-1, dtype=np.float32
    ).reshape(-1, 7)
    box = np.arange(x.size).reshape(x.shape)
    mine = box[..., :num_evaluated, :][np.asarray(valid)[..., :num_evaluated, :]]
    # One partner per query: the same box one object further on (any box costs the same arithmetic).
    partner = (mine + num_steps) % x.size
    floor, _ = median_time(lambda: _one_box_distance_each(boxes, mine, partner), repeat)
    all_pairs = int(np.asarray(valid)[..., :num_evaluated, :].sum()) * (num_objects - 1)
    return {
        "queries": len(mine),
        "all pairs": all_pairs,
        "pairs evaluated": counts["pairs evaluated"],
        "floor seconds": floor,
    }


def score_bytes(raw_scenario: bytes, raw_rollouts: bytes, config, challenge: str) -> dict:
    """One scenario scored end to end as a scoring worker does: the scenario's arrays from its record's bytes, the
    rollouts parsed and their arrays read from the same bytes."""
    rollouts = sim_agents_submission_pb2.ScenarioRollouts.FromString(raw_rollouts)
    return score_scenario(
        record_arrays(raw_scenario), rollout_arrays(rollouts, challenge, raw_rollouts), config,
        challenge=challenge,
    )  # fmt: skip


def stage_breakdown(raw_scenario: bytes, raw_rollouts: bytes, config, challenge: str, repeat: int) -> dict:
    """Median seconds of each stage and end to end, operation counts and floors (see the module doc)."""
    parse = lambda: sim_agents_submission_pb2.ScenarioRollouts.FromString(raw_rollouts)

    end_to_end, metrics = median_time(lambda: score_bytes(raw_scenario, raw_rollouts, config, challenge), repeat)
    stages = {}
    stages["scenario arrays"], arrays = median_time(lambda: record_arrays(raw_scenario), repeat)
    stages["parse rollouts"], rollouts = median_time(parse, repeat)
    stages["rollout arrays"], rollout = median_time(lambda: rollout_arrays(rollouts, challenge, raw_rollouts), repeat)
    stages["samples"], batch = median_time(lambda: sample_batch(arrays, rollout, challenge), repeat)
    stages["map index"], context = median_time(lambda: mf.map_context(arrays), repeat)
    layout = mf.feature_layout(batch.spec, batch.num_evaluated)
    trajectories = mf.trajectory_arrays(batch)
    tails = mf.official_tails(
        batch.trajectories.num_objects, batch.num_evaluated, batch.trajectories.num_steps, layout.first_step
    )
    search = PrunedSearch(
        context.road_edges, context.lanes, mf.signals_from(arrays.signals, layout.first_red_light_step)
    )
    runs = []
    for _ in range(repeat + 1):
        seconds = {}
        timed = TimedSearch(search, seconds)
        start = time.perf_counter()
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            per_step = mf.per_step_features(trajectories, layout, timed, tails)
        seconds["features"] = time.perf_counter() - start
        runs.append(seconds)
    runs = runs[1:]  # the first is the warm-up
    feature_seconds = {name: statistics.median(r[name] for r in runs) for name in runs[0]}
    for name in SEARCHES:
        stages[f"features: {name.replace('_', ' ')}"] = feature_seconds[name]
    stages["features: the rest"] = feature_seconds["features"] - sum(feature_seconds[n] for n in SEARCHES)
    log, sim = mf.metric_features(batch, per_step)
    stages["estimators and metrics"], _ = median_time(lambda: scenario_metrics(config, log, sim), repeat)
    counts = {
        "road edge": {
            **_road_edge_counts(context.road_edges, timed.arguments["road_edge_distance"], repeat),
            "seconds": feature_seconds["road_edge_distance"],
        },
        "nearest object": {
            **_nearest_object_counts(timed.arguments["nearest_object"], repeat),
            "seconds": feature_seconds["nearest_object"],
        },
    }
    return {
        "scenario": arrays.scenario_id,
        "objects": int(batch.trajectories.num_objects),
        "evaluated": int(batch.num_evaluated),
        "segments": int(context.road_edges.valid.sum()),
        "seconds": end_to_end,
        "metametric": float(metrics["metametric"]),
        "stages": stages,
        "counts": counts,
    }


def print_breakdown(r: dict) -> None:
    """The figures of `stage_breakdown`, as the benchmarks print them."""
    print(f"    {'stage':36s} {'median s':>9s}")
    for stage, seconds in r["stages"].items():
        print(f"    {stage:36s} {seconds:9.4f}")
    print("    searches: operation counts and share of the arithmetic floor (one exact evaluation per query)")
    for name, c in r["counts"].items():
        extra = f", of {c['all pairs']:,} pairs in all" if "all pairs" in c else ""
        print(
            f"      {name}: {c['queries']:,} queries, {c['pairs evaluated']:,} pairs evaluated exactly "
            f"({c['pairs evaluated'] / max(c['queries'], 1):.1f} per query{extra}); "
            f"floor {c['floor seconds']:.4f} s of {c['seconds']:.4f} s = {c['floor seconds'] / c['seconds']:.0%}"
        )
