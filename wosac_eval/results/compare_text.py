"""A comparison of two scoring runs written out: a plain-text table for the terminal (with its warnings,
a note on multiple testing and the gates), and GitHub-flavoured Markdown for a CI job summary."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence

from wosac_eval.results.compare import BETTER, WORSE, Comparison


def _fmt(x: float | None, signed: bool = False) -> str:
    if x is None:
        return "-"
    x = round(x, 4) or 0.0  # no "-0.0000" for a change that rounds away
    return f"{x:+.4f}" if signed else f"{x:.4f}"


def _fmt_p(p: float | None) -> str:
    if p is None:
        return "-"
    return "<0.0001" if p < 0.0001 else f"{p:.4f}"


def _wrap(text: str) -> str:
    return textwrap.fill(text, width=110, subsequent_indent="  ", break_on_hyphens=False)


def format_table(c: Comparison) -> str:
    """The comparison as a plain-text table with warnings, a multiple-testing note and the gates."""
    conf = f"{round((1 - c.alpha) * 100):d}% CI"
    header = ["metric", "best", "base", "new", "diff", conf, "p", "verdict"]
    rows = []
    for m in c.metrics:
        ci = f"[{_fmt(m.ci_low, True)}, {_fmt(m.ci_high, True)}]" if m.paired else "-"
        p = m.p_holm if c.adjust == "holm" else m.p_value
        verdict = m.verdict.upper() if m.verdict == WORSE else m.verdict
        rows.append(
            [
                m.metric,
                "high" if m.higher_is_better else "low",
                _fmt(m.base),
                _fmt(m.new),
                _fmt(m.difference, True),
                ci,
                _fmt_p(p),
                verdict,
            ]
        )
    widths = [max(len(r[i]) for r in [header] + rows) for i in range(len(header))]
    right = {2, 3, 4, 6}

    def line(cells: Sequence[str]) -> str:
        return "  ".join(
            c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(cells, widths))
        ).rstrip()

    out = [
        f"base: {c.base_path}  (config {c.base_config})",
        f"new:  {c.new_path}  (config {c.new_config})",
        f"paired over {c.num_shared} shared scenarios; diff = new - base; "
        f"seed {c.seed}, {c.n_boot} bootstrap resamples, "
        + ("exact permutation test" if c.exact_permutation else f"{c.n_perm} random sign flips"),
        "",
        line(header),
        line(["-" * w for w in widths]),
    ]
    out += [line(r) for r in rows]
    tested = sum(1 for m in c.metrics if m.paired)
    if tested > 1:
        p_kind = "Holm-adjusted p-values" if c.adjust == "holm" else "unadjusted p-values"
        out += [
            "",
            _wrap(
                f"note: {tested} metrics tested at alpha={c.alpha:g} with {p_kind}."
                + (
                    ""
                    if c.adjust == "holm"
                    else f" With no real change, about {tested * c.alpha:.1f} of them can still come out"
                    " better/worse by chance; use --adjust holm to control that."
                )
                + " The metrics are correlated (buckets are weighted means of the likelihoods)."
            ),
        ]
    if c.warnings:
        out += [""] + [_wrap(f"warning: {w}") for w in c.warnings]
    if c.gates:
        out.append("")
        for g in c.gates:
            out.append(f"gate {g.gate.spec}  {'PASS' if g.passed else 'FAIL'}  {g.reason}")
        out.append("result: " + ("all gates passed" if c.passed else "GATE FAILED"))
    return "\n".join(out)


def format_markdown(c: Comparison) -> str:
    """The comparison as GitHub-flavoured Markdown (for a CI job summary or a pull-request comment)."""
    conf = f"{round((1 - c.alpha) * 100):d}% CI"
    status = "" if not c.gates else (" — all gates passed" if c.passed else " — **gate failed**")
    out = [
        f"### WOSAC realism: `{c.new_path}` vs `{c.base_path}`{status}",
        "",
        f"Paired over {c.num_shared} shared scenarios (config `{c.new_config}`); diff = new - base.",
        "",
        f"| metric | better if | base | new | diff | {conf} | p | verdict |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for m in c.metrics:
        ci = f"[{_fmt(m.ci_low, True)}, {_fmt(m.ci_high, True)}]" if m.paired else "-"
        p = m.p_holm if c.adjust == "holm" else m.p_value
        verdict = f"**{m.verdict}**" if m.verdict in (BETTER, WORSE) else m.verdict
        out.append(
            f"| `{m.metric}` | {'higher' if m.higher_is_better else 'lower'} | {_fmt(m.base)} | "
            f"{_fmt(m.new)} | {_fmt(m.difference, True)} | {ci} | {_fmt_p(p)} | {verdict} |"
        )
    if c.gates:
        out.append("")
        out += [f"- {'PASS' if g.passed else '**FAIL**'} `{g.gate.spec}`: {g.reason}" for g in c.gates]
    for w in c.warnings:  # one quote block each: consecutive quoted lines would merge into one paragraph
        out += ["", f"> warning: {w}"]
    return "\n".join(out) + "\n"
