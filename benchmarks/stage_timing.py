"""One scenario's scoring timed stage by stage, with each search's operation count and share of its floor.

Shared by `score_speed.py` (Sim Agents) and `scenario_gen_speed.py` (Scenario Generation).

The stages are the pipeline's (parse, arrays, samples, map index, the four searches of the
features, the rest of the features, estimators and metrics); the end-to-end figure is
`score_scenario` itself (protobuf bytes in, metrics out), timed apart.

For the two searches that look for a nearest thing, the floor is the arithmetic alone: one exact
float32 evaluation per query (a box corner against one road-edge segment; an evaluated box
against one other box), with no search at all. `share of floor` is that time over the stage's
time: 100% would mean the search costs nothing beyond computing the answer once.
"""
from __future__ import annotations

import statistics
import time

import numpy as np

from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.samples import sample_batch
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.features import interaction, metric_features as mf, road_edge
from wosac_eval.features.search import PrunedSearch
from wosac_eval.metrics.scenario_metrics import scenario_metrics
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2
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


def _median_time(fn, repeat: int):
    fn()
    runs = []
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        runs.append(time.perf_counter() - start)
    return statistics.median(runs), out


def _road_edge_counts(table: road_edge.SegmentTable, corners, valid, repeat: int) -> dict:
    """Queries (valid box corners), pairs the search evaluates exactly, and the floor's seconds."""
    keep = np.broadcast_to(valid, corners.shape[:-2]).reshape(-1)
    queries = np.asarray(corners, np.float32).reshape(-1, 4, 3)[keep].reshape(-1, 3)
    queries = queries[np.isfinite(queries).all(axis=1)]
    qi, si, _ = road_edge._candidates(table, queries)
    columns = np.ascontiguousarray(queries.T)
    one_each = np.arange(len(queries))
    segment = np.flatnonzero(table.valid)[one_each % int(table.valid.sum())]
    floor, _ = _median_time(lambda: road_edge._selection_distances(table, columns, one_each, segment), repeat)
    return {"queries": len(queries), "pairs evaluated": len(qi), "floor seconds": floor}


def _nearest_object_counts(x, y, length, width, cos_h, sin_h, valid, num_evaluated: int, repeat: int) -> dict:
    """Queries (valid evaluated boxes), pairs evaluated exactly (counted), and the floor's seconds."""
    evaluated = {"pairs": 0}
    pair_distance = interaction._pair_distance

    def counting(outlines, radius, eval_idx, other_idx):
        evaluated["pairs"] += len(eval_idx)
        return pair_distance(outlines, radius, eval_idx, other_idx)

    interaction._pair_distance = counting
    try:
        interaction.distance_to_nearest_object(x, y, length, width, cos_h, sin_h, valid, num_evaluated)
    finally:
        interaction._pair_distance = pair_distance
    num_objects, num_steps = x.shape[-2:]
    box = np.arange(x.size).reshape(x.shape)
    mine = box[..., :num_evaluated, :][np.asarray(valid)[..., :num_evaluated, :]]
    # One partner per query: the same box one object further on (any box costs the same arithmetic).
    other = (mine + num_steps) % x.size
    radius = interaction.corner_radius(length, width).reshape(-1)
    flat = lambda a: np.ascontiguousarray(a).reshape(-1)

    def floor():
        outlines = interaction._Outlines(flat(x), flat(y), flat(length) - 2 * radius, flat(width) - 2 * radius,
                                         flat(cos_h), flat(sin_h))  # outlines of the pairs' boxes only
        return interaction._pair_distance(outlines, radius, mine, other)

    seconds, _ = _median_time(floor, repeat)
    all_pairs = int(np.asarray(valid)[..., :num_evaluated, :].sum()) * (num_objects - 1)
    return {"queries": len(mine), "all pairs": all_pairs, "pairs evaluated": evaluated["pairs"],
            "floor seconds": seconds}


def stage_breakdown(raw_scenario: bytes, raw_rollouts: bytes, config, challenge: str, repeat: int) -> dict:
    """Median seconds of each stage and end to end, operation counts and floors (see the module doc)."""
    parse = lambda: (scenario_pb2.Scenario.FromString(raw_scenario),
                     sim_agents_submission_pb2.ScenarioRollouts.FromString(raw_rollouts))
    end_to_end, metrics = _median_time(lambda: score_scenario(*parse(), config, challenge=challenge), repeat)
    stages = {}
    stages["parse protobufs"], (scenario, rollouts) = _median_time(parse, repeat)
    stages["scenario arrays"], arrays = _median_time(lambda: scenario_arrays(scenario), repeat)
    stages["rollout arrays"], rollout = _median_time(lambda: rollout_arrays(rollouts, challenge), repeat)
    stages["samples"], batch = _median_time(lambda: sample_batch(arrays, rollout, challenge), repeat)
    stages["map index"], context = _median_time(lambda: mf.map_context(arrays), repeat)
    layout = mf.feature_layout(batch.spec, batch.num_evaluated)
    trajectories = mf.trajectory_arrays(batch)
    tails = mf.official_tails(batch.trajectories.num_objects, batch.num_evaluated,
                              batch.trajectories.num_steps, layout.first_step)
    search = PrunedSearch(context.road_edges, context.lanes, mf.signals_from(arrays.signals,
                                                                             layout.first_red_light_step))
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
    stages["estimators and metrics"], _ = _median_time(lambda: scenario_metrics(config, log, sim), repeat)
    corners, valid = timed.arguments["road_edge_distance"]
    counts = {
        "road edge": {**_road_edge_counts(context.road_edges, corners, valid, repeat),
                      "seconds": feature_seconds["road_edge_distance"]},
        "nearest object": {**_nearest_object_counts(*timed.arguments["nearest_object"], repeat),
                           "seconds": feature_seconds["nearest_object"]},
    }
    return {"scenario": arrays.scenario_id, "objects": int(batch.trajectories.num_objects),
            "evaluated": int(batch.num_evaluated), "segments": int(context.road_edges.valid.sum()),
            "seconds": end_to_end, "metametric": float(metrics["metametric"]), "stages": stages, "counts": counts}


def print_breakdown(r: dict) -> None:
    """The figures of `stage_breakdown`, as the benchmarks print them."""
    print(f"    {'stage':36s} {'median s':>9s}")
    for stage, seconds in r["stages"].items():
        print(f"    {stage:36s} {seconds:9.4f}")
    print("    searches: operation counts and share of the arithmetic floor (one exact evaluation per query)")
    for name, c in r["counts"].items():
        extra = f", of {c['all pairs']:,} pairs in all" if "all pairs" in c else ""
        print(f"      {name}: {c['queries']:,} queries, {c['pairs evaluated']:,} pairs evaluated exactly "
              f"({c['pairs evaluated'] / max(c['queries'], 1):.1f} per query{extra}); "
              f"floor {c['floor seconds']:.4f} s of {c['seconds']:.4f} s = {c['floor seconds'] / c['seconds']:.0%}")
