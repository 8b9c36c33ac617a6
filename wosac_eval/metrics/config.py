"""Metric configurations: the challenge presets, or any `SimAgentMetricsConfig` textproto.

Each metric `X` in the config is scored into the output field
`X_likelihood` (the metrics are listed in `metrics.registry`).
Presets: "2025", "2024", "2023" (sim agents) and "scenario_gen_2025"
(scenario generation: the 2025 weights, every metric but the traffic-light
one pooled over all objects of the scene, `aggregate_objects`). They are data:
textproto files named and laid out as the official package lays out its own,
under the root of `wosac_eval.compat` (`CONFIG_ROOT`:
`wdl_limited/sim_agents_metrics/challenge_2025_sim_agents_config.textproto`,
the 2023 one under `legacy_configs/`), where programs written for the official
package look for them; this loader reads that one copy of each.
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

from google.protobuf import text_format

from wosac_eval import challenges
from wosac_eval.metrics.registry import METRIC_BUCKETS, METRIC_NAMES, METRICS, default_feature_config  # noqa: F401
from wosac_eval.protos import sim_agents_metrics_pb2

SimAgentMetricsConfig = sim_agents_metrics_pb2.SimAgentMetricsConfig

# The official package's root as `wosac_eval.compat` lays it out: the presets live there once, at the official
# relative paths, so that a program joining them to `waymo_open_dataset.__path__[0]` finds them. A path, not
# an import: the metrics room reads the data without importing the compat room (which comes after it).
CONFIG_ROOT = Path(__file__).resolve().parents[1] / "compat"
# Preset -> its file under CONFIG_ROOT (the official package's names and folders).
PRESET_FILES = {
    "2025": "wdl_limited/sim_agents_metrics/challenge_2025_sim_agents_config.textproto",
    "2024": "wdl_limited/sim_agents_metrics/challenge_2024_config.textproto",
    "2023": "wdl_limited/sim_agents_metrics/legacy_configs/challenge_2023_config.textproto",
    "scenario_gen_2025": "wdl_limited/sim_agents_metrics/challenge_2025_scenario_gen_config.textproto",
}
PRESET_NAMES = tuple(PRESET_FILES)
DEFAULT_PRESET = "2025"
# The challenge each preset was made for.
PRESET_CHALLENGE = {
    name: (challenges.Challenge.SCENARIO_GEN if name.startswith("scenario_gen") else challenges.Challenge.SIM_AGENTS)
    for name in PRESET_NAMES
}


def default_config(challenge: challenges.ChallengeLike = challenges.Challenge.SIM_AGENTS) -> str:
    """The preset of a challenge's current leaderboard ("2025" or "scenario_gen_2025")."""
    return challenges.spec(challenge).default_config


def preset_fits(name: str, challenge: challenges.ChallengeLike) -> bool:
    """False only for a preset made for the other challenge (a textproto may serve either)."""
    made_for = PRESET_CHALLENGE.get(str(name))
    return made_for is None or made_for == challenges.as_challenge(challenge)


def config_name_for(challenge: challenges.ChallengeLike, config: str | os.PathLike | None = None) -> str:
    """The config a challenge is scored with: the one asked for, or the challenge's current preset.

    A preset of the other challenge is refused (its metrics would be pooled, or not, against the
    challenge's rules and its figures would look plausible): one rule for every front.
    """
    if config is None:
        return default_config(challenge)
    name = str(config)
    if not preset_fits(name, challenge):
        challenge = challenges.as_challenge(challenge)
        raise ValueError(
            f"config {name!r} is the {PRESET_CHALLENGE[name].value} challenge's; the {challenge.value} "
            f"challenge's is {default_config(challenge)!r}"
        )
    return name


def preset(name: str) -> SimAgentMetricsConfig:
    """The metrics config of a challenge year ("2025", "2024", "2023", "scenario_gen_2025"), read from its file."""
    if name not in PRESET_FILES:
        raise ValueError(
            f"unknown config preset {name!r}; choose one of {', '.join(PRESET_NAMES)} or a .textproto file"
        )
    config = SimAgentMetricsConfig()
    config.CopyFrom(_preset_file(name))  # a copy: callers may change theirs
    return config


@functools.cache
def _preset_file(name: str) -> SimAgentMetricsConfig:
    return _read_textproto(preset_path(name))


def preset_path(name: str) -> Path:
    """The textproto file of a preset (KeyError for an unknown name)."""
    return CONFIG_ROOT / PRESET_FILES[name]


def _read_textproto(path: Path) -> SimAgentMetricsConfig:
    """A `SimAgentMetricsConfig` textproto file, completed by `with_defaults`; ValueError naming the file."""
    try:
        config = text_format.Parse(path.read_text(encoding="utf-8"), SimAgentMetricsConfig())
    except UnicodeDecodeError as err:
        raise ValueError(
            f"{path}: not a SimAgentMetricsConfig textproto: not UTF-8 text (byte {err.start} is "
            f"0x{err.object[err.start]:02x}); is it a binary file?"
        ) from None
    except text_format.ParseError as err:
        raise ValueError(f"{path}: not a SimAgentMetricsConfig textproto: {err}") from err
    return with_defaults(config)


def with_defaults(config: SimAgentMetricsConfig) -> SimAgentMetricsConfig:
    """Fills metrics a config omits from their registry default (`registry.Metric.config_default`):
    pre-2025 configs have no traffic-light metric, which then counts as Bernoulli with weight 0 (the
    meta-metric those years defined). Other missing metrics are an error."""
    config = SimAgentMetricsConfig.FromString(config.SerializeToString())
    for metric in METRICS:
        if metric.config_default is not None and not config.HasField(metric.name):
            getattr(config, metric.name).CopyFrom(default_feature_config(metric))
    missing = [m for m in METRIC_NAMES if not config.HasField(m)]
    if missing:
        raise ValueError(f"metrics config lacks {', '.join(missing)}")
    for name in METRIC_NAMES:
        if getattr(config, name).WhichOneof("estimator") is None:
            raise ValueError(f"metrics config: {name} has no estimator")
    return config


def load_config(name_or_path: str | Path | SimAgentMetricsConfig = DEFAULT_PRESET) -> SimAgentMetricsConfig:
    """A preset name, a `SimAgentMetricsConfig` textproto path, or a message."""
    if isinstance(name_or_path, SimAgentMetricsConfig):
        return with_defaults(name_or_path)
    text = str(name_or_path)
    if text in PRESET_FILES:
        return preset(text)
    path = Path(text)
    if not path.is_file():
        raise ValueError(
            f"config {text!r} is neither a preset ({', '.join(PRESET_NAMES)}) nor a readable textproto file"
        )
    return _read_textproto(path)
