"""One evaluation resolved at the edge (`scoring.evaluation`): the rules every front shares."""
from __future__ import annotations

import pytest

from wosac_eval import challenges
from wosac_eval.fronts.cli import main
from wosac_eval.metrics.config import PRESET_NAMES, load_config
from wosac_eval.parse.limits import InputLimits
from wosac_eval.scoring.evaluation import resolve_evaluation


@pytest.mark.parametrize("challenge, default", [("sim_agents", "2025"), ("scenario_gen", "scenario_gen_2025")])
def test_no_config_is_the_challenges_current_preset(challenge, default):
    evaluation = resolve_evaluation(challenge)
    assert evaluation.config_name == default
    assert evaluation.config == load_config(default)
    assert evaluation.spec == challenges.spec(challenge)
    assert evaluation.limits == InputLimits()


def test_every_preset_belongs_to_one_challenge():
    for name in PRESET_NAMES:
        fits = [c for c in challenges.CHALLENGE_NAMES if _fits(c, name)]
        assert len(fits) == 1, (name, fits)


def _fits(challenge: str, name: str) -> bool:
    try:
        resolve_evaluation(challenge, name)
    except ValueError as error:
        assert f"config {name!r} is the" in str(error) and "challenge's is" in str(error)
        return False
    return True


def test_a_textproto_serves_either_challenge(tmp_path):
    from google.protobuf import text_format

    path = tmp_path / "mine.textproto"
    path.write_text(text_format.MessageToString(load_config("2024")))
    for challenge in challenges.CHALLENGE_NAMES:
        assert resolve_evaluation(challenge, path).config_name == str(path)


@pytest.mark.parametrize("kwargs, fragment", [
    ({"challenge": "scenario-generation"}, "unknown challenge"),
    ({"config": "2026"}, "neither a preset"),
    ({"backend": "torch"}, "backend"),
    ({"engine": "slurm"}, "engine"),
    ({"select": "top:0"}, "--select"),
    ({"metadata_checks": "ignore"}, "metadata_checks"),
])
def test_each_bad_argument_is_one_sentence(kwargs, fragment):
    with pytest.raises(ValueError, match=fragment):
        resolve_evaluation(**kwargs)


def test_cli_refuses_a_preset_of_the_other_challenge_before_reading(tmp_path, capsys):
    submission = tmp_path / "s.binproto"
    submission.write_bytes(b"")
    code = main(["score", "--scenarios", str(tmp_path / "none.tfrecord"), "--submission", str(submission),
                 "--challenge", "scenario_gen", "--config", "2025"])
    err = capsys.readouterr().err
    assert code == 2
    assert "config '2025' is the sim_agents challenge's; the scenario_gen challenge's is 'scenario_gen_2025'" in err
