"""The compiled twins of the kernels (`features.compiled`) equal numpy's results bit for bit.

Each kernel runs vectorised on numpy arrays and, flattened and compiled by numba, value by value;
both must give the same float32 bits on ordinary values and on the ones that test the rules of the
scalar operations: both zeros, NaN, infinities, ties, zero-length segments and boxes.
"""

import numpy as np
import pytest

from wosac_eval.features import (
    box_geometry,
    compiled,
    float32_math,
    following,
    interaction,
    ops,
    road_edge,
    traffic_lights,
)
from wosac_eval.features.road_edge import cell_lists, cell_tables, pruned_search, segments, signed_distance
from wosac_eval.parse import wire_walks as walks
from wosac_eval.analysis import criticality_features
from wosac_eval.scoring import warm_up

F = np.float32


def special_floats(rng, n, scale):
    """`n` float32 values: random ones, then zeros of both signs, NaN, infinities and repeats."""
    v = (rng.standard_normal(n) * scale).astype(F)
    special = np.array([0.0, -0.0, np.nan, np.inf, -np.inf, 1.0, -1.0, 1e-30, 3e38], F)
    v[rng.integers(0, n, n // 8)] = rng.choice(special, n // 8)
    return v


def same_bits(a, b):
    a, b = np.asarray(a), np.asarray(b)
    if a.dtype == bool or b.dtype == bool:
        return np.array_equal(a.astype(bool), b.astype(bool))
    both_nan = np.isnan(a.astype(np.float64)) & np.isnan(b.astype(np.float64))
    return bool(np.all((a.astype(b.dtype) == b) & (np.signbit(a) == np.signbit(b)) | both_nan))


def value_by_value(kernel, arguments):
    """The compiled kernel called on each element (from Python: slow, but these are small)."""
    scalar = compiled.compiled(kernel)
    results = [scalar(*(a[i] for a in arguments)) for i in range(len(arguments[0]))]
    if isinstance(results[0], tuple):
        return [np.array([r[k] for r in results]) for k in range(len(results[0]))]
    return [np.array(results)]


KERNELS = {
    "segment_distances": (road_edge.segment_distances, 9, 20.0),
    "side_of_segment": (road_edge.side_of_segment, 6, 20.0),
    "frame_offsets": (following.frame_offsets, 10, 10.0),
    "capped_time_to_collision": (following.capped_time_to_collision, 2, 5.0),
    "packet_sincos": (float32_math.packet_sincos, 1, 4.0),
    "box_pair_distance": (interaction.box_pair_distance, 14, 5.0),
}


@pytest.mark.parametrize("name", sorted(KERNELS))
@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_compiled_kernel_equals_numpy_bit_for_bit(name):
    kernel, arity, scale = KERNELS[name]
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    arguments = [special_floats(rng, 600, scale) for _ in range(arity)]
    if name == "box_pair_distance":  # boxes: sizes mostly positive, cos/sin of one heading, radii
        for side in (0, 7):
            for k in (2, 3):
                arguments[side + k] = np.abs(arguments[side + k])
            heading = rng.uniform(-np.pi, np.pi, 600)
            arguments[side + 4], arguments[side + 5] = np.cos(heading).astype(F), np.sin(heading).astype(F)
            arguments[side + 6] = np.abs(arguments[side + 6]) * F(0.1)
            arguments[side + 1][:40] = arguments[side][:40]  # equal coordinates
    with np.errstate(all="ignore"):
        expected = kernel(*arguments)
    expected = list(expected) if isinstance(expected, tuple) else [expected]
    got = value_by_value(kernel, arguments)
    for k, (e, g) in enumerate(zip(expected, got)):
        assert same_bits(g, e), f"{name} result {k}: {np.flatnonzero(~((g == e) | (np.isnan(g) & np.isnan(e))))[:5]}"


def test_following_gap_and_corner_sign_with_booleans():
    rng = np.random.default_rng(3)
    n = 400
    floats = [special_floats(rng, n, 5.0) for _ in range(7)]
    with np.errstate(all="ignore"):
        expected = following.following_gap(*floats)
    got = value_by_value(following.following_gap, floats)
    assert same_bits(got[0], expected[0]) and same_bits(got[1], expected[1])
    signs = [rng.choice(np.array([-1, 0, 1, np.nan], F), n) for _ in range(3)]
    flags = [rng.random(n) < 0.5 for _ in range(4)]
    arguments = [special_floats(rng, n, 1.0), *signs, *flags]
    got = value_by_value(road_edge.corner_sign, arguments)
    assert same_bits(got[0], road_edge.corner_sign(*arguments))


def test_every_ops_function_has_a_scalar_form():
    public = {
        name
        for name in dir(ops)
        if not name.startswith("_")
        and callable(getattr(ops, name))
        and getattr(getattr(ops, name), "__module__", "") == ops.__name__
    }
    assert public <= set(compiled.SCALAR_OPS)


def test_flat_source_inlines_every_kernel_and_operation():
    source, _ = compiled.flat_source(interaction.rounded_box_distance)
    assert "ops." not in source
    for helper in ("box_outline", "minkowski_vertices", "octagon_signed_distance", "_edge_to_origin"):
        assert f"{helper}(" not in source
    assert box_geometry.octagon_signed_distance.__name__ in dir(box_geometry)


def test_cached_loops_are_named_after_the_kernels_digest():
    digest = compiled.KERNELS_DIGEST[:16]
    # Also the loops that call numba functions of another file (numba's cache checks the loop's file only).
    for loop in (
        pruned_search._search_lists,
        cell_lists.query_cells,
        cell_tables._cell_table,
        interaction._nearest_object_search,
        following._followed_search,
        traffic_lights._crossings,
    ):
        assert loop.py_func.__qualname__.endswith(f"__kernels_{digest}")


def test_compile_loops_covers_what_scoring_calls():
    """After `scoring.warm_up.compile_loops`, scoring and validating a scene compile nothing more (the same
    argument types)."""
    from wosac_eval.metrics.config import load_config
    from wosac_eval.scoring.scenario import score_scenario
    from wosac_eval.sim import scenes
    from wosac_eval.arrays.messages import rollouts_bytes
    from wosac_eval.arrays.rollouts import rollout_arrays
    from wosac_eval.protos.sim_agents_submission_pb2 import ScenarioRollouts
    from wosac_eval.sim.baselines import policy_rollouts
    from wosac_eval.validate.rules import check_scenario_rollouts

    warm_up.compile_loops()
    loops = [
        cell_lists.query_cells,
        cell_lists.cell_lists,
        pruned_search._search_lists,
        pruned_search._ring_searches,
        signed_distance._signed_distances,
        segments._bucket_lists,
        interaction._nearest_object_search,
        following._followed_search,
        traffic_lights._crossings,
        walks._message_spans,
        walks._scalar_fields,
        walks._float_fields,
        walks._rollouts_census,
        criticality_features._pair_entries,
    ]
    before = {loop: len(loop.signatures) for loop in loops}
    scenario = scenes.generate_scenes(1, seed=2)[0]
    for challenge, config in (("sim_agents", "2025"), ("scenario_gen", "scenario_gen_2025")):
        rollouts = policy_rollouts(scenario, "constant_velocity", challenge=challenge)
        score_scenario(scenario, rollouts, load_config(config), challenge=challenge, analysis=True)
        raw = rollouts_bytes(rollouts)
        message = ScenarioRollouts.FromString(raw)
        rollout_arrays(message, challenge, raw)
        check_scenario_rollouts(message, None, challenge=challenge)
    assert {loop: len(loop.signatures) for loop in loops} == before
