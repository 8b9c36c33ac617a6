"""How exact `wosac_eval.jax_realism` is on the device JAX uses: every golden case of both challenges.

For each golden set (the reference material's real WOMD cases, with ../shared or WOSAC_SHARED, and the
oracle cases of the repository), prints per case the largest metric error against the official outputs
(and the fields over 1e-5), and per set how many per-step feature values differ from numpy's (which
are bit-identical to the official ones) and by how much at most. On CPU with `exact_cpu()` the exact
mode differs nowhere; on a GPU XLA's float32 square roots and divisions are not correctly rounded.
The searches are `prepare`'s default for the device (the host's pruned search on a CPU), or the one
named second.

Usage: python benchmarks/jax_realism_exactness.py [float32|exact] [auto|host|device]
"""

from __future__ import annotations

import sys

from bench_env import SHARED  # noqa: F401  (puts tests/ on the path)

import jax
import numpy as np

from support import golden
from wosac_eval import jax_realism
from wosac_eval.features.metric_features import PER_STEP_FIELDS, scenario_features
from wosac_eval.metrics.scenario_metrics import SCENARIO_FIELDS

TOLERANCE = 1e-5


def differing(ours: np.ndarray, want: np.ndarray) -> tuple[int, float]:
    """How many values differ (NaN equals NaN) and the largest absolute difference among them."""
    ours, want = np.asarray(ours, float), np.asarray(want, float)
    diff = ~((ours == want) | (np.isnan(ours) & np.isnan(want)))
    gaps = np.abs(ours - want)[diff]
    return int(diff.sum()), float(gaps[np.isfinite(gaps)].max()) if np.isfinite(gaps).any() else 0.0


def check_set(case_set, mode: str, search: str) -> None:
    cases = case_set.cases
    pairs = [golden.inputs(case_set, c) for c in cases]
    name = case_set.configs[0]
    config = golden.config_reference(case_set, name)
    prepared = jax_realism.prepare([s for s, _ in pairs], challenge=case_set.challenge, config=config, search=search)
    arrays = jax_realism.stack_rollouts(prepared, [r for _, r in pairs])
    with jax.enable_x64(mode == "exact"):
        feats = jax_realism.features(prepared, **arrays)
        got = jax.jit(lambda p, a: jax_realism.realism(p, **a))(prepared, arrays)  # prepared: an argument
    got = {k: np.asarray(v) for k, v in got.items()}
    counts: dict[str, list] = {}
    for s, (case, (scene, rollouts)) in enumerate(zip(cases, pairs)):
        log, sim = scenario_features(scene, rollouts, challenge=case_set.challenge)
        e = log.object_id.size
        for field in PER_STEP_FIELDS:
            ours = np.asarray(getattr(feats, field))[s]
            for part, want in ((ours[:1, :e], getattr(log, field)), (ours[1:, :e], getattr(sim, field))):
                n, gap = differing(part, want)
                total = counts.setdefault(field, [0, 0.0])
                total[0], total[1] = total[0] + n, max(total[1], gap)
        expected = golden.expected_metrics(case_set, case, name)
        errors = {f: abs(float(np.float32(got[f][s])) - expected[f]) for f in SCENARIO_FIELDS if f in expected}
        over = {f: f"{e:.2e}" for f, e in errors.items() if e > TOLERANCE}
        print(
            f"  {case}: largest metric error {max(errors.values()):.2e}"
            + (f", over {TOLERANCE}: {over}" if over else "")
        )
    diffs = ", ".join(f"{f} {n} (up to {gap:.1e})" for f, (n, gap) in counts.items() if n)
    print(
        f"{case_set.name}: {len(cases)} cases; per-step feature values differing from numpy: {diffs or 'none'}",
        flush=True,
    )


def main() -> None:
    mode = sys.argv[1] if len(sys.argv) > 1 else "float32"
    search = sys.argv[2] if len(sys.argv) > 2 else "auto"
    if mode not in ("float32", "exact") or search not in jax_realism.SEARCHES:
        raise SystemExit(__doc__.splitlines()[-1])
    print(f"device: {jax.devices()[0]}; mode {mode}; search {search}")
    for case_set in golden.SETS:
        if case_set.cases:
            check_set(case_set, mode, search)
        else:
            print(f"{case_set.name}: absent ({case_set.folder})")


if __name__ == "__main__":
    main()
