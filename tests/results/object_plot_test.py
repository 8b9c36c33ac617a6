"""`wosac-eval plot --object ID`: one evaluated object's rollouts against its log, with its feature time series."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from support.runs import run_cli
from wosac_eval.arrays.messages import rollouts_from_arrays
from wosac_eval.results.object_plot import object_png
from wosac_eval.sim import scenes


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Two synthetic scenes in one TFRecord and an IDM submission (.tar.gz)."""
    from wosac_eval.sim.baselines import make_submission

    folder = tmp_path_factory.mktemp("object-plot")
    generated = scenes.generate_scenes(2, seed=5)
    paths = scenes.write_scenario_shards(generated, folder / "scenarios", num_shards=1)
    submission = make_submission(paths, "idm", folder / "idm.tar.gz", num_shards=1)
    return paths[0], submission, generated[1]


def _image(data: bytes) -> Image.Image:
    image = Image.open(io.BytesIO(data))
    assert image.format == "PNG"
    return image


def test_object_picture_of_a_log_replay_with_a_collision():
    from wosac_eval.arrays.scenario import scenario_arrays

    scenario = scenes.generate_scene(7, 0, "dense_following")
    arrays = scenario_arrays(scenario)
    log = arrays.log.take_ids(arrays.sim_agent_ids).take_steps(slice(11, 91))
    x, y, z, heading = (np.repeat(a[None], 32, axis=0) for a in (log.x, log.y, log.z, log.heading))
    ids = arrays.sim_agent_ids
    evaluated = int(arrays.predicted_ids[0])
    a = int(np.flatnonzero(ids == evaluated)[0])
    b = (a + 1) % ids.size
    x[5, a, 20:], y[5, a, 20:] = x[5, b, 20:], y[5, b, 20:]  # rollout 5 collides from step 31
    rollouts = rollouts_from_arrays(scenario.scenario_id, ids, x, y, z, heading)
    image = _image(object_png(scenario, rollouts, evaluated))
    assert image.width >= 1200 and image.height >= 600
    pixels = np.asarray(image.convert("RGB"))
    assert (np.abs(pixels.astype(int) - (0xD1, 0x24, 0x2F)).sum(axis=-1) < 30).any()  # the collision's mark
    not_evaluated = next(int(i) for i in ids if int(i) not in arrays.evaluated_ids("sim_agents").tolist())
    with pytest.raises(ValueError, match="is not evaluated"):
        object_png(scenario, rollouts, not_evaluated)


@pytest.mark.slow  # over 4.5 s on 2 cores (--durations): the full run's, not the fast tier's
def test_plot_object_writes_a_png_and_refuses_mistakes(tmp_path, files):
    from wosac_eval.arrays.scenario import scenario_arrays

    scenarios, submission, scenario = files
    evaluated = int(scenario_arrays(scenario).evaluated_ids("sim_agents")[0])
    common = ["--scenarios", str(scenarios), "--scenario", scenario.scenario_id]
    done = run_cli(
        "plot", *common, "--submission", str(submission), "--object", str(evaluated), "-o", str(tmp_path / "o.png")
    )
    assert done.returncode == 0, done.stderr
    assert f"object {evaluated}" in done.stdout and "Warning" not in done.stderr
    _image((tmp_path / "o.png").read_bytes())
    for extra, message in (
        (["--submission", str(submission), "--object", "999999", "-o", str(tmp_path / "x.png")], "is not evaluated"),
        (["--object", str(evaluated), "-o", str(tmp_path / "x.png")], "--object needs --submission"),
        (["--submission", str(submission), "--object", str(evaluated), "-o", str(tmp_path / "x.gif")], "draws a .png"),
    ):
        refused = run_cli("plot", *common, *extra)
        assert refused.returncode == 2 and message in refused.stderr, refused.stderr
