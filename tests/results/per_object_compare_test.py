"""`wosac-eval compare BASE.json NEW.json --per-object`: objects matched by (scenario_id, object_id), and the
object type x criticality strata that changed most, with paired intervals over scenes.

Two small real runs: the real WOMD scene 637f20cafde22ff8 scored for two golden policies (skipped without
../shared), and the demo's synthetic scenes for two baselines (strata over several scenes).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from support.paths import SHARED
from wosac_eval.fronts.cli import main
from wosac_eval.metrics.registry import LIKELIHOOD_FIELDS
from wosac_eval.results import stats
from wosac_eval.results.per_object_compare import (
    OBJECT_METAMETRIC,
    PerObjectError,
    compare_objects,
    format_objects,
    load_objects,
)
from wosac_eval.results.stats import PairedSettings
from wosac_eval.scoring.result_reader import load_result

SCENARIO = SHARED / "womd" / "motion_data_one_scenario.tfrecord"
GOLDEN = SHARED / "golden"


def _score(scenarios, submission, output) -> None:
    assert (
        main(
            ["score", "--scenarios", str(scenarios), "--submission", str(submission), "--per-object", "-o", str(output)]
        )
        == 0
    )


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    if not SCENARIO.is_file() or not GOLDEN.is_dir():
        pytest.skip(f"reference material not found at {SHARED} (womd/ and golden/)")
    out = tmp_path_factory.mktemp("real")
    for policy in ("logreplay_noise05", "stationary"):
        _score(SCENARIO, GOLDEN / f"637f20cafde22ff8__{policy}.binproto", out / f"{policy}.json")
    return out / "logreplay_noise05.json", out / "stationary.json"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from wosac_eval.fronts.demo_pipeline import run_demo

    workdir = tmp_path_factory.mktemp("demo")
    run_demo(
        workdir, num_scenes=6, policies=("constant_velocity", "idm"), challenge="sim_agents", log=lambda *a, **k: None
    )
    for policy in ("constant_velocity", "idm"):
        _score(workdir / "scenarios", workdir / "submissions" / f"{policy}.tar.gz", workdir / f"{policy}.json")
    return workdir / "constant_velocity.json", workdir / "idm.json"


def test_real_runs_objects_changes_are_the_objects_values(real, capsys):
    base_path, new_path = real
    base, new = load_result(base_path), load_result(new_path)
    comparison = compare_objects(base, new, settings=PairedSettings(n_boot=200, n_perm=200))
    b, n = load_objects(base), load_objects(new)
    assert comparison.num_matched == len(b) == len(n) and comparison.num_base_only == 0
    index = {int(o): i for i, o in enumerate(n.object_id)}
    assert {o.object_id for o in comparison.objects} == set(b.object_id.tolist())  # 4 objects: all listed
    for change in comparison.objects:
        i, j = b.object_id.tolist().index(change.object_id), index[change.object_id]
        assert change.difference == pytest.approx(n.values[OBJECT_METAMETRIC][j] - b.values[OBJECT_METAMETRIC][i])
        moved = {f: n.values[f][j] - b.values[f][i] for f in LIKELIHOOD_FIELDS}
        assert change.most_changed_difference == pytest.approx(
            max((d for d in moved.values() if np.isfinite(d)), key=abs)
        )
    # One scene: a stratum's difference is the mean of its objects' differences. A stationary policy's
    # speeds are far from the log's: the moving objects' speed likelihoods drop.
    speed = next(
        s
        for s in comparison.strata
        if s.object_type == "vehicle" and s.criticality == "all" and s.metric == "linear_speed_likelihood"
    )
    vehicles = b.object_type == "vehicle"
    drops = n.values["linear_speed_likelihood"][vehicles] - b.values["linear_speed_likelihood"][vehicles]
    assert speed.num_scenarios == 1 and speed.difference == pytest.approx(drops.mean())
    assert drops.max() <= 0 < -drops.min()
    capsys.readouterr()
    assert (
        main(["compare", str(base_path), str(new_path), "--per-object", "--json", "--n-boot", "200", "--n-perm", "200"])
        == 0
    )
    out = json.loads(capsys.readouterr().out)["per_object"]
    assert out["objects"]["matched"] == len(b) and out["changed_strata"][0]["label"]


@pytest.mark.slow  # over 2 s in the full run (--durations): out of the fast tier
def test_demo_strata_are_paired_tests_over_scenes(demo, capsys):
    base_path, new_path = demo
    base, new = load_result(base_path), load_result(new_path)
    comparison = compare_objects(base, new, top=200, settings=PairedSettings(seed=3, n_boot=500, n_perm=500))
    assert comparison.num_tests == len(comparison.strata) > 10
    b, n = load_objects(base), load_objects(new)
    # Recompute one stratum by hand: vehicles over every scene, the objects' meta-metric.
    stratum = next(
        s
        for s in comparison.strata
        if s.object_type == "vehicle" and s.criticality == "all" and s.metric == OBJECT_METAMETRIC
    )
    vehicles = b.object_type == "vehicle"
    scenes = sorted(set(b.scenario_id[vehicles]))
    per_scene = [
        (
            b.values[OBJECT_METAMETRIC][vehicles & (b.scenario_id == s)].mean(),
            n.values[OBJECT_METAMETRIC][vehicles & (n.scenario_id == s)].mean(),
        )
        for s in scenes
    ]
    pairs = np.array(per_scene)
    test = stats.paired_test(pairs[:, 0], pairs[:, 1], seed=3, n_boot=500, n_perm=500)
    assert stratum.num_scenarios == len(scenes) and stratum.num_objects == int(vehicles.sum())
    assert stratum.difference == pytest.approx(test.mean_difference[0])
    assert (stratum.ci_low, stratum.ci_high) == pytest.approx((test.ci_low[0], test.ci_high[0]))
    assert {s.criticality for s in comparison.strata} >= {"all", "low", "mid", "high", "long tail"}
    # Significant strata come first, then by the size of the change.
    significant = [s.p_value < 0.05 for s in comparison.strata]
    assert significant == sorted(significant, reverse=True)
    for group in (True, False):
        sizes = [abs(s.difference) for s, g in zip(comparison.strata, significant) if g == group]
        assert sizes == sorted(sizes, reverse=True)
    text = format_objects(
        compare_objects(base, new, top=5, settings=PairedSettings(n_boot=200, n_perm=200), metrics=["metametric"])
    )
    assert "vehicles" in text and "strata that changed most" in text and "95% CI" in text
    capsys.readouterr()
    assert (
        main(
            [
                "compare",
                str(base_path),
                str(new_path),
                "--per-object",
                "--metric",
                "metametric,collision_indication_likelihood",
                "--top",
                "3",
                "--n-boot",
                "200",
                "--n-perm",
                "200",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "objects that changed most" in printed and "collision_indication_likelihood" in printed
    markdown = base_path.parent / "summary.md"
    assert (
        main(
            [
                "compare",
                str(base_path),
                str(new_path),
                "--per-object",
                "--top",
                "3",
                "--n-boot",
                "200",
                "--n-perm",
                "200",
                "--markdown-output",
                str(markdown),
            ]
        )
        == 0
    )
    text = markdown.read_text()
    assert "#### Per object: the strata that changed most" in text and text.count("| `synthetic-") == 6


@pytest.mark.slow  # its module's fixture scores the demo's policies first (6 s): out of the fast tier
def test_results_without_objects_are_refused(demo, tmp_path, capsys):
    base_path, new_path = demo
    plain = tmp_path / "plain.json"
    document = json.loads(base_path.read_text())
    document.pop("per_object")
    plain.write_text(json.dumps(document))
    with pytest.raises(PerObjectError, match="score --per-object"):
        compare_objects(load_result(plain), load_result(new_path))
    assert main(["compare", str(plain), str(new_path), "--per-object"]) == 2
    assert "--per-object" in capsys.readouterr().err
