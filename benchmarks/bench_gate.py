"""Times `compare` and `report` on synthetic results the size of the WOSAC test set.

    .venv/bin/python benchmarks/bench_gate.py [--scenarios 44920] [--n-boot 5000] [--n-perm 5000]

Prints wall times of: reading both result JSON files, the paired statistics over
every metric, the whole comparison, and rendering the HTML report.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

from wosac_eval.results import stats
from wosac_eval.results.compare import compare_results
from wosac_eval.results.report import render_report
from wosac_eval.scoring.result_reader import load_result
from wosac_eval.results.synthetic_results import LIKELIHOODS, synthetic_result


def _timed(label, fn):
    start = time.perf_counter()
    out = fn()
    print(f"{label:<44s} {time.perf_counter() - start:8.2f} s")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=44920, help="scenarios per result (WOSAC test set: 44920)")
    parser.add_argument("--n-boot", type=int, default=5000)
    parser.add_argument("--n-perm", type=int, default=5000)
    args = parser.parse_args()
    print(
        f"{args.scenarios} scenarios, {args.n_boot} bootstrap resamples, {args.n_perm} sign flips, "
        f"{os.cpu_count()} CPUs"
    )
    with tempfile.TemporaryDirectory() as tmp:
        base_path, new_path = os.path.join(tmp, "base.json"), os.path.join(tmp, "new.json")
        with open(base_path, "w") as f:
            json.dump(synthetic_result(args.scenarios, seed=0), f)
        with open(new_path, "w") as f:
            json.dump(synthetic_result(args.scenarios, seed=0, shift={LIKELIHOODS[5]: 0.002}, jitter=0.02), f)
        base = _timed("read base result", lambda: load_result(base_path))
        new = _timed("read new result", lambda: load_result(new_path))
        metrics = [m for m in base.values if m in new.values]
        import numpy as np

        b = np.stack([base.values[m] for m in metrics], axis=1)
        w = np.stack([new.values[m] for m in metrics], axis=1)
        _timed(
            f"bootstrap CI ({len(metrics)} metrics)",
            lambda: stats.bootstrap_mean_ci(w - b, np.random.default_rng(0), n_boot=args.n_boot),
        )
        _timed(
            f"permutation p-value ({len(metrics)} metrics)",
            lambda: stats.permutation_p_value(w - b, np.random.default_rng(0), n_perm=args.n_perm),
        )
        comparison = _timed(
            "compare_results (all metrics)",
            lambda: compare_results(base, new, settings=stats.PairedSettings(n_boot=args.n_boot, n_perm=args.n_perm)),
        )
        page = _timed("render_report with comparison", lambda: render_report(new, base, comparison))
        print(f"report size: {len(page) / 1024:.0f} KiB")


if __name__ == "__main__":
    main()
