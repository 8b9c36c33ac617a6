"""How many official outputs wosac-eval reproduces bit for bit: per field, over every golden case and config.

Scores every case of every golden set (`tests/support/golden.SETS`: the reference material's real WOMD
cases and Scenario Generation cases, with ../shared or WOSAC_SHARED, and the oracle cases of the
repository) under every config its official outputs were made for, and compares each likelihood,
rate, displacement error, meta-metric and bucket with the official value as float32: how many are
bit-identical, the largest distance in units in the last place (ulps) and the largest absolute
difference. The numpy path by default; `--jax exact` or `--jax float32` scores through
`wosac_eval.jax_realism` in that mode instead (one program per golden set and config; on this
machine's CPU, with XLA's CPU code restricted to AVX as `exact_cpu()` does).

Usage:
  python benchmarks/exactness_table.py [--jax exact|float32] [--markdown docs/exactness.md]

With --markdown, the table replaces the part of the file between `<!-- exactness-table: KEY -->` and
`<!-- /exactness-table: KEY -->` (KEY: numpy, jax-exact or jax-float32), with the command and the commit.
"""

from __future__ import annotations

import argparse
import collections
import os
import re
import subprocess
import sys
from pathlib import Path

from bench_env import SHARED  # noqa: F401  (puts tests/ on the path)

import numpy as np

from support import golden
from wosac_eval.features.metric_features import scenario_features
from wosac_eval.metrics.scenario_metrics import bucket_metrics, scenario_metrics

REPO = Path(__file__).resolve().parents[1]


def ulps(a: float, b: float) -> int:
    """Distance between two float32 values in units in the last place (0: the same bits; NaN = NaN)."""

    def ordered(v: float) -> int:
        bits = int(np.float32(v).view(np.int32))
        return -(bits & 0x7FFFFFFF) if bits < 0 else bits

    if np.isnan(a) and np.isnan(b):
        return 0
    return abs(ordered(a) - ordered(b))


def numpy_rows(case_set, case: str):
    """(config name, our fields with buckets) per config of the case, by the numpy path."""
    log, sim = scenario_features(*golden.inputs(case_set, case), challenge=case_set.challenge)
    for name in case_set.configs:
        config = golden.config(case_set, name)
        ours = scenario_metrics(config, log, sim)
        yield name, {**ours, **{f"buckets.{k}": v for k, v in bucket_metrics(config, ours).items()}}


def jax_rows(case_set, mode: str):
    """{(case, config name): our fields} of a whole set by `jax_realism` in `mode` (buckets: from its fields)."""
    import jax  # the jax extra, only for --jax

    from wosac_eval import jax_realism

    out = {}
    pairs = [golden.inputs(case_set, c) for c in case_set.cases]
    for name in case_set.configs:
        config = golden.config(case_set, name)
        prepared = jax_realism.prepare(
            [s for s, _ in pairs],
            challenge=case_set.challenge,
            config=golden.config_reference(case_set, name),
            grouped=False,
            search="device",
        )
        arrays = jax_realism.stack_rollouts(prepared, [r for _, r in pairs])
        with jax.enable_x64(mode == "exact"):
            got = jax.jit(lambda p, a: jax_realism.realism(p, **a, mode=mode))(prepared, arrays)
        got = {k: np.asarray(v) for k, v in got.items()}
        for s, case in enumerate(case_set.cases):
            fields = {k: float(np.float32(v[s])) for k, v in got.items() if np.ndim(v) == 1}
            buckets = bucket_metrics(config, fields)
            out[case, name] = {**fields, **{f"buckets.{k}": v for k, v in buckets.items()}}
    return out


def compare(jax_mode: str | None):
    """field -> [values, bit-identical, worst ulps, worst absolute difference], over every set."""
    table: dict = collections.defaultdict(lambda: [0, 0, 0, 0.0])
    for case_set in golden.SETS:
        by_jax = jax_rows(case_set, jax_mode) if jax_mode and case_set.cases else {}
        for case in case_set.cases:
            rows = ((n, by_jax[case, n]) for n in case_set.configs) if jax_mode else numpy_rows(case_set, case)
            for name, ours in rows:
                expected = golden.expected_metrics(case_set, case, name)
                official = {k: v for k, v in expected.items() if k != "buckets"}
                official.update({f"buckets.{k}": v for k, v in expected["buckets"].items()})
                for field, value in official.items():
                    distance = ulps(ours[field], value)
                    row = table[field]
                    row[0] += 1
                    row[1] += distance == 0
                    row[2] = max(row[2], distance)
                    if not np.isnan(value):
                        row[3] = max(row[3], abs(float(np.float32(ours[field])) - value))
    return table


def markdown(table: dict) -> str:
    lines = ["| field | values | bit-identical | worst ulps | worst absolute difference |", "|---|---|---|---|---|"]
    for field in sorted(table):
        n, same, worst, gap = table[field]
        lines.append(f"| `{field}` | {n} | {same} | {worst} | {gap:.2g} |")
    n, same = sum(r[0] for r in table.values()), sum(r[1] for r in table.values())
    lines.append(f"| **all** | **{n}** | **{same}** | **{max(r[2] for r in table.values())}** | |")
    return "\n".join(lines)


def write_section(path: Path, key: str, text: str) -> None:
    start, end = f"<!-- exactness-table: {key} -->", f"<!-- /exactness-table: {key} -->"
    document = path.read_text()
    block = f"{start}\n{text}\n{end}"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    document = pattern.sub(lambda _: block, document) if pattern.search(document) else document + "\n" + block + "\n"
    path.write_text(document)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jax", choices=("exact", "float32"), help="score through jax_realism in this mode")
    parser.add_argument("--markdown", type=Path, help="write the table into this Markdown file")
    args = parser.parse_args()
    if args.jax:
        os.environ.setdefault("XLA_FLAGS", "--xla_cpu_max_isa=AVX")  # as exact_cpu(): before JAX starts
    sets = [f"{s.name}: {len(s.cases)} cases x {len(s.configs)} configs" for s in golden.SETS]
    table = compare(args.jax)
    text = markdown(table)
    print("\n".join(sets) + "\n\n" + text)
    if args.markdown:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=REPO)
        command = "python benchmarks/exactness_table.py" + (f" --jax {args.jax}" if args.jax else "")
        header = f"`{command}` at `{commit.stdout.strip()}` ({'; '.join(sets)}):\n"
        write_section(args.markdown, f"jax-{args.jax}" if args.jax else "numpy", header + "\n" + text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
