"""The Markdown writer of `benchmarks/speed_report.py` (docs/speed.md), on fake figures: nothing is timed."""
import sys

from support.paths import REPO

sys.path.insert(0, str(REPO / "benchmarks"))
import speed_report  # noqa: E402

WHERE = {"cpu": "Test CPU, 2 cores", "python": "3.11.7", "system": "Linux x86_64", "date": "2026-11-28 03:00 UTC"}


def _section(key: str, figures: str) -> str:
    return speed_report.section_markdown(key, f"Title of {key}", f"python benchmarks/{key}.py --repeat 3", "abc1234",
                                         WHERE, 12.4, figures)


def test_a_section_states_its_command_commit_machine_and_figures():
    text = _section("objects", "agents evaluated s/scenario\n    16         4      0.049\n")
    assert text.startswith("<!-- speed-report: objects -->\n### Title of objects\n")
    assert text.endswith("<!-- /speed-report: objects -->\n")
    assert ("Command: `python benchmarks/objects.py --repeat 3` · commit `abc1234` · Test CPU, 2 cores · "
            "Python 3.11.7 · Linux x86_64 · 2026-11-28 03:00 UTC (12 s)") in text
    assert "```text\nagents evaluated s/scenario\n    16         4      0.049\n```\n" in text


def test_sections_replace_their_own_part_and_keep_the_rest():
    document = ("# Speed\n\nHow to regenerate.\n\n" + _section("one", "old one\n") + "\nProse between.\n\n"
                + _section("two", "old two\n"))
    updated = speed_report.replace_sections(document, {"two": _section("two", "new two\n"),
                                                       "three": _section("three", "new three\n")})
    assert updated.startswith("# Speed\n\nHow to regenerate.\n\n" + _section("one", "old one\n") + "\nProse between.\n")
    assert "old two" not in updated and updated.count("new two") == 1
    assert updated.endswith("\n\n" + _section("three", "new three\n"))
    assert speed_report.replace_sections(updated, {"two": _section("two", "new two\n")}) == updated


def test_one_core_sections_show_their_environment_and_every_key_is_unique():
    every = speed_report.sections("7", ["100"])
    assert len({s.key for s in every}) == len(every) and len({s.title for s in every}) == len(every)
    one = next(s for s in every if s.key == "one-scenario")
    assert speed_report.command_line(one) == ("OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 "
                                              "python benchmarks/score_speed.py --repeat 7")
    assert all((speed_report.HERE / s.script).exists() for s in every)
