"""Signed distance from box corners to the road edge; offroad.

Five modules, used in this order:
- `segments`: the segment table of a scenario's road edges (official order, neighbours, the planar
  bucket grid) and the float32 kernels of the signed distance, shared by numpy, JAX and numba;
- `pruned_search`: the compiled search of the numpy path for the nearest segment (`nearest_segments`),
  exact by proven bounds, over the candidate lists of the cells where queries fall (`cell_lists`);
- `signed_distance`: the signed distance of points and of box corners from those segments
  (`signed_distance_to_polylines`, `box_distance_to_road_edge`);
- `cell_tables`: per-cell candidate lists with a clearance, for the fixed-shape search on a device
  (`features.dense`).
Their public names are importable from here.
"""

from wosac_eval.features.road_edge.cell_tables import (
    CELL_CANDIDATES,
    CELL_NEAR_CANDIDATES,
    CELL_SIDE,
    cell_candidate_table,
    unsettling_cell_table,
)
from wosac_eval.features.road_edge.pruned_search import nearest_segments
from wosac_eval.features.road_edge.segments import (
    BUCKET_SIDE,
    CYCLIC_TOLERANCE_M2,
    EXTREMELY_LARGE_DISTANCE,
    OFFROAD_DISTANCE_THRESHOLD,
    Z_STRETCH,
    SegmentTable,
    build_segment_table,
    corner_sign,
    segment_distances,
    segment_side,
    side_of_segment,
)
from wosac_eval.features.road_edge.signed_distance import box_distance_to_road_edge, signed_distance_to_polylines

__all__ = [
    "BUCKET_SIDE",
    "CELL_CANDIDATES",
    "CELL_NEAR_CANDIDATES",
    "CELL_SIDE",
    "CYCLIC_TOLERANCE_M2",
    "EXTREMELY_LARGE_DISTANCE",
    "OFFROAD_DISTANCE_THRESHOLD",
    "Z_STRETCH",
    "SegmentTable",
    "box_distance_to_road_edge",
    "build_segment_table",
    "cell_candidate_table",
    "corner_sign",
    "nearest_segments",
    "segment_distances",
    "segment_side",
    "side_of_segment",
    "signed_distance_to_polylines",
    "unsettling_cell_table",
]
