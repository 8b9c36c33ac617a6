"""Any array in: torch tensors, JAX arrays, and anything implementing `__array__` (as TensorFlow's tensors do) or
`__dlpack__` give the compat functions the same bits as numpy arrays. JAX arrays come back as JAX arrays from
the trajectory features (the same kernel under JAX); every other result is numpy.

Torch is not a dependency (a CUDA build is gigabytes): its tests skip without it, naming why; CI installs the CPU
wheel (`pip install torch==2.13.0`).
"""

from __future__ import annotations

import numpy as np
import pytest

from support.paths import TEST_DATA
from wosac_eval.compat import (
    estimators,
    interaction_features,
    map_metric_features,
    traffic_light_features,
    trajectory_features,
)
from wosac_eval.protos import map_pb2, sim_agents_metrics_pb2

DATA = np.load(TEST_DATA / "oracle_compat" / "feature_functions.npz")
IN = {k[3:]: DATA[k] for k in DATA.files if k.startswith("in/")}
BOX_FIELDS = ("center_x", "center_y", "center_z", "length", "width", "height", "heading")
_Config = sim_agents_metrics_pb2.SimAgentMetricsConfig
HISTOGRAM = _Config.HistogramEstimate(min_val=-2, max_val=3, num_bins=7, additive_smoothing_pseudocount=0.1)


def _polylines(name: str) -> list:
    points, lengths = IN[f"{name}/points"], IN[f"{name}/lengths"]
    ends = np.cumsum(lengths)
    return [[map_pb2.MapPoint(x=x, y=y, z=z) for x, y, z in points[end - n : end]] for n, end in zip(lengths, ends)]


def _signals() -> list:
    signals: list[list] = [[] for _ in range(IN["red/x"].shape[1])]
    for t, lane, state, sx, sy in IN["signals"]:
        point = map_pb2.MapPoint(x=sx, y=sy)
        signals[int(t)].append(map_pb2.TrafficSignalLaneState(lane=int(lane), state=int(state), stop_point=point))
    return signals


def every_function(convert) -> dict:
    """Each compat function called with its arrays converted by `convert`: name -> result(s)."""
    c = convert
    series, heading, valid = IN["traj/series"], IN["traj/heading"], IN["traj/valid"]
    boxes = {name: c(IN[f"boxes/{name}"]) for name in BOX_FIELDS}
    fields = ("center_x", "center_y", "length", "width", "heading")
    following = {name: c(IN[f"following/{name}"]) for name in fields}
    road = {name: c(IN[f"road/{name}"]) for name in BOX_FIELDS}
    mask = c(IN["boxes/mask"])
    log, sim = IN["est/log"], IN["est/sim"]
    feature = _Config.FeatureConfig(histogram=HISTOGRAM, independent_timesteps=True)
    return {
        "central_diff": trajectory_features.central_diff(c(series[0]), pad_value=0.5),
        "central_logical_and": trajectory_features.central_logical_and(c(valid), pad_value=True),
        "displacement": trajectory_features.compute_displacement_error(*map(c, series), *map(c, series[::-1])),
        "kinematics": trajectory_features.compute_kinematic_features(*map(c, series), c(heading), 0.1),
        "validity": trajectory_features.compute_kinematic_validity(c(valid)),
        "nearest": interaction_features.compute_distance_to_nearest_object(
            **boxes, valid=c(IN["boxes/valid"]), evaluated_object_mask=mask
        ),
        "ttc": interaction_features.compute_time_to_collision_with_object_in_front(
            **following, valid=c(IN["boxes/valid"]), evaluated_object_mask=mask, seconds_per_step=0.1
        ),
        "road": map_metric_features.compute_distance_to_road_edge(
            **road, valid=c(IN["road/valid"]), evaluated_object_mask=mask, road_edge_polylines=_polylines("road_edges")
        ),
        "red": traffic_light_features.compute_red_light_violation(
            center_x=c(IN["red/x"]),
            center_y=c(IN["red/y"]),
            valid=c(IN["red/valid"]),
            evaluated_object_mask=mask,
            lane_polylines=_polylines("lanes"),
            lane_ids=IN["lanes/ids"].tolist(),
            traffic_signals=_signals(),
        ),
        "histogram": estimators.histogram_estimate(HISTOGRAM, c(log), c(sim)),
        "bernoulli": estimators.bernoulli_estimate(_Config.BernoulliEstimate(), c(log > 0), c(sim > 0)),
        "timeseries": estimators.log_likelihood_estimate_timeseries(
            feature, c(IN["est/series_log"]), c(IN["est/series_sim"])
        ),
    }


def _flat(results: dict) -> dict:
    out = {}
    for name, value in results.items():
        for k, v in enumerate(value if isinstance(value, tuple) else (value,)):
            out[f"{name}/{k}"] = v
    return out


EXPECTED = _flat(every_function(lambda a: a))


def assert_same_bits(results: dict, jax_out: tuple = ()) -> None:
    results = _flat(results)
    assert results.keys() == EXPECTED.keys()
    for name, value in results.items():
        if name.split("/")[0] in jax_out:
            import jax  # the caller's JAX: only reached under the jax marker

            assert isinstance(value, jax.Array), name
        else:
            assert isinstance(value, np.ndarray), name
        got = np.asarray(value)
        assert got.dtype == EXPECTED[name].dtype, name
        np.testing.assert_array_equal(got, EXPECTED[name], err_msg=name)


class ArrayOnly:
    """An array known only by `__array__`, as TensorFlow's eager tensors and many array types expose theirs."""

    def __init__(self, value):
        self.value = np.asarray(value)

    def __array__(self, dtype=None, copy=None):
        return self.value if dtype is None else self.value.astype(dtype)


class DLPackOnly:
    """An array known only by the DLPack protocol (`__dlpack__`, `__dlpack_device__`), on the CPU."""

    def __init__(self, value):
        self.value = np.ascontiguousarray(value)

    def __dlpack__(self, **kwargs):
        return self.value.__dlpack__(**kwargs)

    def __dlpack_device__(self):
        return self.value.__dlpack_device__()


class OnADevice(DLPackOnly):
    """A device array as GPU array libraries export theirs (no `__array__`): the DLPack producer's side, which
    copies to the CPU when asked for `dl_device=(kDLCPU, 0)` (torch's CUDA tensors do; this host has no GPU)."""

    asked: list = []

    def __dlpack_device__(self):
        return (2, 0)  # kDLCUDA, device 0

    def __dlpack__(self, *, dl_device=None, copy=None, **kwargs):
        OnADevice.asked.append(dl_device)
        if dl_device != (1, 0):
            raise BufferError("a CUDA array can be exported to the CPU only as a copy")
        return np.array(self.value, copy=True).__dlpack__(**kwargs)


@pytest.mark.parametrize("kind", [ArrayOnly, DLPackOnly, OnADevice, list])
def test_any_array_protocol_gives_the_numpy_bits(kind):
    convert = (lambda a: np.asarray(a).tolist()) if kind is list else kind
    assert_same_bits(every_function(convert))
    if kind is OnADevice:
        assert set(OnADevice.asked) == {(1, 0)}  # every array was asked for on the CPU


def test_torch_cpu_tensors_give_the_numpy_bits():
    torch = pytest.importorskip("torch", reason="torch is not installed (an optional extra of the tests: CI's venv)")
    assert_same_bits(every_function(torch.from_numpy))


def test_a_tensor_that_requires_grad_is_refused_by_name():
    torch = pytest.importorskip("torch", reason="torch is not installed (an optional extra of the tests: CI's venv)")
    x = torch.zeros(3, 5, requires_grad=True)
    with pytest.raises(ValueError, match=r"x: cannot read a Tensor as an array .*detach"):
        trajectory_features.compute_kinematic_features(x, x, x, x, seconds_per_step=0.1)


@pytest.mark.jax
@pytest.mark.slow  # JAX compiles each kernel's operations: about 30 s on empty caches
def test_jax_arrays_give_the_numpy_bits():
    jnp = pytest.importorskip("jax.numpy", reason="JAX is not installed (the jax extra)")
    trajectory = ("central_diff", "central_logical_and", "displacement", "kinematics", "validity")
    assert_same_bits(every_function(jnp.asarray), jax_out=trajectory)
