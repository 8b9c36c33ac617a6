"""`wosac_eval.jax_realism`: realism on device arrays equals the file path, under jit and vmap, padding or not.

Both precisions: "float32" (x64 off, JAX's default: what a training loop runs
with) and "exact" (x64 on while tracing). Every metric of both agrees with the
official outputs within 1e-5; in exact mode on CPU the per-step features and
every metric are bit-identical to the numpy path (hence to the official ones). The test process
opts in to exact float32 on XLA's CPU (tests/conftest.py sets XLA_FLAGS).

Both searches: most tests prepare with search="device" (the fixed-shape
kernels an accelerator runs, which on a CPU only tests exercise); the host
search (the default on a CPU: the numpy path's pruned search called back from
the trace) has its own tests and golden run below.
"""

from __future__ import annotations

from functools import lru_cache

import contextlib
import os
import re
import subprocess
import sys
import warnings

import numpy as np
import pytest

from wosac_eval import jax_realism

# About 10 minutes on 2 cores, most of it XLA compiling: the full run's, not the fast tier's.
pytestmark = pytest.mark.slow

import jax  # noqa: E402
from jax import lax  # noqa: E402

from support import golden, tiling  # noqa: E402
from wosac_eval.arrays.scenario import scenario_arrays  # noqa: E402
from wosac_eval.features.metric_features import PER_STEP_FIELDS, scenario_features  # noqa: E402
from wosac_eval.features.registry import MAP_PARTS  # noqa: E402
from wosac_eval.metrics.registry import LIKELIHOOD_FIELDS  # noqa: E402
from wosac_eval.metrics.scenario_metrics import SCENARIO_FIELDS  # noqa: E402
from wosac_eval.scoring.scenario import score_scenario, score_scenario_per_object  # noqa: E402
from wosac_eval.sim import scenes  # noqa: E402
from wosac_eval.sim.baselines import policy_rollouts  # noqa: E402

METRIC_TOLERANCE = 1e-5  # the official outputs' tolerance (float32 mode); measured here: 2e-6. Exact mode: the bits
MODES = ("exact", "float32")
# One mode per challenge where both are not the point (each pair a program of its own to compile): the
# same pairs in every test below, so that they share their programs (the exact sim-agents one, the
# float32 scenario-gen one, grouped or not).
CHALLENGE_MODES = [("sim_agents", "exact"), ("scenario_gen", "float32")]


def traced_as(mode: str):
    """The x64 state a caller traces `mode` in: on for exact, JAX's default (off) for float32."""
    return jax.enable_x64(True) if mode == "exact" else contextlib.nullcontext()


# One jitted step for every test: JAX compiles it once per scene set, rollout shapes and x64 state
# (its cache key), so tests that score the same scenes share the compilation.
_step = jax.jit(lambda prepared, a: jax_realism.realism(prepared, **a))
_step_per_object = jax.jit(lambda prepared, a: jax_realism.realism(prepared, **a, per_object=True))


def in_jit(mode: str, prepared, arrays: dict, per_object: bool = False):
    """`realism` as a training step calls it: inside the caller's own `jax.jit`, x64 as `mode` needs."""
    with traced_as(mode):
        out = (_step_per_object if per_object else _step)(prepared, arrays)
    assert out.mode == mode
    return as_numpy(out)


@lru_cache(maxsize=None)
def scene_set(challenge: str):
    """Three demo scenes of different sizes, their rollouts (IDM / scenario-gen log replay) and arrays."""
    scs = [scenes.generate_scene(0, k) for k in (1, 5, 8)]
    policy = "idm" if challenge == "sim_agents" else "log_replay_noise"
    rollouts = [policy_rollouts(sc, policy, challenge=challenge) for sc in scs]
    return scs, rollouts


@lru_cache(maxsize=None)
def prepared_set(challenge: str, padded: bool = False, grouped: bool = False, search: str = "device"):
    """The scene set prepared as one group (one compiled program: most tests), in groups by size
    (`grouped`: three here, put back in scene order), or padded wider (`padded`); the searches on
    the device (fixed shapes) unless `search` says "host"."""
    scs, rollouts = scene_set(challenge)
    floor = wider_than(prepared_set(challenge)[0]) if padded else None
    prepared = jax_realism.prepare(scs, challenge=challenge, min_sizes=floor, grouped=grouped, search=search)
    assert len(prepared.groups) == (3 if grouped else 1) and prepared.search == search
    return prepared, jax_realism.stack_rollouts(prepared, rollouts)


def padded_sizes(prepared) -> tuple[int, ...]:
    """The padded sizes of `prepared`'s one group, in `min_sizes` order: objects, evaluated objects, then
    the registry's map sizes (road-edge segments, signals, lane segments, road-edge grid cells)."""
    (arrays,) = prepared.arrays
    maps = arrays["maps"]
    map_sizes = (np.shape(maps[size.counted_by])[size.axis + 1] for part in MAP_PARTS for size in part.sizes)
    return (np.shape(arrays["real"])[1], np.shape(arrays["evaluated"])[1], *map_sizes)


def wider_than(prepared) -> tuple[int, ...]:
    """`min_sizes` past every padded size of `prepared`: padding rows in every dimension, each padding rule
    of the registry at work, and none very wide (on a CPU every padded row costs the program's work)."""
    return tuple(n + max(3, n // 8) for n in padded_sizes(prepared))


def as_numpy(tree):
    return jax.tree_util.tree_map(np.asarray, tree)


@pytest.mark.parametrize("challenge, mode", CHALLENGE_MODES)
def test_realism_equals_the_file_path(challenge, mode):
    """In float32 mode (a training loop's) the scenes come in three groups by size (`prepare`'s
    default), each scene's values put back in its place and equal to one group's within 1e-6. The grouped
    programs are the per-object ones (their scene fields are these): compiled once, for this test and
    test_per_object_values_equal_the_numpy_path."""
    scs, rollouts = scene_set(challenge)
    grouped = mode == "float32"
    got = in_jit(mode, *prepared_set(challenge, grouped=grouped), per_object=grouped)
    one_group = in_jit(mode, *prepared_set(challenge)) if grouped else got
    for s, (sc, ro) in enumerate(zip(scs, rollouts)):
        expected = score_scenario(sc, ro, challenge=challenge)
        for field in SCENARIO_FIELDS:
            assert abs(float(one_group[field][s]) - float(got[field][s])) <= 1e-6, (sc.scenario_id, field)
            assert got[field].shape == (3,)
            if mode == "exact":
                want = np.float32(expected[field])
                np.testing.assert_array_equal(np.float32(got[field][s]), want, f"{sc.scenario_id} {field}")
            else:
                assert abs(float(np.float32(got[field][s])) - expected[field]) <= METRIC_TOLERANCE, (
                    sc.scenario_id,
                    field,
                )


@pytest.mark.parametrize("search", ["device", "host"])
@pytest.mark.parametrize("challenge", ["sim_agents", "scenario_gen"])
def test_features_are_bit_identical_to_numpy(challenge, search):
    scs, rollouts = scene_set(challenge)
    prepared, arrays = prepared_set(challenge, search=search)
    with jax.enable_x64(True):
        feats = jax_realism.features(prepared, **arrays)
    for s, (sc, ro) in enumerate(zip(scs, rollouts)):
        log, sim = scenario_features(scenario_arrays(sc), ro, challenge=challenge)
        e = log.object_id.size
        for name in PER_STEP_FIELDS + ("average_displacement_error",):
            ours = np.asarray(getattr(feats, name))[s]
            np.testing.assert_array_equal(ours[:1, :e], getattr(log, name), err_msg=f"{sc.scenario_id} log {name}")
            np.testing.assert_array_equal(ours[1:, :e], getattr(sim, name), err_msg=f"{sc.scenario_id} sim {name}")
        np.testing.assert_array_equal(np.asarray(feats.valid)[s][1:, :e], sim.valid)


@pytest.mark.parametrize("challenge, mode", CHALLENGE_MODES)
def test_padding_never_changes_a_result(challenge, mode):
    """The means are summed in the official tensors' order whatever the padding (`eigen_sum32` with the
    real count), so in exact mode padding changes no bit; in float32 mode the device's own `log` and
    `exp` may round a value differently in a program of other shapes."""
    tight, arrays = prepared_set(challenge)
    wide, wide_arrays = prepared_set(challenge, padded=True)
    assert all(w > t for w, t in zip(padded_sizes(wide), padded_sizes(tight), strict=True))
    assert wide.layout.num_evaluated > tight.layout.num_evaluated
    a = in_jit(mode, tight, arrays)
    b = in_jit(mode, wide, wide_arrays)
    for field in SCENARIO_FIELDS:
        if mode == "exact":
            np.testing.assert_array_equal(a[field], b[field], err_msg=field)
        else:
            np.testing.assert_allclose(a[field], b[field], rtol=0, atol=1e-6, err_msg=field)


@pytest.mark.parametrize("challenge, mode", CHALLENGE_MODES)
def test_values_in_padding_columns_are_ignored(challenge, mode):
    tight, arrays = prepared_set(challenge)
    noisy = {k: v.copy() for k, v in arrays.items()}
    pad = tight.sim_agent_ids < 0
    for v in noisy.values():
        v[np.broadcast_to(pad[:, None, :, None], v.shape)] = 1e6
    a, c = in_jit(mode, tight, arrays), in_jit(mode, tight, noisy)
    for field in SCENARIO_FIELDS:
        np.testing.assert_array_equal(a[field], c[field], err_msg=field)


def numpy_per_object(prepared, challenge: str) -> dict:
    """The numpy path's per-object values of the scene set in `realism`'s columns: field -> (float32 values
    `(num_scenes, max_agents)`, NaN where no evaluated object; int32 counts, 0 there)."""
    scs, rollouts = scene_set(challenge)
    ids = prepared.sim_agent_ids
    out = {f: (np.full(ids.shape, np.nan, np.float32), np.zeros(ids.shape, np.int32)) for f in LIKELIHOOD_FIELDS}
    for s, (sc, ro) in enumerate(zip(scs, rollouts)):
        per_object = score_scenario_per_object(sc, ro, challenge=challenge)
        columns = [int(np.flatnonzero(ids[s] == object_id)[0]) for object_id in per_object.object_id]
        for field, (values, counts) in out.items():
            values[s, columns] = per_object.likelihood[field]
            counts[s, columns] = per_object.count[field]
    return out


@pytest.mark.parametrize(
    "challenge, mode, search, grouped",
    [
        ("sim_agents", "exact", "device", False),
        # Grouped: the three per-object programs test_realism_equals_the_file_path compiled.
        ("scenario_gen", "float32", "device", True),
    ],
)
def test_per_object_values_equal_the_numpy_path(challenge, mode, search, grouped):
    """`realism(..., per_object=True)` inside a plain `jax.jit`: each evaluated object's likelihood and count
    in its rollout column, equal to the numpy path's (within the metrics' tolerance; bit-identical in exact
    mode on CPU), NaN and 0 in the other columns; the scene fields as without it (one group's, within 1e-6
    when grouped, as test_realism_equals_the_file_path checks). Grouped: three programs, their columns put
    back in scene order."""
    prepared, arrays = prepared_set(challenge, grouped=grouped, search=search)
    plain = in_jit(mode, *prepared_set(challenge, search=search))
    assert plain.per_object is None and plain.per_object_counts is None
    with traced_as(mode):
        got = as_numpy(_step_per_object(prepared, arrays))
    assert got.mode == mode
    for field in SCENARIO_FIELDS:
        np.testing.assert_allclose(got[field], plain[field], rtol=0, atol=1e-6, err_msg=field)
    want = numpy_per_object(prepared, challenge)
    assert set(got.per_object) == set(got.per_object_counts) == set(LIKELIHOOD_FIELDS)
    for field, (values, counts) in want.items():
        ours, our_counts = got.per_object[field], got.per_object_counts[field]
        assert ours.dtype == np.float32 and our_counts.dtype == np.int32, field
        assert ours.shape == our_counts.shape == prepared.sim_agent_ids.shape, field
        np.testing.assert_array_equal(our_counts, counts, err_msg=field)
        np.testing.assert_array_equal(np.isnan(ours), np.isnan(values), err_msg=field)
        np.testing.assert_allclose(ours, values, rtol=0, atol=METRIC_TOLERANCE, equal_nan=True, err_msg=field)
        if mode == "exact":
            np.testing.assert_array_equal(ours, values, err_msg=field)
        # The identity on the device's values: each scene's field is their count-weighted geometric mean.
        for s in range(prepared.num_scenes):
            counted = our_counts[s] > 0
            weights = our_counts[s][counted] / our_counts[s].sum()
            mean = np.exp((weights * np.log(ours[s][counted].astype(np.float64))).sum())
            assert mean == pytest.approx(float(got[field][s]), rel=1e-6), (s, field)


def test_a_plain_training_step_with_x64_off():
    """jit, lax.scan over steps of vmapped rollout sets, all with JAX's defaults; a grad-free loss of the
    meta-metric. (The loss is the step other tests compiled, called with moved rollouts: a jitted loss
    around it would be one more program, about 17 s of compiling, checking nothing more.)"""
    assert not jax.config.jax_enable_x64
    prepared, arrays = prepared_set("sim_agents")

    def loss(shift):
        moved = dict(arrays, x=arrays["x"] + np.float32(shift))
        return 1.0 - float(np.mean(in_jit("float32", prepared, moved)["metametric"]))

    def scan_of_vmap(prepared, steps):  # steps: (num_steps, num_sets, *rollout shape)
        def step(carry, sets):
            out = jax.vmap(lambda a: jax_realism.realism(prepared, **a))(sets)
            return carry, (out["metametric"], out.mode == "float32")

        return lax.scan(step, 0.0, steps)[1]

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no dtype truncation warnings in the caller's trace, no closed-over scenes
        base, moved = loss(0.0), loss(3.0)
        steps = {k: np.stack([np.stack([v, v + np.float32(k == "x")])] * 2) for k, v in arrays.items()}
        scanned, float32_mode = jax.jit(scan_of_vmap)(prepared, steps)
    expected = in_jit("float32", prepared, arrays)  # the step other tests compiled already
    assert expected["metametric"].dtype == np.float32
    assert base == pytest.approx(1.0 - np.mean(expected["metametric"]), abs=1e-6)
    assert moved > base  # rollouts moved 3 m off are less realistic
    assert np.asarray(float32_mode).all()
    scanned = np.asarray(scanned)  # (steps, sets, scenes)
    np.testing.assert_array_equal(scanned[:, 0], np.stack([expected["metametric"]] * 2))
    assert (scanned[:, 1] < scanned[:, 0]).all()  # the set moved 1 m is less realistic, in every step


_CONSTANT = re.compile(r"stablehlo\.constant\s+(dense(?:_resource)?)<(.{0,3})[^\n]*?:\s*tensor<([^>]*)>")
_ELEMENT_BITS = {
    "i1": 8,
    "i8": 8,
    "ui8": 8,
    "i16": 16,
    "ui16": 16,
    "f16": 16,
    "bf16": 16,
    "i32": 32,
    "ui32": 32,
    "f32": 32,
    "i64": 64,
    "ui64": 64,
    "f64": 64,
}


def largest_constant_bytes(stablehlo: str) -> int:
    """The bytes of the largest constant a lowered module embeds (a splat counts one element)."""
    largest = 0
    for kind, head, tensor in _CONSTANT.findall(stablehlo):
        *dims, element = tensor.split("x")
        splat = kind == "dense" and not head.startswith(("[", '"0x'))
        count = 1 if splat else int(np.prod([int(d) for d in dims], dtype=np.int64))
        largest = max(largest, count * _ELEMENT_BITS[element] // 8)
    return largest


@pytest.mark.parametrize("search", ["device", "host"])
def test_prepared_as_an_argument_embeds_no_large_constant(search):
    """256 scenes (three repeated; abstract arrays: lowered, not compiled), `prepared` an argument of the
    caller's jit, directly or through `jit_step`: no constant over 1 MB in the program and no warning. The
    same step closing over the three scenes embeds their arrays (device search: 9 MB), which the scan sees."""
    prepared, arrays = prepared_set("sim_agents", search=search)
    big = tiling.tiled(prepared, 256, abstract=True)
    big_arrays = tiling.tiled_rollouts(arrays, 256, abstract=True)
    assert big.num_scenes == 256 and big.host_searches is prepared.host_searches
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        lowered = [
            _step.lower(big, big_arrays),
            jax_realism.jit_step(lambda p, a: jax_realism.realism(p, **a)["metametric"], big).lower(big_arrays),
        ]
    for low in lowered:
        assert largest_constant_bytes(low.as_text()) <= 2**20
    if search == "device":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the closed-over warning (once per process): its own test
            closed = jax.jit(lambda a: jax_realism.realism(prepared, **a)).lower(arrays).as_text()
        assert largest_constant_bytes(closed) > 2**20


def test_a_closed_over_prepared_set_warns_once_with_the_fix(monkeypatch):
    """Traced by a jit with `prepared` closed over (its arrays concrete: 9 MB here), `realism` warns once per
    process in one sentence showing the fix; an eager call or vmap stages nothing and is not a jit."""
    from wosac_eval.backends import realism_inputs as backend

    monkeypatch.setattr(backend, "_closed_over_warned", False)
    prepared, arrays = prepared_set("sim_agents")
    assert sum(leaf.nbytes for leaf in jax.tree_util.tree_leaves(prepared)) > backend.CLOSED_OVER_WARNING_BYTES
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        jax.eval_shape(lambda p, a: jax_realism.realism(p, **a), prepared, arrays)  # an argument: silent
        assert not caught
        for _ in range(2):
            jax.eval_shape(lambda a: jax_realism.realism(prepared, **a), arrays)
    assert len(caught) == 1, [str(w.message) for w in caught]
    message = str(caught[0].message)
    assert caught[0].filename == __file__
    assert "constants of the compiled program" in message and "pass them as an argument" in message
    assert "jax.jit(lambda prepared, x, y, z, heading:" in message and "jit_step" in message
    under = []
    jax.vmap(lambda v: under.append(backend._under_a_jit()) or v)(np.zeros(2))
    jax.jit(lambda v: under.append(backend._under_a_jit()) or v)(np.zeros(2))
    assert under == [False, True] and not backend._under_a_jit()


@pytest.mark.parametrize("challenge", ["sim_agents", "scenario_gen"])
def test_the_host_search_in_a_training_step_with_x64_off(challenge):
    """The CPU's default: the pruned searches called back from the caller's jit, vmap and scan,
    with JAX's defaults; metrics as the file path's within the official tolerance."""
    assert not jax.config.jax_enable_x64
    scs, rollouts = scene_set(challenge)
    prepared, arrays = prepared_set(challenge, search="host")
    device = in_jit("float32", *prepared_set(challenge))

    def scan_of_vmap(steps):  # steps: (num_steps, num_sets, *rollout shape)
        def step(carry, sets):
            out = jax.vmap(lambda a: jax_realism.realism(prepared, **a))(sets)
            return carry, out.metrics

        return lax.scan(step, 0.0, steps)[1]

    steps = {k: np.stack([np.stack([v, v + np.float32(k == "x")])] * 2) for k, v in arrays.items()}
    scanned = as_numpy(jax.jit(scan_of_vmap)(steps))  # (steps, sets, scenes)
    for s, (sc, ro) in enumerate(zip(scs, rollouts)):
        expected = score_scenario(sc, ro, challenge=challenge)
        for field in SCENARIO_FIELDS:
            got = scanned[field][:, 0, s]
            assert (got == got[0]).all(), (sc.scenario_id, field)
            assert abs(float(np.float32(got[0])) - expected[field]) <= METRIC_TOLERANCE, (sc.scenario_id, field)
            assert abs(float(got[0]) - float(device[field][s])) <= METRIC_TOLERANCE, (sc.scenario_id, field)
    moved, still = scanned["metametric"][:, 1], scanned["metametric"][:, 0]
    assert (moved != still).all()  # each element of the batch was scored on its own rollouts
    if challenge == "sim_agents":
        assert (moved < still).all()  # IDM rollouts moved 1 m are less realistic


def test_the_search_is_chosen_by_the_backend_and_recorded():
    scs, _ = scene_set("sim_agents")
    default = jax_realism.prepare(scs[:1])
    assert default.search == ("host" if jax.default_backend() == "cpu" else "device")
    with pytest.raises(ValueError, match="unknown search .*: choose one of auto, host, device"):
        jax_realism.prepare(scs[:1], search="gpu")


def test_the_mode_is_explicit_and_recorded():
    prepared, arrays = prepared_set("sim_agents")
    with pytest.raises(ValueError, match=r"x64 must be on.*enable_x64\(True\).*mode='float32'"):
        jax_realism.realism(prepared, **arrays, mode="exact")
    with pytest.raises(ValueError, match="unknown mode .*: choose one of exact, float32"):
        jax_realism.realism(prepared, **arrays, mode="float16")
    with jax.enable_x64(True):  # jitted: an eager call compiles each of its operations, every run
        exact = _step(prepared, arrays)  # the program test_realism_equals_the_file_path compiled
        also_float32 = jax.jit(lambda p, a: jax_realism.realism(p, **a, mode="float32"))(prepared, arrays)
    assert (exact.mode, also_float32.mode) == ("exact", "float32")
    assert exact["metametric"].dtype == np.float64
    assert set(exact) == set(SCENARIO_FIELDS) and dict(exact).keys() == exact.keys()
    np.testing.assert_allclose(
        np.asarray(also_float32["metametric"]), np.asarray(exact["metametric"]), rtol=0, atol=METRIC_TOLERANCE
    )


class DlpackOnly:
    """A producer that offers nothing but the DLPack protocol (as a torch tensor does to JAX)."""

    def __init__(self, array):
        self._array = array

    def __dlpack__(self, **kwargs):
        return self._array.__dlpack__(**kwargs)

    def __dlpack_device__(self):
        return self._array.__dlpack_device__()


def test_any_dlpack_array_is_taken():
    prepared, arrays = prepared_set("sim_agents")
    with jax.enable_x64(True):  # an eager call: DLPack producers are taken at the call, not by a jit
        got = as_numpy(jax_realism.realism(prepared, **{k: DlpackOnly(v) for k, v in arrays.items()}))
    want = in_jit("exact", prepared, arrays)  # the program test_realism_equals_the_file_path compiled
    assert (got.mode, want.mode) == ("exact", "exact")
    for field in SCENARIO_FIELDS:
        np.testing.assert_array_equal(got[field], want[field], err_msg=field)


def test_importing_leaves_the_jax_configuration_alone():
    """No XLA_FLAGS, no x64 switch: the user's model compiles as it would without wosac-eval."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    code = (
        "import os, jax; from wosac_eval import jax_realism; from wosac_eval.backends import jax_backend; "
        "print(os.environ.get('XLA_FLAGS'), jax.config.jax_enable_x64, jax_backend.fma_contraction())"
    )
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split()[:2] == ["None", "False"]


def test_exact_cpu_is_an_opt_in_made_before_the_first_computation():
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    opt_in = (
        "from wosac_eval import jax_realism; from wosac_eval.backends import jax_backend; "
        "jax_realism.exact_cpu(); print(jax_backend.fma_contraction())"
    )
    out = subprocess.run([sys.executable, "-c", opt_in], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False"]
    too_late = (
        "import jax, jax.numpy as jnp; from wosac_eval.backends import jax_backend; "
        "jax.block_until_ready(jnp.ones(3) * 2 + 1); "
        "fused = jax_backend.fma_contraction(jax.devices('cpu')[0]); print(fused)\n"
        "try:\n    jax_backend.exact_cpu()\n"
        "finally:\n    import os; print(os.environ.get('XLA_FLAGS'))"
    )
    out = subprocess.run([sys.executable, "-c", too_late], env=env, capture_output=True, text=True)
    if out.stdout.split()[:1] == ["True"]:  # a CPU with FMA: XLA had started fusing, exact_cpu says so
        assert out.returncode != 0 and "already started with fused multiply-adds" in out.stderr
        # ... and leaves XLA_FLAGS unset, as it was: children and JAX's compilation cache key read them
        assert out.stdout.split() == ["True", "None"]


def test_waymax_style_arrays_in():
    """Objects x timesteps including the history, in Waymax's object order (reversed here), with padding."""
    prepared, arrays = prepared_set("sim_agents")
    scs, _ = scene_set("sim_agents")
    ids = prepared.sim_agent_ids
    n_obj = ids.shape[1] + 2
    object_ids = np.full((3, n_obj), 99999, np.int64)
    waymax = {k: np.zeros((3, 32, n_obj, 91), np.float32) for k in ("x", "y", "z", "yaw")}
    for s in range(3):
        real = ids[s][ids[s] >= 0]
        object_ids[s, : real.size] = real[::-1]
        for a, oid in enumerate(ids[s]):
            if oid < 0:
                continue
            col = int(np.flatnonzero(object_ids[s] == oid)[0])
            for wk, k in (("x", "x"), ("y", "y"), ("z", "z"), ("yaw", "heading")):
                waymax[wk][s, :, col, 11:] = arrays[k][s, :, a]
    columns = jax_realism.waymax_columns(prepared, object_ids)
    picked = jax_realism.from_waymax(prepared, columns, **waymax)
    got, want = in_jit("float32", prepared, picked), in_jit("float32", prepared, arrays)  # one program
    for field in SCENARIO_FIELDS:
        np.testing.assert_array_equal(got[field], want[field], err_msg=field)
    with pytest.raises(ValueError, match="not among the Waymax objects"):
        jax_realism.waymax_columns(prepared, np.zeros((3, 4), np.int64))


def test_bad_arrays_are_refused_with_the_shapes():
    prepared, arrays = prepared_set("sim_agents")
    with pytest.raises(ValueError, match=r"x must be \(num_scenes, num_rollouts, max_agents, num_steps\)"):
        jax_realism.realism(prepared, **dict(arrays, x=arrays["x"][..., :79]))
    with pytest.raises(ValueError, match="box sizes from the log"):
        jax_realism.realism(prepared, **arrays, length=arrays["x"])
    sg, sg_arrays = prepared_set("scenario_gen")
    with pytest.raises(ValueError, match="height missing"):
        jax_realism.realism(sg, **{k: v for k, v in sg_arrays.items() if k != "height"})


def golden_runs() -> list:
    """Every golden set in exact mode (the official bits: the point), and once in float32 mode (within
    1e-5): by the host search for the sim-agents sets (a training loop's on a CPU), on the device for the
    scenario-gen ones."""
    runs = []
    for case_set in golden.SETS:
        float32_search = "host" if case_set.challenge == "sim_agents" else "device"
        for mode, search in (("exact", "device"), ("float32", float32_search)):
            runs.append(pytest.param(case_set, mode, search, id=f"{case_set.name}-{mode}-{search}"))
    return runs


@pytest.mark.ci  # eight programs of the golden sets' shapes (4 minutes of compiling on 2 cores): the CI tier's
@pytest.mark.parametrize("case_set, mode, search", golden_runs())
def test_every_golden_case_matches_the_official_metrics(case_set, mode, search):
    """All cases of a golden set (real WOMD scenes with ../shared; synthetic oracle cases always) in one
    batch, one group (one program to compile; padding changes no result, as tested above). The host
    search runs in float32 mode, a training loop's on a CPU (its exact mode: bit-identical features)."""
    cases = case_set.cases
    if not cases:
        golden.skip_if_absent(case_set, None)
    pairs = [golden.inputs(case_set, case) for case in cases]
    config_name = case_set.configs[0]
    config = golden.config_reference(case_set, config_name)
    prepared = jax_realism.prepare(
        [scene for scene, _ in pairs], challenge=case_set.challenge, config=config, grouped=False, search=search
    )
    got = in_jit(mode, prepared, jax_realism.stack_rollouts(prepared, [ro for _, ro in pairs]))
    for s, case in enumerate(cases):
        expected = golden.expected_metrics(case_set, case, config_name)
        for field in SCENARIO_FIELDS:
            if field not in expected:
                continue
            if mode == "exact":  # the official float32 value, bit for bit
                want = np.float32(expected[field])
                np.testing.assert_array_equal(np.float32(got[field][s]), want, f"{case} {field}")
            else:
                assert abs(float(np.float32(got[field][s])) - expected[field]) <= METRIC_TOLERANCE, (case, field)
