"""Criticality of a scenario in [0, 1]: how demanding its logged scene is, with its components kept.

From `analysis.criticality_features` (the logged scene alone): each component is
mapped to [0, 1] by a logistic around a threshold of "demanding" behaviour, so
everyday driving scores near 0 and clear events near 1:

    component           statistic of the per-step worst value     threshold, width
    braking             90th percentile over steps (m/s^2)        4.0, 0.75   (hard braking, ~0.4 g)
    jerk                90th percentile (m/s^3)                   8.0, 2.0
    yaw_acceleration    90th percentile (rad/s^2)                 1.5, 0.4
    time_to_collision   3rd least over steps (s), lower is worse  1.5, 0.4
    closing_speed       3rd most over steps (m/s)                 8.0, 2.0
    near_miss           3rd most over steps, already in [0, 1]    -
    offroad             the most over tested steps (m)            0.5, 0.15
    red_light           a moving vehicle ran a red light: 0 or 1  -
    rarity              see below                                 -

(kinematic values are percentiles, robust to the noise of logged positions;
interaction values must last three steps, 0.3 s, to count).

Rarity rates the scene's behaviour against a scenario set: the set's
(acceleration, yaw rate) histogram gives each sample a surprisal -log p (p with
add-one smoothing); the scene's rarity is the 95th percentile of its samples'
surprisal, scaled to [0, 1] between the most common bin's surprisal and an
unseen bin's. It depends on the set: the same scene is rarer among calmer ones.

    score = 0.25 kinematic + 0.35 interaction + 0.25 map + 0.15 rarity,
    kinematic = max(braking, jerk, yaw_acceleration), interaction = max(time_to_collision, closing_speed,
    near_miss), map = max(offroad, red_light)

The per-step criticality applies the same maps and weights to each step's
values (rarity left out: it is a property of the whole scene); `peak_step` is
where it is highest.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from wosac_eval.analysis.criticality_features import BEHAVIOUR_BINS, CriticalityFeatures, criticality_features
from wosac_eval.arrays.scenario import ScenarioArrays
from wosac_eval.features.metric_features import MapContext

# component -> (threshold, width, lower_is_worse)
THRESHOLDS = {
    "braking": (4.0, 0.75, False),
    "jerk": (8.0, 2.0, False),
    "yaw_acceleration": (1.5, 0.4, False),
    "time_to_collision": (1.5, 0.4, True),
    "closing_speed": (8.0, 2.0, False),
    "offroad": (0.5, 0.15, False),
}
KINEMATIC = ("braking", "jerk", "yaw_acceleration")
INTERACTION = ("time_to_collision", "closing_speed", "near_miss")
MAP = ("offroad", "red_light")
COMPONENTS = KINEMATIC + INTERACTION + MAP + ("rarity",)
WEIGHTS = {"kinematic": 0.25, "interaction": 0.35, "map": 0.25, "rarity": 0.15}
RAW_UNITS = {
    "braking": "m/s^2",
    "jerk": "m/s^3",
    "yaw_acceleration": "rad/s^2",
    "time_to_collision": "s",
    "closing_speed": "m/s",
    "near_miss": "",
    "offroad": "m",
    "red_light": "",
    "rarity": "nats",
}
KINEMATIC_PERCENTILE = 90
SUSTAINED_STEPS = 3
LONG_TAIL_QUANTILE = 0.9  # the long tail of a set: its most critical decile


def logistic(values: ArrayLike, component: str) -> np.ndarray:
    """A raw value (or array) mapped to [0, 1]: 0.5 at the component's threshold, NaN to 0."""
    threshold, width, lower_is_worse = THRESHOLDS[component]
    x = np.asarray(values, dtype=np.float64)
    z = (threshold - x) / width if lower_is_worse else (x - threshold) / width
    with np.errstate(over="ignore"):
        out = 1.0 / (1.0 + np.exp(-z))
    return np.where(np.isnan(x), 0.0, out)


def _sustained(values: np.ndarray, lower_is_worse: bool) -> float:
    """The value held for at least SUSTAINED_STEPS steps: the 3rd worst of the series."""
    ordered = np.sort(values) if lower_is_worse else -np.sort(-values)
    return float(ordered[min(SUSTAINED_STEPS, ordered.size) - 1])


def raw_components(features: CriticalityFeatures) -> dict[str, float]:
    """The scenario-level statistic of every heuristic component (see the module's table); NaN if undefined."""
    raw = {}
    for name in KINEMATIC:
        series = getattr(features, name)
        # `np.nanpercentile` of a 1-D series, without its general machinery (a tenth of a millisecond a scene).
        kept = series[~np.isnan(series)]
        raw[name] = float(np.percentile(kept, KINEMATIC_PERCENTILE)) if np.isfinite(kept).any() else float("nan")
    raw["time_to_collision"] = _sustained(features.time_to_collision, True)
    raw["closing_speed"] = _sustained(features.closing_speed, False)
    raw["near_miss"] = _sustained(features.near_miss, False)
    raw["offroad"] = float(np.nanmax(features.offroad)) if np.isfinite(features.offroad).any() else float("nan")
    raw["red_light"] = float(features.red_light.any())
    return raw


def step_criticality(features: CriticalityFeatures) -> np.ndarray:
    """Criticality of each step (without rarity), float64 `(num_steps,)` in [0, 0.85].

    Off-road, tested every few steps, holds its value until the next test.
    """
    kinematic = np.max([logistic(getattr(features, n), n) for n in KINEMATIC], axis=0)
    interaction = np.max(
        [
            logistic(features.time_to_collision, "time_to_collision"),
            logistic(features.closing_speed, "closing_speed"),
            features.near_miss,
        ],
        axis=0,
    )
    tested = np.flatnonzero(np.isfinite(features.offroad))
    offroad = np.zeros(features.offroad.shape)
    if tested.size:
        held = tested[np.clip(np.searchsorted(tested, np.arange(offroad.size), side="right") - 1, 0, None)]
        offroad = logistic(features.offroad[held], "offroad")
    map_based = np.maximum(offroad, features.red_light.astype(np.float64))
    return WEIGHTS["kinematic"] * kinematic + WEIGHTS["interaction"] * interaction + WEIGHTS["map"] * map_based


class BehaviourHistogram:
    """The (acceleration, yaw rate) counts of a scenario set, and the rarity of a scene against them."""

    def __init__(self, counts: np.ndarray | None = None) -> None:
        if counts is None:
            counts = np.zeros((len(BEHAVIOUR_BINS[0]) - 1, len(BEHAVIOUR_BINS[1]) - 1), dtype=np.int64)
        self.counts = np.asarray(counts, dtype=np.int64)

    def add(self, counts: np.ndarray) -> None:
        self.counts = self.counts + counts

    def surprisal(self) -> np.ndarray:
        """-log p of each bin, with add-one smoothing, float64 like `counts`."""
        return -np.log((self.counts + 1.0) / (self.counts.sum() + self.counts.size))

    def rarity(self, scene_counts: np.ndarray) -> tuple[float, float]:
        """(rarity in [0, 1], raw surprisal in nats) of a scene's samples; (0, 0) for a scene without any."""
        scene_counts = np.asarray(scene_counts).ravel()
        if scene_counts.sum() == 0:
            return 0.0, 0.0
        surprisal = self.surprisal().ravel()
        order = np.argsort(surprisal, kind="stable")
        cumulative = np.cumsum(scene_counts[order])
        # The 95th percentile of the scene's samples' surprisal (a weighted quantile over bins).
        raw = float(surprisal[order][np.searchsorted(cumulative, 0.95 * cumulative[-1])])
        low, high = float(surprisal.min()), float(-np.log(1.0 / (self.counts.sum() + self.counts.size)))
        return (float(np.clip((raw - low) / (high - low), 0.0, 1.0)) if high > low else 0.0), raw


def behaviour_entries(counts: np.ndarray) -> list[list[int]]:
    """A histogram as sparse [flat index, count] pairs (what a scenario's row carries to the assembly)."""
    flat = np.asarray(counts).ravel()
    return [[int(k), int(flat[k])] for k in np.flatnonzero(flat)]


def behaviour_counts(entries: list, shape: tuple[int, int]) -> np.ndarray:
    """The histogram of `behaviour_entries`."""
    flat = np.zeros(shape[0] * shape[1], dtype=np.int64)
    for k, n in entries:
        flat[k] += n
    return flat.reshape(shape)


def scene_criticality(features: CriticalityFeatures) -> dict:
    """The heuristic part of a scene's criticality (everything but rarity, which needs the whole set).

    Returns:
      {"components": {name: [0, 1]}, "raw": {name: value in RAW_UNITS or None}, "peak_step": step,
      "behaviour": `behaviour_entries` of the scene's histogram}; `with_rarity` completes it.
    """
    raw = raw_components(features)
    components = {name: float(logistic(raw[name], name)) for name in THRESHOLDS}
    components["near_miss"] = raw["near_miss"]
    components["red_light"] = raw["red_light"]
    return {
        "components": components,
        "raw": {k: (float(v) if np.isfinite(v) else None) for k, v in raw.items()},
        "peak_step": int(np.argmax(step_criticality(features))),
        "behaviour": behaviour_entries(features.behaviour),
    }


def scenario_criticality(scenario: ScenarioArrays, context: MapContext | None = None) -> dict:
    """`scene_criticality` of a scenario's log (`ScenarioArrays`; `context` its `MapContext` if built already)."""
    return scene_criticality(criticality_features(scenario, context))


def with_rarity(scene: dict, histogram: BehaviourHistogram) -> dict:
    """The scene's criticality {"score", "components", "raw", "peak_step"}, rarity rated against `histogram`."""
    counts = behaviour_counts(scene["behaviour"], histogram.counts.shape)
    components = dict(scene["components"])
    raw = dict(scene["raw"])
    components["rarity"], raw["rarity"] = histogram.rarity(counts)
    groups = {"kinematic": KINEMATIC, "interaction": INTERACTION, "map": MAP}
    score = sum(WEIGHTS[g] * max(components[n] for n in names) for g, names in groups.items())
    score += WEIGHTS["rarity"] * components["rarity"]
    return {"score": float(score), "components": components, "raw": raw, "peak_step": scene["peak_step"]}


def set_histogram(scenes: list[dict]) -> BehaviourHistogram:
    """The behaviour histogram of a set of scenes (`scene_criticality` results)."""
    histogram = BehaviourHistogram()
    for scene in scenes:
        histogram.add(behaviour_counts(scene["behaviour"], histogram.counts.shape))
    return histogram
