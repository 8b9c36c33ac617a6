"""One evaluation resolved at the edge (`scoring.evaluation`): the rules every front shares."""

from __future__ import annotations

import pytest

from wosac_eval import challenges
from wosac_eval.fronts.cli import main
from wosac_eval.metrics.config import PRESET_NAMES, load_config
from wosac_eval.parse.limits import InputLimits
from wosac_eval.metrics.registry import Metric
from wosac_eval.options import Backend, Engine, Mask, MetadataChecks, Mode, Search
from wosac_eval.scoring.evaluation import RunOptions, evaluation_for, resolve_evaluation
from wosac_eval.scoring.submission import score_submission


@pytest.mark.parametrize("challenge, default", [("sim_agents", "2025"), ("scenario_gen", "scenario_gen_2025")])
def test_no_config_is_the_challenges_current_preset(challenge, default):
    evaluation = resolve_evaluation(challenge)
    assert evaluation.config_name == default
    assert evaluation.config == load_config(default)
    assert evaluation.spec == challenges.spec(challenge)
    assert evaluation.options.limits == InputLimits()


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


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        ({"challenge": "scenario-generation"}, "unknown challenge"),
        ({"config": "2026"}, "neither a preset"),
        ({"backend": "torch"}, "backend"),
        ({"engine": "slurm"}, "engine"),
        ({"select": "top:0"}, "--select"),
        ({"metadata_checks": "ignore"}, "metadata_checks"),
    ],
)
def test_each_bad_argument_is_one_sentence(kwargs, fragment):
    with pytest.raises(ValueError, match=fragment):
        resolve_evaluation(**kwargs)


def test_cli_refuses_a_preset_of_the_other_challenge_before_reading(tmp_path, capsys):
    submission = tmp_path / "s.binproto"
    submission.write_bytes(b"")
    code = main(
        [
            "score",
            "--scenarios",
            str(tmp_path / "none.tfrecord"),
            "--submission",
            str(submission),
            "--challenge",
            "scenario_gen",
            "--config",
            "2025",
        ]
    )
    err = capsys.readouterr().err
    assert code == 2
    assert "config '2025' is the sim_agents challenge's; the scenario_gen challenge's is 'scenario_gen_2025'" in err


@pytest.mark.parametrize(
    "choice, bad",
    [
        (Backend, "torch"),
        (Engine, "slurm"),
        (MetadataChecks, "ignore"),
        (Mode, "float16"),
        (Search, "gpu"),
        (Mask, "wheels"),
    ],
)
def test_every_choice_is_refused_in_one_sentence_naming_the_value_and_the_allowed_ones(choice, bad):
    with pytest.raises(ValueError) as error:
        choice.parse(bad)
    assert str(error.value) == f"unknown {choice.kind()} {bad!r}: choose one of {', '.join(choice.names())}"
    assert all(
        choice.parse(name) is member and str(member) == name == f"{member}"
        for name, member in zip(choice.names(), choice)
    )


def test_a_metric_with_a_mask_no_kernel_computes_is_refused():
    with pytest.raises(ValueError, match="unknown mask 'wheels': choose one of valid, speed, acceleration, vehicle"):
        Metric("toy", "kinematic", "linear_speed", False, "wheels")
    assert Metric("toy", "kinematic", "linear_speed", False, "speed").mask is Mask.SPEED


def test_run_options_are_checked_once_and_hold_members():
    options = RunOptions(backend="numpy", engine="local", metadata_checks="error", workers=3)
    assert (options.backend, options.engine, options.metadata_checks) == (
        Backend.NUMPY,
        Engine.LOCAL,
        MetadataChecks.ERROR,
    )
    assert resolve_evaluation("sim_agents", None, options).options is options
    assert resolve_evaluation("sim_agents", workers=3, metadata_checks="error").options == options
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="workers must be a whole number >= 1"):
            RunOptions(workers=bad)
    with pytest.raises(TypeError, match="not both"):
        resolve_evaluation("sim_agents", None, options, workers=2)
    with pytest.raises(TypeError, match="unexpected keyword argument 'worker'"):
        resolve_evaluation(worker=2)


def test_evaluation_and_arguments_that_disagree_are_refused_before_any_work(tmp_path):
    evaluation = resolve_evaluation("sim_agents", "2024", workers=2)
    missing = tmp_path / "none"  # never read: the refusal comes first
    with pytest.raises(ValueError) as error:
        score_submission(
            missing, missing, "2025", evaluation=evaluation, backend="numpy", workers=3, challenge="scenario_gen"
        )
    message = str(error.value)
    assert message.startswith("score_submission: evaluation= already decides the run, and ")
    assert (
        "challenge='scenario_gen' (it has 'sim_agents'); config='2025' (it has '2024'); workers=3 (it has 2)" in message
    )
    assert "backend" not in message  # the same as the evaluation's: no conflict
    with pytest.raises(ValueError, match=r"metadata_checks='error' \(it has 'warn'\)"):
        score_submission(missing, missing, evaluation=evaluation, metadata_checks="error")
    with pytest.raises(ValueError, match="unknown engine 'slurm'"):
        score_submission(missing, missing, evaluation=evaluation, engine="slurm")


def test_arguments_that_agree_with_the_evaluation_are_accepted():
    evaluation = resolve_evaluation("sim_agents", "2024", workers=2)
    agreed = evaluation_for(
        "score_submission",
        evaluation,
        "sim_agents",
        "2024",
        {"workers": 2, "backend": Backend.NUMPY, "limits": InputLimits()},
    )
    assert agreed is evaluation
