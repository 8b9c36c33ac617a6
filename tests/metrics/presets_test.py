"""The presets are data: one textproto file each, laid out under the root of `wosac_eval.compat` as the
official package lays out its own, where programs written for the official package open them."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from google.protobuf import text_format

import wosac_eval
import wosac_eval.compat
from wosac_eval.compat import metrics as compat_metrics
from wosac_eval.metrics.config import PRESET_FILES, SimAgentMetricsConfig, load_config, preset_path, with_defaults

from support.paths import SHARED

OFFICIAL = SHARED / "official-configs"
# Where waymo-open-dataset (1.6.7 and its repository) keeps each preset, relative to its package root.
OFFICIAL_PLACES = {
    "2025": "wdl_limited/sim_agents_metrics/challenge_2025_sim_agents_config.textproto",
    "2024": "wdl_limited/sim_agents_metrics/challenge_2024_config.textproto",
    "2023": "wdl_limited/sim_agents_metrics/legacy_configs/challenge_2023_config.textproto",
    "scenario_gen_2025": "wdl_limited/sim_agents_metrics/challenge_2025_scenario_gen_config.textproto",
}


@pytest.mark.parametrize("name", sorted(PRESET_FILES))
def test_each_preset_is_the_official_file(name):
    if not OFFICIAL.is_dir():
        pytest.skip(f"reference data {OFFICIAL} is absent (the official configs are needed)")
    official = text_format.Parse((OFFICIAL / preset_path(name).name).read_text(), SimAgentMetricsConfig())
    assert load_config(name) == with_defaults(official)


@pytest.mark.parametrize("name", sorted(PRESET_FILES))
def test_presets_lie_where_official_programs_look(name):
    # A program written for the official package joins the relative path to the package root.
    at_root = Path(os.path.join(wosac_eval.compat.__path__[0], OFFICIAL_PLACES[name]))
    assert at_root.is_file() and not at_root.is_symlink()
    assert at_root.resolve() == preset_path(name).resolve()  # the library's loader reads this very file
    assert load_config(str(at_root)) == load_config(name)  # --config FILE reads the same


def test_each_preset_file_is_in_the_package_once():
    package = Path(wosac_eval.__path__[0])
    found = sorted(str(p.relative_to(package)) for p in package.rglob("*.textproto") if "testdata" not in p.parts)
    assert found == sorted(f"compat/{place}" for place in OFFICIAL_PLACES.values())


def test_the_configs_load_from_any_working_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the official loader opens a path relative to the working folder; ours does not
    for challenge in compat_metrics.ChallengeType:
        config = compat_metrics.load_metrics_config(challenge)
        assert config == load_config({"sim_agents": "2025", "scenario_gen": "scenario_gen_2025"}[challenge.value])


def test_a_preset_is_a_fresh_message_each_time():
    first, untouched = load_config("2025"), load_config("2025")
    first.linear_speed.metametric_weight = 1.0
    assert load_config("2025") == untouched != first


def test_a_binary_file_as_config_names_the_file(tmp_path):
    path = tmp_path / "weights.bin"
    path.write_bytes(bytes(range(256)))
    with pytest.raises(ValueError, match="weights.bin: not a SimAgentMetricsConfig textproto"):
        load_config(str(path))
