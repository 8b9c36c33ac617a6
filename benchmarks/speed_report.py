"""The speed report in one run: the figures of docs/speed.md, each with its command, commit and machine.

Sections run by default (each measured in this run, side by side where compared):
  one-scenario  one real scenario (637f20cafde22ff8, its official 32-rollout submission)
                on one core, steady state, with the stage breakdown (score_speed.py);
  objects       cost against the number of objects and of evaluated objects (score_objects.py);
  workers       whole submissions through `score_submission` (validation included) with 1 and
                2 worker processes: seconds per scenario, speed-up, peak RSS, identical results
                (score_scaling.py);
  backends      numpy against jax on this machine (score_backends.py), when JAX is installed.
The others of SECTIONS run when named with --with (the official evaluator side by side, Scenario
Generation, validation, the comparison gate, the analysis, Ray, jax_realism, the allocator, and
the validation-size runs of full_scale.py, which take hours and tens of GiB of disk).
Each section runs in its own process, so one section's memory or threads do not colour another's.
Needs ../shared (the real scenario and submission).

With --markdown FILE (docs/speed.md), every section that ran to exit 0 replaces its part of FILE
(between `<!-- speed-report: KEY -->` and `<!-- /speed-report: KEY -->`, appended when absent):
its title, the command, the git commit, the machine (CPU model, cores, Python, system), the date,
and the figures as the script printed them. Sections not run, or failed, keep what FILE holds.

Usage:
  python benchmarks/speed_report.py [--sizes 100 500] [--repeat 15] [--skip objects backends]
                                    [--with side-by-side scenario-gen ...] [--markdown docs/speed.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib.util
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ONE_CORE = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


@dataclasses.dataclass(frozen=True)
class Section:
    key: str  # its marker in the Markdown file
    title: str  # its heading there (docs link to the heading's anchor)
    script: str  # in benchmarks/
    args: tuple[str, ...] = ()
    one_core: bool = False
    default: bool = True  # run without --with
    needs: str = ""  # a module that must be importable


def sections(repeat: str, sizes: list[str]) -> tuple[Section, ...]:
    """Every section the report knows, in the order they run: those it runs by default, then the others."""
    return _default_sections(repeat, sizes) + _optional_sections(repeat)


def _default_sections(repeat: str, sizes: list[str]) -> tuple[Section, ...]:
    """The sections run without --with: one scenario, objects, workers, the backends."""
    return (
        Section("one-scenario", "One scenario on one core", "score_speed.py", ("--repeat", repeat), one_core=True),
        Section("objects", "Cost against objects and evaluated objects", "score_objects.py", one_core=True),
        Section(
            "workers",
            "Whole submissions: workers and peak memory",
            "score_scaling.py",
            ("--sizes", *sizes, "--workers", "1", "2"),
            one_core=True,
        ),
        Section("backends", "numpy against JAX on the CPU", "score_backends.py", needs="jax"),
    )


def _optional_sections(repeat: str) -> tuple[Section, ...]:
    """The sections run only when --with names them (longer, or needing an extra)."""
    return (
        Section(
            "allocator",
            "The allocator",
            "score_speed.py",
            ("--repeat", repeat, "--system-malloc"),
            one_core=True,
            default=False,
        ),
        Section(
            "side-by-side",
            "Sim Agents side by side with the official evaluator",
            "official_side_by_side.py",
            ("--repeat", "3", "--official-one-core"),
            default=False,
        ),
        Section(
            "scenario-gen",
            "Scenario Generation: one scene on one core",
            "scenario_gen_speed.py",
            ("--repeat", "7"),
            one_core=True,
            default=False,
        ),
        Section(
            "side-by-side-scenario-gen",
            "Scenario Generation side by side with the official evaluator",
            "official_side_by_side.py",
            ("--challenge", "scenario_gen", "--repeat", "3", "--official-one-core"),
            default=False,
        ),
        Section("analysis", "What the analysis costs", "analysis_cost.py", default=False),
        Section(
            "validate",
            "Validation throughput and memory",
            "validate_throughput.py",
            ("--scenarios", "100"),
            default=False,
        ),
        Section("gate", "Compare and report at the size of the test set", "bench_gate.py", default=False),
        Section("ray", "Ray scaling", "ray_scaling.py", ("--scenarios", "48"), default=False, needs="ray"),
        Section(
            "jax-realism",
            "JAX realism in a training loop",
            "jax_realism_speed.py",
            ("--scenes", "16,64", "--repeat", "3"),
            default=False,
            needs="jax",
        ),
        Section(
            "jax-programs",
            "JAX: a first run and a later one",
            "jax_program_cache.py",
            default=False,
            needs="jax",
        ),
        Section(
            "full-scale",
            "The whole validation set",
            "full_scale.py",
            ("--paths", "validate,cli,service"),
            default=False,
        ),
        Section(
            "full-scale-scenario-gen",
            "Scenario Generation at 4,000 scenes",
            "full_scale.py",
            ("--challenge", "scenario_gen", "--scenes", "4000", "--paths", "validate,cli"),
            default=False,
        ),
        Section(
            "full-scale-interrupt",
            "An interrupted run",
            "full_scale.py",
            ("--scenes", "4000", "--paths", "cli,interrupt"),
            default=False,
        ),
    )


def command_line(section: Section) -> str:
    """The command as a reader types it, with the one-core environment when it has one."""
    env = "".join(f"{name}={value} " for name, value in ONE_CORE.items()) if section.one_core else ""
    return " ".join([f"{env}python benchmarks/{section.script}", *section.args])


def git_commit(repo: Path) -> str:
    """The short commit of the tree, `+changes` when it differs from that commit; `unknown` outside git."""

    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True).stdout.strip()

    try:
        commit = git("rev-parse", "--short", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except OSError:
        return "unknown"
    return (commit + ("+changes" if dirty else "")) if commit else "unknown"


def cpu_model() -> str:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or platform.machine()
    found = re.search(r"^model name\s*:\s*(.+)$", text, re.M)
    return found.group(1).strip() if found else platform.machine()


def machine() -> dict[str, str]:
    """Where the figures come from: CPU model and cores, Python, system, date (UTC)."""
    return {
        "cpu": f"{cpu_model()}, {os.cpu_count()} cores",
        "python": platform.python_version(),
        "system": f"{platform.system()} {platform.machine()}",
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    }


def section_markdown(
    key: str, title: str, command: str, commit: str, where: dict[str, str], seconds: float, output: str
) -> str:
    """One section of the Markdown file, markers included: what was run, where, and what it printed."""
    return (
        f"<!-- speed-report: {key} -->\n### {title}\n\n"
        f"Command: `{command}` · commit `{commit}` · {where['cpu']} · Python {where['python']} · "
        f"{where['system']} · {where['date']} ({seconds:.0f} s)\n\n"
        f"```text\n{output.rstrip()}\n```\n<!-- /speed-report: {key} -->\n"
    )


def replace_sections(document: str, rendered: dict[str, str]) -> str:
    """`document` with each rendered section in place of its marked part, or appended when it has none."""
    for key, text in rendered.items():
        marked = re.compile(
            rf"<!-- speed-report: {re.escape(key)} -->\n.*?<!-- /speed-report: {re.escape(key)} -->\n", re.S
        )
        if marked.search(document):
            document = marked.sub(lambda _: text, document, count=1)
        else:
            document = document.rstrip("\n") + "\n\n" + text
    return document


NEW_DOCUMENT = """# Speed

Generated by `python benchmarks/speed_report.py --markdown docs/speed.md` (`--with KEY ...` for the
sections that do not run by default): each section holds the figures as its command printed them,
with the commit and the machine they were measured on.
"""


def _run(section: Section) -> tuple[int, str, float]:
    """Run one section's script, echoing its output as it comes; (exit status, output, seconds)."""
    print(f"\n== {section.title} ==\n$ {command_line(section)}", flush=True)
    start = time.perf_counter()
    process = subprocess.Popen(
        [sys.executable, str(HERE / section.script), *section.args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **(ONE_CORE if section.one_core else {})},
    )
    lines = []
    assert process.stdout is not None
    for line in process.stdout:
        print(line, end="", flush=True)
        lines.append(line)
    code = process.wait()
    seconds = time.perf_counter() - start
    print(f"({seconds:.0f} s)", flush=True)
    return code, "".join(lines), seconds


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", nargs="+", default=["100", "500"], help="submission sizes of the workers section")
    p.add_argument("--repeat", default="15", help="runs of the single-scenario measurement")
    p.add_argument(
        "--skip",
        nargs="*",
        default=[],
        choices=[s.key for s in sections("15", ["100"]) if s.default] + ["scenario", "jax"],
        help="default sections to leave out (their keys, as --with names the others; `scenario` and `jax` are "
        "one-scenario and backends)",
    )
    every = sections("15", ["100"])
    p.add_argument(
        "--with",
        dest="extra",
        nargs="*",
        default=[],
        choices=[s.key for s in every if not s.default],
        help="sections to run beside the default ones",
    )
    p.add_argument("--markdown", type=Path, help="write the figures into this Markdown file (docs/speed.md)")
    args = p.parse_args()
    skipped = {{"scenario": "one-scenario", "jax": "backends"}.get(name, name) for name in args.skip}
    chosen = [
        s for s in sections(args.repeat, args.sizes) if (s.default and s.key not in skipped) or s.key in args.extra
    ]
    where, commit = machine(), git_commit(HERE.parent)
    print(f"machine: {where['cpu']}; python {where['python']}; commit {commit}")
    failed, rendered = 0, {}
    for section in chosen:
        if section.needs and importlib.util.find_spec(section.needs) is None:
            print(f"\n== {section.title} ==\nskipped: {section.needs} is not installed")
            continue
        code, output, seconds = _run(section)
        failed |= code
        if code == 0:
            rendered[section.key] = section_markdown(
                section.key, section.title, command_line(section), commit, where, seconds, output
            )
    if args.markdown:
        document = args.markdown.read_text() if args.markdown.exists() else NEW_DOCUMENT
        args.markdown.write_text(replace_sections(document, rendered))
        print(f"\n{len(rendered)} section(s) written to {args.markdown}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
