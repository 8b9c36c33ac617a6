"""The exact mode leaves no compiler a float32 rounding to change (issue 42, item 3), checked without a GPU.

1. The lowered StableHLO of `jax_realism.realism` in exact mode holds no float32 multiply, division, root
   or transcendental, and no float64 one a compiler could shrink back to float32 (`float32_hazards`);
   the float32 mode's program holds hundreds (the check sees them).
2. On this CPU with XLA's fused multiply-adds allowed (no `exact_cpu()`: what a GPU compiler does), the
   exact mode's per-step features are still bit-identical to the numpy path's.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import textwrap

import pytest

jax = pytest.importorskip("jax")

from wosac_eval import jax_realism  # noqa: E402
from wosac_eval.backends.exact_rounding import float32_hazards  # noqa: E402
from wosac_eval.sim import scenes  # noqa: E402
from wosac_eval.sim.baselines import policy_rollouts  # noqa: E402

CHALLENGES = ("sim_agents", "scenario_gen")


def demo_set(challenge: str, keys=(1,)):
    scs = [scenes.generate_scene(0, k) for k in keys]
    policy = "idm" if challenge == "sim_agents" else "log_replay_noise"
    return scs, [policy_rollouts(sc, policy, challenge=challenge) for sc in scs]


def lowered(challenge: str, mode: str) -> str:
    scs, rollouts = demo_set(challenge)
    prepared = jax_realism.prepare(scs, challenge=challenge, search="device")
    arrays = jax_realism.stack_rollouts(prepared, rollouts)
    step = jax.jit(lambda p, a: jax_realism.realism(p, **a, mode=mode))
    with jax.enable_x64(True) if mode == "exact" else contextlib.nullcontext():
        return step.lower(prepared, arrays).as_text()


@pytest.mark.parametrize("challenge", CHALLENGES)
@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_the_exact_mode_program_leaves_no_float32_rounding_to_the_compiler(challenge):
    assert float32_hazards(lowered(challenge, "exact")) == {}


@pytest.mark.parametrize("challenge", CHALLENGES)
@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_the_check_finds_the_hazards_of_the_float32_mode(challenge):
    hazards = float32_hazards(lowered(challenge, "float32"))
    assert hazards["multiply"] > 100 and hazards["divide"] > 0 and hazards["sqrt"] > 0, hazards


def test_the_check_reads_widened_float32_operations_as_shrinkable():
    text = textwrap.dedent("""\
        func.func public @main(%arg0: tensor<4xf32>, %arg1: tensor<4xf32>) -> tensor<4xf32> {
          %0 = stablehlo.convert %arg0 : (tensor<4xf32>) -> tensor<4xf64>
          %1 = stablehlo.reshape %0 : (tensor<4xf64>) -> tensor<4xf64>
          %2 = stablehlo.sqrt %1 : tensor<4xf64>
          %3 = stablehlo.multiply %arg0, %arg1 : tensor<4xf32>
          %4 = stablehlo.add %3, %arg1 : tensor<4xf32>
          %5 = stablehlo.bitcast_convert %0 : (tensor<4xf64>) -> tensor<4xi64>
          %6 = stablehlo.bitcast_convert %5 : (tensor<4xi64>) -> tensor<4xf64>
          %7 = stablehlo.sqrt %6 : tensor<4xf64>
          return %4 : tensor<4xf32>
        }
        """)
    assert float32_hazards(text) == {"shrinkable sqrt": 1, "multiply": 1}


FMA_RUN = """
import jax, numpy as np
from wosac_eval import jax_realism
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.backends import jax_backend
from wosac_eval.features.metric_features import PER_STEP_FIELDS, scenario_features
from exact_rounding_test import demo_set
assert jax_backend.fma_contraction(), "XLA's CPU compiler was expected to fuse multiply-adds here"
for challenge in ("sim_agents", "scenario_gen"):
    scs, rollouts = demo_set(challenge, keys=(1, 5))
    prepared = jax_realism.prepare(scs, challenge=challenge, search="device")
    with jax.enable_x64(True):
        feats = jax_realism.features(prepared, **jax_realism.stack_rollouts(prepared, rollouts))
    for s, (sc, ro) in enumerate(zip(scs, rollouts)):
        log, sim = scenario_features(scenario_arrays(sc), ro, challenge=challenge)
        e = log.object_id.size
        for field in PER_STEP_FIELDS:
            ours = np.asarray(getattr(feats, field))[s]
            for got, want in ((ours[:1, :e], getattr(log, field)), (ours[1:, :e], getattr(sim, field))):
                np.testing.assert_array_equal(np.asarray(got, np.asarray(want).dtype), want,
                                              err_msg=f"{challenge} scene {s} {field}")
print("bit-identical")
"""


@pytest.mark.ci  # a process compiling both challenges' programs anew with other flags (1-2 min): the CI tier's
def test_exact_features_stay_bit_identical_where_the_compiler_fuses_multiply_adds(tmp_path):
    if "fma" not in open("/proc/cpuinfo").read().split():
        pytest.skip("this CPU has no fused multiply-add: XLA cannot contract here")
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}  # no exact_cpu(): FMA on
    env["PYTHONPATH"] = os.pathsep.join([os.path.dirname(__file__), *sys.path])
    done = subprocess.run(  # (not run in the repository: `-c` imports from its working folder)
        [sys.executable, "-c", FMA_RUN], env=env, capture_output=True, text=True, timeout=1200, cwd=tmp_path
    )
    assert done.returncode == 0 and "bit-identical" in done.stdout, done.stdout[-3000:] + done.stderr[-5000:]
