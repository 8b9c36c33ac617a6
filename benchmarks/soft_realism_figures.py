"""The figures of docs/soft-realism.md: how close `jax_realism.soft_realism` is to the official meta-metric,
and whether its gradients are real.

1. Per golden case (the reference material's cases with ../shared or WOSAC_SHARED; the repository's
   oracle cases with `--oracle`), |soft - official meta-metric| at temperatures 1, 0.1 and 0.01, the
   official value from the case's JSON (the challenge's leaderboard config).
2. On the repository's oracle case whose rollouts run red lights: the soft red-light likelihood and
   violation rate against the official ones at each temperature, and the red-light likelihood's gradient
   in x and y (finite? how many non-zero?).
3. On a demo scene (`sim.scenes`, IDM rollouts): the gradient of the soft meta-metric with respect to
   x, y, z and heading (finite? how many non-zero?), and `jax.test_util.check_grads` (order 1, forward
   and reverse) of the meta-metric as a function of a shift (x, y, heading) of the first evaluated object's rollouts.

Usage: python benchmarks/soft_realism_figures.py [--oracle] [--no-golden] [--no-red-light] [--no-gradients]
"""

from __future__ import annotations

import sys
import time

import jax
import jax.numpy as jnp
import jax.test_util
import numpy as np
from bench_env import SHARED  # noqa: F401  (puts tests/ on the path)

from support import golden
from wosac_eval import jax_realism
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import policy_rollouts

TEMPERATURES = (1.0, 0.1, 0.01)


def golden_gaps(case_set) -> None:
    """Prints |soft - official meta-metric| per case of `case_set` at each temperature."""
    cases = case_set.cases
    if not cases:
        print(f"{case_set.name}: absent ({case_set.folder})")
        return
    config_name = case_set.configs[0]
    prepared, arrays = golden.device_inputs(case_set, cases, config_name)
    step = jax.jit(lambda p, a, t: jax_realism.soft_realism(p, **a, temperature=t)["metametric"])
    start = time.perf_counter()
    soft = {t: np.asarray(step(prepared, arrays, t)) for t in TEMPERATURES}  # the temperature is traced
    seconds = time.perf_counter() - start
    print(
        f"{case_set.name} ({case_set.challenge}, config {config_name}; {len(cases)} cases, "
        f"{seconds:.0f} s with one compile)"
    )
    print(f"  {'case':58s} {'official':>9s} " + " ".join(f"{'T=' + str(t):>9s}" for t in TEMPERATURES))
    worst = dict.fromkeys(TEMPERATURES, 0.0)
    for k, case in enumerate(cases):
        official = golden.expected_metrics(case_set, case, config_name)["metametric"]
        gaps = {t: abs(float(soft[t][k]) - official) for t in TEMPERATURES}
        worst = {t: max(worst[t], gaps[t]) for t in TEMPERATURES}
        print(f"  {case:58s} {official:9.5f} " + " ".join(f"{gaps[t]:9.2e}" for t in TEMPERATURES))
    print(f"  {'largest':58s} {'':9s} " + " ".join(f"{worst[t]:9.2e}" for t in TEMPERATURES))


RED_LIGHT_CASE = "synthetic-7-000-red-light__constvel_noise"
RED_LIGHT_FIELDS = ("traffic_light_violation_likelihood", "simulated_traffic_light_violation_rate")


def red_light_figures() -> None:
    """The soft red-light values against the official ones, and their gradient, on the oracle red-light case."""
    case_set = next(s for s in golden.SETS if s.name == "oracle")
    prepared, arrays = golden.device_inputs(case_set, [RED_LIGHT_CASE], "2025")
    arrays = {k: jnp.asarray(v) for k, v in arrays.items()}
    official = golden.expected_metrics(case_set, RED_LIGHT_CASE, "2025")
    crossings = golden.expected_features(case_set, RED_LIGHT_CASE)["sim_traffic_light_violation_per_step"]
    print(f"red light (oracle case {RED_LIGHT_CASE}, config 2025; {int(crossings.sum())} crossings on red):")
    step = jax.jit(lambda p, a, t: jax_realism.soft_realism(p, **a, temperature=t))
    temperatures = (*TEMPERATURES, 1e-3)
    outs = {t: step(prepared, arrays, t) for t in temperatures}
    print(f"  {'field':40s} {'official':>9s} " + " ".join(f"{'T=' + str(t):>9s}" for t in temperatures))
    for field in (*RED_LIGHT_FIELDS, "metametric"):
        gaps = " ".join(f"{abs(float(outs[t][field][0]) - official[field]):9.2e}" for t in temperatures)
        print(f"  {field:40s} {official[field]:9.5f} {gaps}")
    for temperature in TEMPERATURES:

        def likelihood(x, y):
            out = jax_realism.soft_realism(prepared, x, y, arrays["z"], arrays["heading"], temperature=temperature)
            return out["traffic_light_violation_likelihood"].sum()

        grads = jax.grad(likelihood, argnums=(0, 1))(arrays["x"], arrays["y"])
        finite = all(bool(jnp.isfinite(g).all()) for g in grads)
        parts = ", ".join(
            f"{name} {int(np.count_nonzero(g))} non-zero, max |g| {float(jnp.abs(g).max()):.2e}"
            for name, g in zip(["x", "y"], grads)
        )
        print(f"  T={temperature}: red-light likelihood's gradient finite everywhere: {finite}; {parts}")


def gradient_figures() -> None:
    """Gradient of the soft meta-metric on a demo scene, and `check_grads` of a shift of one agent."""
    scene = scenes.generate_scene(0, 1)
    prepared = jax_realism.prepare([scene], search="device")
    arrays = {
        k: jnp.asarray(v) for k, v in jax_realism.stack_rollouts(prepared, [policy_rollouts(scene, "idm")]).items()
    }
    for temperature in TEMPERATURES:

        def metametric(x, y, z, heading):
            return jax_realism.soft_realism(prepared, x, y, z, heading, temperature=temperature)["metametric"].sum()

        grads = jax.grad(metametric, argnums=(0, 1, 2, 3))(arrays["x"], arrays["y"], arrays["z"], arrays["heading"])
        parts = ", ".join(
            f"{name} {int(np.count_nonzero(g))} non-zero, max |g| {float(jnp.abs(g).max()):.2e}"
            for name, g in zip(["x", "y", "z", "heading"], grads)
        )
        finite = all(bool(jnp.isfinite(g).all()) for g in grads)
        print(f"  T={temperature}: gradient finite everywhere: {finite}; {parts}")

    # The rollouts of the first evaluated object (official row 0), shifted.
    column = jnp.arange(prepared.max_agents) == int(prepared.arrays[0]["columns"][0, 0])

    def shifted(shift):
        out = jax_realism.soft_realism(
            prepared,
            arrays["x"] + shift[0] * column[:, None],
            arrays["y"] + shift[1] * column[:, None],
            arrays["z"],
            arrays["heading"] + shift[2] * column[:, None],
            temperature=1.0,
        )
        return out["metametric"]

    # A generic point: unshifted, the demo's boxes are parallel, where box distances have kinks in the heading.
    shift = jnp.asarray((0.013, -0.021, 0.0173), jnp.float32)
    start = time.perf_counter()
    jax.test_util.check_grads(shifted, (shift,), order=1, modes=("fwd", "rev"), eps=2e-3)
    gradient = jax.grad(lambda s: shifted(s).sum())(shift)
    print(
        f"  check_grads(order=1, modes=fwd, rev; eps=2e-3) of the meta-metric in a shift (x, y, heading) = "
        f"{tuple(round(float(v), 4) for v in shift)} of the first evaluated object's rollouts, T=1: passed in "
        f"{time.perf_counter() - start:.0f} s; gradient {np.asarray(gradient)}"
    )


def main(argv: list[str]) -> None:
    if "--no-golden" not in argv:
        names = ("shared", "shared_scenario_gen") + (("oracle", "oracle_scenario_gen") if "--oracle" in argv else ())
        for case_set in golden.SETS:
            if case_set.name in names:
                golden_gaps(case_set)
    if "--no-red-light" not in argv:
        red_light_figures()
    if "--no-gradients" not in argv:
        print("gradients (demo scene 1 of sim.scenes.generate_scenes(10, seed=0), IDM rollouts, sim agents 2025):")
        gradient_figures()


if __name__ == "__main__":
    main(sys.argv[1:])
