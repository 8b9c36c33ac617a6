"""`wosac-eval plot` and the scene pictures of the report: what is drawn is what the metrics flagged."""

from __future__ import annotations

import io
import re

import numpy as np
import pytest
from PIL import Image

from support.browser import dump_dom, find_chromium
from support.runs import run_cli
from wosac_eval.arrays.messages import rollouts_from_arrays
from wosac_eval.results.scene_plot import animation_steps, scene_png, scene_view
from wosac_eval.sim import scenes


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Two synthetic scenes in one TFRecord and an IDM submission (.tar.gz)."""
    from wosac_eval.sim.baselines import make_submission

    folder = tmp_path_factory.mktemp("plot")
    generated = scenes.generate_scenes(2, seed=5)
    paths = scenes.write_scenario_shards(generated, folder / "scenarios", num_shards=1)
    submission = make_submission(paths, "idm", folder / "idm.tar.gz", num_shards=1)
    ids = [s.scenario_id for s in generated]
    return paths[0], submission, ids


def log_replay_arrays(scenario):
    """The logged future of every sim agent, 32 times (sim agents challenge)."""
    from wosac_eval.arrays.scenario import scenario_arrays

    arrays = scenario_arrays(scenario)
    log = arrays.log.take_ids(arrays.sim_agent_ids).take_steps(slice(11, 91))
    repeat = lambda a: np.repeat(a[None], 32, axis=0)  # noqa: E731
    return arrays, [repeat(a) for a in (log.x, log.y, log.z, log.heading)]


def test_a_collision_is_marked_where_and_when_it_starts():
    scenario = scenes.generate_scene(7, 0, "dense_following")
    arrays, (x, y, z, heading) = log_replay_arrays(scenario)
    ids = arrays.sim_agent_ids
    evaluated = int(arrays.predicted_ids[0])
    a = int(np.flatnonzero(ids == evaluated)[0])
    b = (a + 1) % ids.size
    # Rollout 5: from simulated step 20 (logged step 31) on, the evaluated object sits on another one.
    x[5, a, 20:], y[5, a, 20:] = x[5, b, 20:], y[5, b, 20:]
    view = scene_view(scenario, rollouts_from_arrays(scenario.scenario_id, ids, x, y, z, heading))
    collisions = [e for e in view.events if e.kind == "collision" and e.object_id == evaluated]
    assert [(e.rollout, e.step) for e in collisions] == [(5, 31)]
    assert (collisions[0].x, collisions[0].y) == (float(x[5, a, 20]), float(y[5, a, 20]))
    image = Image.open(io.BytesIO(scene_png(view, step=31)))
    assert image.format == "PNG" and image.width >= 600


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_plot_writes_png_gif_and_html(tmp_path, files):
    scenarios, submission, ids = files
    common = ["--scenarios", str(scenarios), "--submission", str(submission), "--scenario", ids[1]]
    png = run_cli("plot", *common, "-o", str(tmp_path / "s.png"), "--step", "40")
    assert png.returncode == 0, png.stderr
    assert f"scenario {ids[1]}" in png.stdout
    assert Image.open(tmp_path / "s.png").format == "PNG"
    gif = run_cli("plot", *common, "-o", str(tmp_path / "s.gif"), "--density", "--every", "5")
    assert gif.returncode == 0, gif.stderr
    with Image.open(tmp_path / "s.gif") as image:
        assert image.n_frames == len(animation_steps(5))
    page = run_cli("plot", *common, "-o", str(tmp_path / "s.html"), "--rollouts", "all")
    assert page.returncode == 0, page.stderr
    text = (tmp_path / "s.html").read_text()
    assert "http://" not in text and "https://" not in text  # self-contained
    events = int(re.search(r"<h2>Events \((\d+)\)</h2>", text).group(1))
    assert text.count("<tr><td>") == events


@pytest.mark.browser
@pytest.mark.skipif(find_chromium() is None, reason="no chromium on PATH (apt-get install chromium)")
def test_plot_page_steps_through_frames_in_a_browser(tmp_path, files):
    scenarios, submission, ids = files
    out = tmp_path / "s.html"
    done = run_cli(
        "plot",
        "--scenarios",
        str(scenarios),
        "--submission",
        str(submission),
        "--scenario",
        ids[0],
        "-o",
        str(out),
        "--every",
        "10",
    )
    assert done.returncode == 0, done.stderr
    dom = dump_dom(out)
    # The script ran: the frame shows a PNG and the label names its step.
    assert re.search(r'<img id="frame" alt="scene" src="data:image/png;base64,', dom)
    assert re.search(r'<span id="step-label">step \d+</span>', dom)
    assert 'max="9"' in dom  # 0, 10, ..., 90: ten frames behind the slider


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_plot_mistakes_are_usage_errors(tmp_path, files):
    scenarios, submission, ids = files
    bad_suffix = run_cli("plot", "--scenarios", str(scenarios), "-o", str(tmp_path / "s.jpg"), "--scenario", ids[0])
    assert bad_suffix.returncode == 2 and ".png, .gif, .html" in bad_suffix.stderr
    ambiguous = run_cli("plot", "--scenarios", str(scenarios), "-o", str(tmp_path / "s.png"))
    assert ambiguous.returncode == 2 and "choose one with --scenario" in ambiguous.stderr
    unknown = run_cli("plot", "--scenarios", str(scenarios), "-o", str(tmp_path / "s.png"), "--scenario", "nope")
    assert unknown.returncode == 2 and ids[0] in unknown.stderr
    wrong = run_cli(
        "plot",
        "--scenarios",
        str(scenarios),
        "--submission",
        str(submission),
        "--scenario",
        ids[0],
        "--challenge",
        "scenario_gen",
        "-o",
        str(tmp_path / "s.png"),
    )
    assert wrong.returncode == 1 and "--challenge sim_agents" in wrong.stderr
    assert not (tmp_path / "s.png").exists()
    log_only = run_cli("plot", "--scenarios", str(scenarios), "--scenario", ids[0], "-o", str(tmp_path / "log.png"))
    assert log_only.returncode == 0, log_only.stderr


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_report_shows_the_worst_scenes(tmp_path, files):
    scenarios, submission, _ = files
    result = tmp_path / "r.json"
    assert (
        run_cli("score", "--scenarios", str(scenarios), "--submission", str(submission), "-o", str(result)).returncode
        == 0
    )
    import json

    scored = json.loads(result.read_text())["scenarios"]
    worst = min(scored, key=lambda s: s["metametric"])["scenario_id"]
    done = run_cli(
        "report",
        str(result),
        "--html",
        str(tmp_path / "r.html"),
        "--scenarios",
        str(scenarios),
        "--submission",
        str(submission),
        "--scenes",
        "1",
    )
    assert done.returncode == 0, done.stderr
    page = (tmp_path / "r.html").read_text()
    assert re.findall(r'<figure class="scene" data-scenario="([^"]+)">', page) == [worst]
    half = run_cli("report", str(result), "--html", str(tmp_path / "r2.html"), "--scenarios", str(scenarios))
    assert half.returncode == 2 and "go together" in half.stderr
