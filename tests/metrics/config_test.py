"""Tests of the metric configurations: presets, textprotos, defaults, bucket weights."""

from pathlib import Path

import pytest
from google.protobuf import text_format

from wosac_eval.metrics import config as cfg
from wosac_eval.metrics.scenario_metrics import bucket_metrics

from support.paths import SHARED

OFFICIAL_CONFIGS = SHARED / "official-configs"
HISTOGRAM_METRICS = (
    "linear_speed",
    "linear_acceleration",
    "angular_speed",
    "angular_acceleration",
    "distance_to_nearest_object",
    "time_to_collision",
    "distance_to_road_edge",
)
INDICATOR_METRICS = ("collision_indication", "offroad_indication", "traffic_light_violation")


def weights(config):
    return {m: getattr(config, m).metametric_weight for m in cfg.METRIC_NAMES}


def test_buckets_partition_the_metrics():
    names = [m for bucket in cfg.METRIC_BUCKETS.values() for m in bucket]
    assert sorted(names) == sorted(set(names)) == sorted(HISTOGRAM_METRICS + INDICATOR_METRICS)
    assert cfg.METRIC_NAMES == tuple(names)


@pytest.mark.parametrize("name", ["2025", "2024", "2023"])
def test_presets_load(name):
    config = cfg.load_config(name)
    assert isinstance(config, cfg.SimAgentMetricsConfig)
    for metric in HISTOGRAM_METRICS:
        feature = getattr(config, metric)
        assert feature.WhichOneof("estimator") == "histogram"
        assert feature.independent_timesteps
        assert feature.histogram.additive_smoothing_pseudocount == pytest.approx(0.1)
        assert feature.histogram.min_val < feature.histogram.max_val
    for metric in INDICATOR_METRICS:
        feature = getattr(config, metric)
        assert feature.WhichOneof("estimator") == "bernoulli"
        assert feature.bernoulli.additive_smoothing_pseudocount == pytest.approx(0.001)  # proto default
    # A preset already has every metric, so filling defaults changes nothing.
    assert cfg.with_defaults(config) == config


def test_default_preset_is_2025():
    assert cfg.load_config() == cfg.preset("2025")


def test_2025_histograms_by_hand():
    config = cfg.preset("2025")
    h = config.linear_acceleration.histogram
    assert (h.min_val, h.max_val, h.num_bins) == (-12.0, 12.0, 11)
    h = config.angular_speed.histogram
    assert (h.min_val, h.max_val, h.num_bins) == (pytest.approx(-0.628), pytest.approx(0.628), 11)
    h = config.distance_to_road_edge.histogram
    assert (h.min_val, h.max_val, h.num_bins) == (-20.0, 40.0, 10)


@pytest.mark.parametrize(
    "name, kinematic, interactive, map_based",
    [
        # 4 x 0.05 | 0.1 + 0.25 + 0.1 | 0.05 + 0.25 + 0.05
        ("2025", 0.20, 0.45, 0.35),
        # 4 x 0.05 | 0.1 + 0.25 + 0.1 | 0.1 + 0.25 + 0 (no traffic-light metric yet)
        ("2024", 0.20, 0.45, 0.35),
        # 4 x 0.09 | 0.09 + 0.18 + 0.09 | 0.09 + 0.18 + 0
        ("2023", 0.36, 0.36, 0.27),
    ],
)
def test_bucket_weights(name, kinematic, interactive, map_based):
    w = weights(cfg.preset(name))
    sums = {bucket: sum(w[m] for m in names) for bucket, names in cfg.METRIC_BUCKETS.items()}
    assert sums == pytest.approx({"kinematic": kinematic, "interactive": interactive, "map_based": map_based})


def test_traffic_light_weight_only_from_2025():
    assert cfg.preset("2025").traffic_light_violation.metametric_weight == pytest.approx(0.05)
    assert cfg.preset("2024").traffic_light_violation.metametric_weight == 0.0
    assert cfg.preset("2023").traffic_light_violation.metametric_weight == 0.0


def _scenario_metrics(likelihood_by_metric):
    metrics = {f"{m}_likelihood": likelihood_by_metric[m] for m in cfg.METRIC_NAMES}
    metrics.update(
        metametric=0.7,
        min_average_displacement_error=1.5,
        simulated_collision_rate=0.25,
        simulated_offroad_rate=0.125,
        simulated_traffic_light_violation_rate=0.0,
    )
    return metrics


def test_bucket_metrics_are_weighted_means():
    likelihood = {
        "linear_speed": 0.2,
        "linear_acceleration": 0.4,
        "angular_speed": 0.6,
        "angular_acceleration": 0.8,
        "distance_to_nearest_object": 0.5,
        "collision_indication": 0.9,
        "time_to_collision": 0.7,
        "distance_to_road_edge": 0.3,
        "offroad_indication": 1.0,
        "traffic_light_violation": 0.1,
    }
    out = bucket_metrics(cfg.preset("2025"), _scenario_metrics(likelihood))
    # Equal kinematic weights: plain mean.
    assert out["kinematic_metrics"] == pytest.approx(0.5, rel=1e-6)
    assert out["interactive_metrics"] == pytest.approx((0.1 * 0.5 + 0.25 * 0.9 + 0.1 * 0.7) / 0.45, rel=1e-6)
    assert out["map_based_metrics"] == pytest.approx((0.05 * 0.3 + 0.25 * 1.0 + 0.05 * 0.1) / 0.35, rel=1e-6)
    assert out["realism_meta_metric"] == pytest.approx(0.7)
    assert out["min_ade"] == 1.5 and out["simulated_collision_rate"] == 0.25
    # 2024 ignores the traffic-light likelihood.
    out = bucket_metrics(cfg.preset("2024"), _scenario_metrics(likelihood))
    assert out["map_based_metrics"] == pytest.approx((0.1 * 0.3 + 0.25 * 1.0) / 0.35, rel=1e-6)


def test_bucket_with_zero_weight_is_an_error():
    config = cfg.preset("2025")
    for m in cfg.METRIC_BUCKETS["kinematic"]:
        getattr(config, m).metametric_weight = 0.0
    with pytest.raises(ValueError, match="kinematic bucket has zero total weight"):
        bucket_metrics(config, _scenario_metrics({m: 0.5 for m in cfg.METRIC_NAMES}))


def test_unknown_preset():
    with pytest.raises(ValueError, match="unknown config preset '1999'"):
        cfg.preset("1999")
    with pytest.raises(ValueError, match="neither a preset"):
        cfg.load_config("1999")


CUSTOM = """
linear_speed { histogram { min_val: 1 max_val: 31 num_bins: 6 additive_smoothing_pseudocount: 0.5 }
               metametric_weight: 0.3 }
linear_acceleration { histogram { min_val: -4 max_val: 4 num_bins: 8 } independent_timesteps: true
                      metametric_weight: 0.1 }
angular_speed { kernel_density { bandwidth: 0.25 } metametric_weight: 0.1 }
angular_acceleration { histogram { min_val: -1 max_val: 1 num_bins: 4 } metametric_weight: 0.1 }
distance_to_nearest_object { histogram { min_val: -5 max_val: 40 num_bins: 10 } metametric_weight: 0.1 }
collision_indication { bernoulli { additive_smoothing_pseudocount: 0.01 } metametric_weight: 0.1 }
time_to_collision { histogram { min_val: 0 max_val: 5 num_bins: 10 } metametric_weight: 0.1 }
distance_to_road_edge { histogram { min_val: -20 max_val: 40 num_bins: 10 } metametric_weight: 0.05
                        aggregate_objects: true }
offroad_indication { bernoulli { } metametric_weight: 0.05 }
"""


def test_textproto_file_loads(tmp_path):
    path = tmp_path / "my_config.textproto"
    path.write_text(CUSTOM + "traffic_light_violation { bernoulli { } metametric_weight: 0.2 }\n")
    config = cfg.load_config(path)
    h = config.linear_speed.histogram
    assert (h.min_val, h.max_val, h.num_bins, h.additive_smoothing_pseudocount) == (1, 31, 6, 0.5)
    assert not config.linear_speed.independent_timesteps
    assert config.linear_acceleration.independent_timesteps
    assert config.linear_acceleration.histogram.additive_smoothing_pseudocount == pytest.approx(0.001)
    assert config.angular_speed.kernel_density.bandwidth == 0.25
    assert config.collision_indication.bernoulli.additive_smoothing_pseudocount == pytest.approx(0.01)
    assert config.distance_to_road_edge.aggregate_objects
    assert config.traffic_light_violation.metametric_weight == pytest.approx(0.2)
    # A string path works as well as a Path.
    assert cfg.load_config(str(path)) == config


def test_missing_traffic_light_metric_gets_bernoulli_weight_zero(tmp_path):
    path = tmp_path / "pre2025.textproto"
    path.write_text(CUSTOM)
    config = cfg.load_config(path)
    tl = config.traffic_light_violation
    assert tl.WhichOneof("estimator") == "bernoulli"
    assert tl.metametric_weight == 0.0
    # The rest is untouched.
    assert config.linear_speed.metametric_weight == pytest.approx(0.3)


def test_with_defaults_does_not_modify_its_argument():
    message = text_format.Parse(CUSTOM, cfg.SimAgentMetricsConfig())
    filled = cfg.load_config(message)
    assert filled.HasField("traffic_light_violation")
    assert not message.HasField("traffic_light_violation")


@pytest.mark.parametrize("metric", ["linear_speed", "collision_indication", "distance_to_road_edge"])
def test_missing_other_metric_is_an_error(tmp_path, metric):
    message = text_format.Parse(CUSTOM, cfg.SimAgentMetricsConfig())
    message.ClearField(metric)
    path = tmp_path / "partial.textproto"
    path.write_text(text_format.MessageToString(message))
    with pytest.raises(ValueError, match=f"lacks {metric}"):
        cfg.load_config(path)


def test_metric_without_estimator_is_an_error():
    message = text_format.Parse(CUSTOM, cfg.SimAgentMetricsConfig())
    message.time_to_collision.ClearField("histogram")
    message.time_to_collision.metametric_weight = 0.1  # present, but with no estimator
    with pytest.raises(ValueError, match="time_to_collision has no estimator"):
        cfg.load_config(message)


def test_unparsable_textproto_names_the_file(tmp_path):
    path = tmp_path / "broken.textproto"
    path.write_text("linear_speed { histogram { min_val: oops } }")
    with pytest.raises(ValueError, match="broken.textproto: not a SimAgentMetricsConfig textproto"):
        cfg.load_config(path)


def test_missing_file(tmp_path):
    with pytest.raises(ValueError, match="neither a preset"):
        cfg.load_config(tmp_path / "nope.textproto")


# --- Against the official textprotos -------------------------------------------------------------

OFFICIAL = {
    "2025": "challenge_2025_sim_agents_config.textproto",
    "2024": "challenge_2024_config.textproto",
    "2023": "challenge_2023_config.textproto",
}


def need_official_configs():
    if not OFFICIAL_CONFIGS.is_dir():
        pytest.skip(f"official configs not available ({OFFICIAL_CONFIGS} is absent; it comes with ../shared)")


@pytest.mark.parametrize("name", OFFICIAL)
def test_presets_equal_official_textprotos(name):
    need_official_configs()
    official = cfg.load_config(OFFICIAL_CONFIGS / OFFICIAL[name])
    ours = cfg.preset(name)
    for metric in cfg.METRIC_NAMES:
        a, b = getattr(ours, metric), getattr(official, metric)
        assert a.WhichOneof("estimator") == b.WhichOneof("estimator"), metric
        for field in ("independent_timesteps", "aggregate_objects", "metametric_weight"):
            assert getattr(a, field) == getattr(b, field), f"{name} {metric}.{field}"
        estimator = a.WhichOneof("estimator")
        assert getattr(a, estimator) == getattr(b, estimator), f"{name} {metric}.{estimator}"
    assert ours == official


def test_official_2023_has_no_traffic_light_metric():
    need_official_configs()
    raw = text_format.Parse((OFFICIAL_CONFIGS / OFFICIAL["2023"]).read_text(), cfg.SimAgentMetricsConfig())
    assert not raw.HasField("traffic_light_violation")
    assert cfg.load_config(OFFICIAL_CONFIGS / OFFICIAL["2023"]).traffic_light_violation.metametric_weight == 0.0


@pytest.mark.parametrize(
    "file",
    [
        "challenge_2025_scenario_gen_config.textproto",
        "test_config.textproto",
        "test_config_dependent_timesteps.textproto",
    ],
)
def test_other_official_configs_load(file):
    need_official_configs()
    config = cfg.load_config(OFFICIAL_CONFIGS / file)
    assert all(getattr(config, m).WhichOneof("estimator") for m in cfg.METRIC_NAMES)
