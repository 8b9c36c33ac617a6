"""Metric configurations: the challenge presets, or any `SimAgentMetricsConfig` textproto.

Each metric `X` in the config is scored into the output field
`X_likelihood` (the metrics are listed in `metrics.registry`).
Presets: "2025", "2024", "2023" (sim agents) and "scenario_gen_2025"
(scenario generation: the 2025 weights, every metric but the traffic-light
one pooled over all objects of the scene, `aggregate_objects`).
"""
from __future__ import annotations

from pathlib import Path

from google.protobuf import text_format

from wosac_eval import challenges
from wosac_eval.metrics.registry import METRIC_BUCKETS, METRIC_NAMES  # noqa: F401  (re-exported)
from wosac_eval.protos import sim_agents_metrics_pb2

SimAgentMetricsConfig = sim_agents_metrics_pb2.SimAgentMetricsConfig

# (min, max, bins) of the histogram metrics, and every metric's weight, per challenge.
# Histograms use a 0.1 pseudo-count and independent timesteps; the three
# indicators are Bernoulli with the default pseudo-count.
_2024_HISTOGRAMS = {
    "linear_speed": (0.0, 25.0, 10), "linear_acceleration": (-12.0, 12.0, 11),
    "angular_speed": (-0.628, 0.628, 11), "angular_acceleration": (-3.14, 3.14, 11),
    "distance_to_nearest_object": (-5.0, 40.0, 10), "distance_to_road_edge": (-20.0, 40.0, 10),
    "time_to_collision": (0.0, 5.0, 10),
}
_2025_WEIGHTS = {
    "linear_speed": 0.05, "linear_acceleration": 0.05, "angular_speed": 0.05,
    "angular_acceleration": 0.05, "distance_to_nearest_object": 0.1,
    "collision_indication": 0.25, "time_to_collision": 0.1, "distance_to_road_edge": 0.05,
    "offroad_indication": 0.25, "traffic_light_violation": 0.05}
# Preset -> (histograms, weights, metrics pooled over the objects of a scene).
_PRESETS = {
    "2025": (_2024_HISTOGRAMS, _2025_WEIGHTS),
    "2024": (_2024_HISTOGRAMS, {
        "linear_speed": 0.05, "linear_acceleration": 0.05, "angular_speed": 0.05,
        "angular_acceleration": 0.05, "distance_to_nearest_object": 0.1,
        "collision_indication": 0.25, "time_to_collision": 0.1, "distance_to_road_edge": 0.1,
        "offroad_indication": 0.25, "traffic_light_violation": 0.0}),
    "2023": ({
        "linear_speed": (0.0, 35.0, 10), "linear_acceleration": (-15.0, 15.0, 10),
        "angular_speed": (-31.5, 31.5, 10), "angular_acceleration": (-31.5, 31.5, 10),
        "distance_to_nearest_object": (-5.0, 40.0, 10), "distance_to_road_edge": (-20.0, 40.0, 10),
        "time_to_collision": (0.0, 5.0, 10)}, {
        "linear_speed": 0.09, "linear_acceleration": 0.09, "angular_speed": 0.09,
        "angular_acceleration": 0.09, "distance_to_nearest_object": 0.09,
        "collision_indication": 0.18, "time_to_collision": 0.09, "distance_to_road_edge": 0.09,
        "offroad_indication": 0.18, "traffic_light_violation": 0.0}),
    "scenario_gen_2025": (_2024_HISTOGRAMS, _2025_WEIGHTS,
                          tuple(m for m in METRIC_NAMES if m != "traffic_light_violation")),
}
PRESET_NAMES = tuple(_PRESETS)
DEFAULT_PRESET = "2025"
# The challenge each preset was made for.
PRESET_CHALLENGE = {name: (challenges.Challenge.SCENARIO_GEN if name.startswith("scenario_gen")
                           else challenges.Challenge.SIM_AGENTS) for name in PRESET_NAMES}


def default_config(challenge=challenges.Challenge.SIM_AGENTS) -> str:
    """The preset of a challenge's current leaderboard ("2025" or "scenario_gen_2025")."""
    return challenges.spec(challenge).default_config


def preset_fits(name: str, challenge) -> bool:
    """False only for a preset made for the other challenge (a textproto may serve either)."""
    made_for = PRESET_CHALLENGE.get(str(name))
    return made_for is None or made_for == challenges.as_challenge(challenge)


def config_name_for(challenge, config: str | Path | None = None) -> str:
    """The config a challenge is scored with: the one asked for, or the challenge's current preset.

    A preset of the other challenge is refused (its metrics would be pooled, or not, against the
    challenge's rules and its figures would look plausible): one rule for every front.
    """
    if config is None:
        return default_config(challenge)
    name = str(config)
    if not preset_fits(name, challenge):
        challenge = challenges.as_challenge(challenge)
        raise ValueError(f"config {name!r} is the {PRESET_CHALLENGE[name].value} challenge's; the {challenge.value} "
                         f"challenge's is {default_config(challenge)!r}")
    return name


def preset(name: str) -> SimAgentMetricsConfig:
    """The metrics config of a challenge year ("2025", "2024", "2023", "scenario_gen_2025")."""
    if name not in _PRESETS:
        raise ValueError(f"unknown config preset {name!r}; choose one of {', '.join(PRESET_NAMES)} "
                         f"or a .textproto file")
    histograms, weights, *pooled = _PRESETS[name]
    pooled = pooled[0] if pooled else ()
    config = SimAgentMetricsConfig()
    for metric in METRIC_NAMES:
        feature = getattr(config, metric)
        if metric in histograms:
            lo, hi, bins = histograms[metric]
            feature.histogram.min_val, feature.histogram.max_val = lo, hi
            feature.histogram.num_bins = bins
            feature.histogram.additive_smoothing_pseudocount = 0.1
            feature.independent_timesteps = True
        else:
            feature.bernoulli.SetInParent()
        feature.metametric_weight = weights[metric]
        if metric in pooled:
            feature.aggregate_objects = True
    return config


def with_defaults(config: SimAgentMetricsConfig) -> SimAgentMetricsConfig:
    """Fills metrics a config omits: pre-2025 configs have no traffic-light
    metric, which then counts as Bernoulli with weight 0 (the meta-metric those
    years defined). Other missing metrics are an error."""
    config = SimAgentMetricsConfig.FromString(config.SerializeToString())
    if not config.HasField("traffic_light_violation"):
        config.traffic_light_violation.bernoulli.SetInParent()
        config.traffic_light_violation.metametric_weight = 0.0
    missing = [m for m in METRIC_NAMES if not config.HasField(m)]
    if missing:
        raise ValueError(f"metrics config lacks {', '.join(missing)}")
    for metric in METRIC_NAMES:
        if getattr(config, metric).WhichOneof("estimator") is None:
            raise ValueError(f"metrics config: {metric} has no estimator")
    return config


def load_config(name_or_path: str | Path | SimAgentMetricsConfig = DEFAULT_PRESET) -> SimAgentMetricsConfig:
    """A preset name, a `SimAgentMetricsConfig` textproto path, or a message."""
    if isinstance(name_or_path, SimAgentMetricsConfig):
        return with_defaults(name_or_path)
    text = str(name_or_path)
    if text in _PRESETS:
        return preset(text)
    path = Path(text)
    if not path.is_file():
        raise ValueError(f"config {text!r} is neither a preset ({', '.join(PRESET_NAMES)}) "
                         f"nor a readable textproto file")
    try:
        config = text_format.Parse(path.read_text(), SimAgentMetricsConfig())
    except text_format.ParseError as err:
        raise ValueError(f"{path}: not a SimAgentMetricsConfig textproto: {err}") from err
    return with_defaults(config)
