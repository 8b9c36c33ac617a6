"""The presets are data: textproto files beside the metrics module, and beside the compat metrics module
where programs written for the official package open them."""

from __future__ import annotations

from pathlib import Path

import pytest
from google.protobuf import text_format

from wosac_eval.compat import metrics as compat_metrics
from wosac_eval.metrics import config
from wosac_eval.metrics.config import PRESET_FILES, SimAgentMetricsConfig, load_config, with_defaults

from support.paths import SHARED

OFFICIAL = SHARED / "official-configs"


@pytest.mark.parametrize("name", sorted(PRESET_FILES))
def test_each_preset_is_the_official_file(name):
    if not OFFICIAL.is_dir():
        pytest.skip(f"reference data {OFFICIAL} is absent (the official configs are needed)")
    official = text_format.Parse((OFFICIAL / PRESET_FILES[name]).read_text(), SimAgentMetricsConfig())
    assert load_config(name) == with_defaults(official)


@pytest.mark.parametrize("name", sorted(PRESET_FILES))
def test_presets_lie_where_official_programs_look(name):
    beside_ours = Path(config.__file__).with_name(PRESET_FILES[name])
    beside_compat = Path(compat_metrics.__file__).parent / PRESET_FILES[name]
    assert beside_compat.read_bytes() == beside_ours.read_bytes()
    assert load_config(str(beside_compat)) == load_config(name)  # --config FILE reads the same


def test_a_preset_is_a_fresh_message_each_time():
    first, untouched = load_config("2025"), load_config("2025")
    first.linear_speed.metametric_weight = 1.0
    assert load_config("2025") == untouched != first


def test_a_binary_file_as_config_names_the_file(tmp_path):
    path = tmp_path / "weights.bin"
    path.write_bytes(bytes(range(256)))
    with pytest.raises(ValueError, match="weights.bin: not a SimAgentMetricsConfig textproto"):
        load_config(str(path))
