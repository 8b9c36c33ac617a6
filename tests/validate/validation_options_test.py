"""`validate_submission` takes its options as one `ValidationOptions`, or by name: the same report."""

from __future__ import annotations

import pytest

from wosac_eval.parse.limits import InputLimits
from wosac_eval.sim import baselines, scenes
from wosac_eval.validate import ValidationOptions, validate_submission


@pytest.fixture(scope="module")
def scene_and_submission(tmp_path_factory):
    folder = tmp_path_factory.mktemp("options")
    paths = scenes.write_scenario_shards(scenes.generate_scenes(2, seed=3), folder / "scenarios", num_shards=1)
    return paths, baselines.make_submission(paths, "constant_velocity", folder / "cv.tar.gz", num_shards=1)


def _judged(report) -> dict:
    """The report without its timing."""
    data = report.to_dict(include_skipped=True)
    del data["stats"]["elapsed_s"], data["stats"]["scenarios_per_s"]
    return data


def test_options_by_name_or_as_one_object_judge_alike(scene_and_submission):
    paths, submission = scene_and_submission
    limits = InputLimits(max_total_bytes=64 << 10)
    named = validate_submission(paths, submission, challenge="scenario_gen", limits=limits, max_listed=1)
    given = validate_submission(
        paths, submission, ValidationOptions(challenge="scenario_gen", limits=limits, max_listed=1)
    )
    assert _judged(named) == _judged(given)
    assert not named.ok and named.challenge == "scenario_gen" and named.count("container.size_limit") == 1
    assert _judged(validate_submission(paths, submission)) == _judged(
        validate_submission(paths, submission, ValidationOptions())
    )


def test_a_bad_option_is_refused_before_any_work(scene_and_submission):
    paths, submission = scene_and_submission
    with pytest.raises(TypeError, match="unexpected keyword argument 'max_listing'"):
        validate_submission(paths, submission, max_listing=3)
    with pytest.raises(TypeError, match="not both"):
        validate_submission(paths, submission, ValidationOptions(), challenge="sim_agents")
    with pytest.raises(ValueError, match="metadata_checks must be one of error, warn, not 'loud'"):
        ValidationOptions(metadata_checks="loud")
    with pytest.raises(ValueError, match="max_listed must be >= 0"):
        ValidationOptions(max_listed=-1)
    with pytest.raises(ValueError, match="scenario_gen"):
        ValidationOptions(challenge="scenario_generation")
