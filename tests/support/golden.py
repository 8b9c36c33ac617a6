"""Golden cases: submissions scored by the official implementation, with its outputs.

A case is `<scenario_id>__<policy>` in a folder of cases: the submission
(`.binproto`, or `.binproto.gz`), the official metrics (`.json`, under
`metrics.<config>`) and the official per-step features (`.features.npz`).
Four collections, two per challenge:

- `../shared/golden` (sim agents, real WOMD scenarios, five configs) and
  `../shared/golden/scenario_gen` (scenario gen, synthetic scenes): absent in a
  user's clone, and extended with more cases on every landing, so the tests
  take whatever cases are there;
- `tests/data/oracle` and `tests/data/oracle_scenario_gen`: synthetic
  edge-case scenes in the repository, so some parity runs everywhere.

Scenarios are looked up by id in every scene folder of the collections.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
from functools import lru_cache
from pathlib import Path

import numpy as np

from support.paths import SHARED, TEST_DATA
from wosac_eval.arrays.rollouts import rollout_arrays
from wosac_eval.arrays.scenario import scenario_arrays
from wosac_eval.metrics.config import load_config
from wosac_eval.parse.scenarios import iter_scenarios
from wosac_eval.protos import sim_agents_submission_pb2

# Per-step features compared bit for bit, and the displacement error (also bit-identical).
EXACT_FEATURES = (
    "object_id",
    "object_type",
    "valid",
    "linear_speed",
    "linear_acceleration",
    "angular_speed",
    "angular_acceleration",
    "distance_to_nearest_object",
    "collision_per_step",
    "time_to_collision",
    "distance_to_road_edge",
    "offroad_per_step",
    "traffic_light_violation_per_step",
    "average_displacement_error",
)
SHARED_CONFIGS = {
    "2025": "2025",
    "2024": "2024",
    "2023": "2023",
    "test": "official-configs/test_config.textproto",
    "test_dependent": "official-configs/test_config_dependent_timesteps.textproto",
}


@dataclasses.dataclass(frozen=True)
class CaseSet:
    """A folder of golden cases of one challenge and the configs their JSON holds."""

    name: str
    folder: Path
    challenge: str
    configs: tuple[str, ...]
    in_repository: bool

    @property
    def cases(self) -> list[str]:
        if not self.folder.is_dir():
            return []
        return sorted(p.name[: -len(".json")] for p in self.folder.glob("*.json"))


SETS = (
    CaseSet("shared", SHARED / "golden", "sim_agents", tuple(SHARED_CONFIGS), False),
    CaseSet("shared_scenario_gen", SHARED / "golden" / "scenario_gen", "scenario_gen", ("scenario_gen_2025",), False),
    CaseSet("oracle", TEST_DATA / "oracle", "sim_agents", ("2025", "2024", "2023"), True),
    CaseSet("oracle_scenario_gen", TEST_DATA / "oracle_scenario_gen", "scenario_gen", ("scenario_gen_2025",), True),
)
SCENE_FOLDERS = (
    SHARED / "womd",
    SHARED / "golden" / "scenario_gen" / "scenes",
    TEST_DATA / "oracle" / "scenes",
    TEST_DATA / "oracle_scenario_gen" / "scenes",
)


def all_cases(*names: str) -> list:
    """pytest params `(set, case)` of the named sets (all sets by default), one id per case."""
    import pytest

    params = []
    for s in SETS:
        if names and s.name not in names:
            continue
        cases = s.cases
        if not cases and not s.in_repository:
            params.append(pytest.param(s, None, id=f"{s.name}-absent"))
        params += [pytest.param(s, case, id=f"{s.name}-{case}") for case in cases]
    return params


def skip_if_absent(case_set: CaseSet, case: str | None) -> None:
    import pytest

    if case is None:
        pytest.skip(
            f"{case_set.folder} is absent: golden parity needs the official reference outputs "
            "(../shared, or WOSAC_SHARED, on developer machines and in CI; not in a user's clone)"
        )


@lru_cache(maxsize=None)
def _scenarios() -> dict:
    found = {}
    for folder in SCENE_FOLDERS:
        if folder.is_dir():
            for parsed, _ in iter_scenarios(folder):
                found.setdefault(parsed.scenario_id, parsed)
    return found


def scenario(scenario_id: str):
    """The `Scenario` message with this id, from any scene folder of the collections."""
    return _scenarios()[scenario_id]


def rollouts(case_set: CaseSet, case: str):
    path = case_set.folder / f"{case}.binproto"
    raw = (
        path.read_bytes() if path.exists() else gzip.decompress((case_set.folder / f"{case}.binproto.gz").read_bytes())
    )
    return sim_agents_submission_pb2.SimAgentsChallengeSubmission.FromString(raw).scenario_rollouts[0]


@lru_cache(maxsize=64)
def inputs(case_set: CaseSet, case: str):
    """(ScenarioArrays, RolloutArrays) of a case."""
    r = rollouts(case_set, case)
    return scenario_arrays(scenario(r.scenario_id)), rollout_arrays(r, case_set.challenge)


def device_inputs(case_set: CaseSet, cases: list, config_name: str):
    """`jax_realism.prepare` of `cases` with the device searches under the config `config_name`, and their
    rollouts stacked: (prepared, arrays). JAX is imported here, by its callers only."""
    from wosac_eval import jax_realism

    pairs = [inputs(case_set, c) for c in cases]
    prepared = jax_realism.prepare(
        [s for s, _ in pairs],
        challenge=case_set.challenge,
        config=config_reference(case_set, config_name),
        search="device",
    )
    return prepared, jax_realism.stack_rollouts(prepared, [r for _, r in pairs])


def expected_features(case_set: CaseSet, case: str):
    return np.load(case_set.folder / f"{case}.features.npz")


def expected_metrics(case_set: CaseSet, case: str, config_name: str) -> dict:
    return json.loads((case_set.folder / f"{case}.json").read_text())["metrics"][config_name]


def config_reference(case_set: CaseSet, name: str) -> str:
    """What `load_config` (and `jax_realism.prepare(config=...)`) takes for a set's config `name`:
    a preset's name, or the path of an official textproto in ../shared."""
    value = SHARED_CONFIGS.get(name, name) if case_set.name == "shared" else name
    return str(SHARED / value) if value.endswith(".textproto") else value


def config(case_set: CaseSet, name: str):
    return load_config(config_reference(case_set, name))


def assert_features_equal(ours, expected, where: str, names=EXACT_FEATURES) -> None:
    """Every named feature of (log, sim) `MetricFeatures` equal to the `log_*` / `sim_*` arrays, NaN for NaN."""
    for prefix, features in (("log_", ours[0]), ("sim_", ours[1])):
        for name in names:
            if prefix + name not in expected:
                continue  # e.g. object types were not stored with the oldest cases
            actual = np.asarray(getattr(features, name))
            wanted = np.asarray(expected[prefix + name])
            assert actual.shape == wanted.shape, (where, prefix + name, actual.shape, wanted.shape)
            np.testing.assert_array_equal(actual, wanted, err_msg=f"{where}: {prefix}{name}")


def as_feature_dict(pair) -> dict:
    """(log, sim) `MetricFeatures` as `{"log_<name>": ..., "sim_<name>": ...}`."""
    return {
        f"{prefix}{name}": getattr(features, name)
        for prefix, features in (("log_", pair[0]), ("sim_", pair[1]))
        for name in EXACT_FEATURES
    }
