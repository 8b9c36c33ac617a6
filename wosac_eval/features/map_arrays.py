"""The unpadded map arrays of one scene for the dense searches (`features.dense.DenseSearch`), numpy.

Each builder is a `registry.MapPart`'s (`registry.scene_map_arrays` runs those the features need): it
takes (scenario, `metric_features.MapContext`, `metric_features.FeatureLayout`, number of steps, whether
the road-edge cell table is wanted) and returns arrays by name; `registry.MapPart.arrays` says how each
is padded.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wosac_eval.arrays.scenario import ScenarioArrays, TrafficSignals
from wosac_eval.features import road_edge, traffic_lights
from wosac_eval.features.spatial import NON_FINITE_PREFIX, non_finite_pick

# The map context and the layout are `metric_features`' `MapContext` and `FeatureLayout` (Any below):
# `metric_features` imports this module, and an import back would close a circle.

_F = np.float32


def segment_table_arrays(table: road_edge.SegmentTable, cells: bool = True) -> dict:
    """Both road-edge parts of a segment table: `road_edge_segments` and `road_edge_cells`."""
    return {**_segments(table), **_cells(table, cells)}


def road_edge_segments(scenario: ScenarioArrays, context: Any, layout: Any, num_steps: int, cells: bool) -> dict:
    return _segments(context.road_edges)


def _segments(table: road_edge.SegmentTable) -> dict:
    """The valid road-edge segments, in official order, with their neighbours' geometry, and the
    official pick for points with a NaN or infinite coordinate (which may be a padding segment)."""
    fallback = segments_at(table, np.array([non_finite_pick(table.valid)]))
    return {
        **segments_at(table, np.flatnonzero(table.valid)),
        **{NON_FINITE_PREFIX + k: v for k, v in fallback.items()},
    }


def road_edge_cells(scenario: ScenarioArrays, context: Any, layout: Any, num_steps: int, cells: bool) -> dict:
    return _cells(context.road_edges, cells)


def _cells(table: road_edge.SegmentTable, cells: bool) -> dict:
    """The cell table of the valid road-edge segments (`cells`; else a one-cell table that settles
    nothing, for a scene the device never searches)."""
    idx = np.flatnonzero(table.valid)
    out = (
        road_edge.cell_candidate_table(table.start[idx], table.delta[idx])
        if cells
        else road_edge.unsettling_cell_table()
    )
    return {f"cell_{k}": v for k, v in out.items()}


def segments_at(table: road_edge.SegmentTable, idx: np.ndarray) -> dict:
    """Segments `idx` of the table with their neighbours' geometry, `(len(idx), ...)`."""
    prior, nxt = table.prior[idx], table.next[idx]
    return {
        "start": table.start[idx],
        "delta": table.delta[idx],
        "prior_start": table.start[prior],
        "prior_delta": table.delta[prior],
        "next_start": table.start[nxt],
        "next_delta": table.delta[nxt],
        "valid": table.valid[idx],
        "prior_valid": table.prior_valid[idx],
        "next_valid": table.next_valid[idx],
        "convex_before": table.convex_before[idx],
        "convex_after": table.convex_after[idx],
    }


def red_light_arrays(scenario: ScenarioArrays, context: Any, layout: Any, num_steps: int, cells: bool) -> dict:
    """Stop lines `(num_steps, num_signals, ...)` of the signals that can be violated, from the first
    red-light step on, and the lane segments."""
    signals = traffic_lights.signals_from(scenario.signals, layout.first_red_light_step)
    return stop_line_arrays(signals, context.lanes, num_steps - layout.first_red_light_step)


def stop_line_arrays(signals: TrafficSignals | None, lanes: traffic_lights.LaneTable | None, num_steps: int) -> dict:
    """Stop lines `(num_steps, num_signals, ...)` of the signals that can be violated, and the lane segments."""
    none = {
        "stop_start": np.zeros((num_steps, 0, 2), _F),
        "stop_delta": np.zeros((num_steps, 0, 2), _F),
        "stop_point": np.zeros((num_steps, 0, 2), _F),
        "stopping": np.zeros((num_steps, 0), bool),
        "signal_lane_id": np.zeros(0, np.int32),
        "lane_start": np.zeros((0, 2), _F),
        "lane_delta": np.zeros((0, 2), _F),
        "lane_valid": np.zeros(0, bool),
        "lane_id": np.zeros(0, np.int32),
    }
    if lanes is None or signals is None:
        return none
    if signals.state.shape[0] != num_steps:
        raise ValueError(
            f"the scenario has {signals.state.shape[0]} dynamic map states, expected one per step ({num_steps})"
        )
    start, delta, lane_known = traffic_lights.stop_point_segments(lanes, signals)
    seg = np.flatnonzero(lanes.valid)
    # The device only compares lane ids: their ranks among the scene's ids fit int32 (x64 off).
    signal_lane, segment_lane = np.split(
        np.unique(np.concatenate([signals.lane_id, lanes.lane_ids[seg // lanes.num_segments]]), return_inverse=True)[
            1
        ].astype(np.int32),
        [len(signals.lane_id)],
    )
    return {
        "stop_start": start.astype(_F),
        "stop_delta": delta.astype(_F),
        "stop_point": signals.stop_point.astype(_F),
        "stopping": np.isin(signals.state, traffic_lights.LANE_STATE_STOP_VALUES) & lane_known,
        "signal_lane_id": signal_lane,
        "lane_start": lanes.start[seg],
        "lane_delta": lanes.delta[seg],
        "lane_valid": np.ones(len(seg), bool),
        "lane_id": segment_lane,
    }
