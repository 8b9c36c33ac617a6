"""The `compare` and `report` sub-commands through the real CLI dispatcher."""

import json
import subprocess

import pytest

from wosac_eval.fronts.cli import main
from wosac_eval.results.synthetic_results import result_json, synthetic_scenarios

from support.runs import WOSAC_EVAL

FAST = ["--n-boot", "300", "--n-perm", "300"]


@pytest.fixture()
def results(tmp_path):
    def write(name, **kwargs):
        sl = kwargs.pop("keep", slice(None))
        path = tmp_path / name
        path.write_text(json.dumps(result_json(synthetic_scenarios(120, seed=0, **kwargs)[sl])))
        return str(path)

    return write


def test_compare_identical_exits_0_with_table(results, capsys):
    base = results("base.json")
    assert main(["compare", base, base, *FAST, "--fail-if-worse", "metametric:0"]) == 0
    out = capsys.readouterr().out
    assert "paired over 120 shared scenarios" in out and "all gates passed" in out


def test_compare_failed_gate_exits_1(results, capsys):
    base = results("base.json")
    new = results("new.json", shift={"metametric": -0.01})
    assert main(["compare", base, new, *FAST, "--fail-if-worse", "metametric:0.005"]) == 1
    assert "GATE FAILED" in capsys.readouterr().out
    assert main(["compare", base, new, *FAST, "--fail-if-worse", "metametric:0.02"]) == 0


def test_compare_json_output(results, capsys):
    base = results("base.json")
    new = results("new.json", shift={"simulated_offroad_rate": 0.02}, keep=slice(10, None))
    code = main(
        [
            "compare",
            base,
            new,
            *FAST,
            "--json",
            "--metric",
            "simulated_offroad_rate",
            "--fail-if-worse",
            "simulated_offroad_rate:0.01",
        ]
    )
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert code == 1 and out["passed"] is False
    assert [m["metric"] for m in out["metrics"]] == ["simulated_offroad_rate"]
    assert out["metrics"][0]["verdict"] == "worse"
    assert out["scenarios"] == {"shared": 110, "base_only": 10, "new_only": 0}
    assert "warning: the scenario sets differ" in captured.err


@pytest.mark.parametrize(
    "make_args, message",
    [
        (lambda b, n, d: [b, d], "share no scenario"),
        (lambda b, n, d: [b, b + ".missing"], "no such file"),
        (lambda b, n, d: [b, n, "--fail-if-worse", "metametric"], "expected METRIC:DELTA"),
        (lambda b, n, d: [b, n, "--metric", "realism"], "unknown metric 'realism'"),
        (lambda b, n, d: [b, n, "--min-shared", "1000"], "fewer than --min-shared 1000"),
    ],
)
def test_compare_cannot_compare_exits_2(results, capsys, make_args, message):
    base, new = results("base.json"), results("new.json")
    disjoint = results("other.json", id_prefix="other")
    assert main(["compare", *make_args(base, new, disjoint), *FAST]) == 2
    err = capsys.readouterr().err
    assert "wosac-eval compare: error:" in err and message in err


def test_compare_exit_code_of_the_real_process(results):
    base = results("base.json")
    new = results("new.json", shift={"collision_indication_likelihood": -0.1})
    proc = subprocess.run(
        [
            *WOSAC_EVAL,
            "compare",
            base,
            new,
            *FAST,
            "--fail-if-worse",
            "collision_indication_likelihood:0.05",
        ],
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 1, proc.stderr
    assert "collision_indication_likelihood" in proc.stdout and "FAIL" in proc.stdout


def test_report_command_writes_html(results, tmp_path, capsys):
    base = results("base.json")
    new = results("new.json", shift={"metametric": 0.01})
    html_path = tmp_path / "report.html"
    assert main(["report", new, "--compare", base, "--html", str(html_path), *FAST, "--top", "3"]) == 0
    page = html_path.read_text()
    assert 'id="comparison"' in page and page.count("<details") >= 10
    assert f"wrote {html_path}" in capsys.readouterr().out


def test_report_command_errors_exit_2(results, tmp_path, capsys):
    assert main(["report", str(tmp_path / "none.json"), "--html", str(tmp_path / "r.html")]) == 2
    assert "no such file" in capsys.readouterr().err
    base = results("base.json")
    assert main(["report", base, "--html", str(tmp_path / "missing-dir" / "r.html")]) == 2
    assert "cannot write" in capsys.readouterr().err


def test_compare_markdown_output_and_comma_separated_metrics(results, tmp_path, capsys):
    base = results("base.json")
    new = results("new.json", shift={"metametric": 0.02})
    md = tmp_path / "comparison.md"
    assert (
        main(
            [
                "compare",
                base,
                new,
                *FAST,
                "--metric",
                "metametric,min_ade",
                "--markdown-output",
                str(md),
                "--fail-if-worse",
                "metametric:1%",
            ]
        )
        == 0
    )
    lines = md.read_text().splitlines()
    rows = [line for line in lines if line.startswith("| `")]
    assert [r.split("|")[1].strip() for r in rows] == ["`metametric`", "`min_average_displacement_error`"]
    assert "**better**" in rows[0] and "+0.0200" in rows[0]
    assert "- PASS `metametric:1%`: not worse (change +0.02)" in lines
    assert "metametric" in capsys.readouterr().out  # the table still goes to stdout
