"""Scenario Generation golden cases for what the official validator accepts but looks wrong (run with the oracle's python).

    ~/.wosac-oracle/bin/python scripts/oracle_reference_arithmetic.py \
        scripts/oracle_scenario_gen_edge_cases.py OUT_DIR SCENE.tfrecord [SCENE.tfrecord ...]

For each scene, two cases in the layout of ../shared/oracle/make_scenario_gen_golden.py
(`<scenario_id>__sg_<policy>.{binproto.gz,json,features.npz}`):

- `logged_boxes`: 32 copies of the official `converters.scenario_to_joint_scene` (the log as a
  submission): the logged boxes are 0 on a track's invalid steps, and the official scores them so.
- `odd_boxes`: the log's positions with a small drift, box sizes 0 on some steps and negative on
  others, and no object_type on every other object (scored as TYPE_UNSET).

Both pass the official `validate_scenario_rollouts`; wosac-eval's validator reports them as warnings
(`rollouts.non_positive_size`, `rollouts.missing_object_type`) and must score them as the official does.
"""

import gzip
import json
import os
import sys

os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
import numpy as np  # noqa: E402
import tensorflow as tf  # noqa: E402
from google.protobuf import text_format  # noqa: E402
from waymo_open_dataset.protos import scenario_pb2, sim_agents_metrics_pb2, sim_agents_submission_pb2  # noqa: E402
from waymo_open_dataset.utils.sim_agents import converters, submission_specs  # noqa: E402
from waymo_open_dataset.wdl_limited.sim_agents_metrics import metric_features, metrics  # noqa: E402

SG = submission_specs.ChallengeType.SCENARIO_GEN
SHARED = os.environ.get("WOSAC_SHARED") or os.path.join(
    os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared"
)
FIELDS = (
    "object_id",
    "object_type",
    "valid",
    "average_displacement_error",
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
)


def rollouts_of(scenario, policy: str, rng) -> sim_agents_submission_pb2.ScenarioRollouts:
    logged = converters.scenario_to_joint_scene(scenario, SG)
    scenes = []
    for _ in range(32):
        scene = sim_agents_submission_pb2.JointScene()
        scene.CopyFrom(logged)
        if policy == "odd_boxes":
            for k, t in enumerate(scene.simulated_trajectories):
                for name in ("center_x", "center_y"):
                    values = np.asarray(getattr(t, name), np.float64) + np.cumsum(rng.normal(0, 0.05, 91))
                    del getattr(t, name)[:]
                    getattr(t, name).extend(values.tolist())
                t.length[k % 91] = 0.0
                t.width[(3 * k + 1) % 91] = -1.5
                t.height[(5 * k + 2) % 91] = 0.0
                if k % 2:
                    t.ClearField("object_type")
        elif policy != "logged_boxes":
            raise ValueError(policy)
        scenes.append(scene)
    return sim_agents_submission_pb2.ScenarioRollouts(scenario_id=scenario.scenario_id, joint_scenes=scenes)


def main(out_dir: str, *scene_files: str) -> None:
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(SHARED, "official-configs", "challenge_2025_scenario_gen_config.textproto")
    config = text_format.Parse(open(path).read(), sim_agents_metrics_pb2.SimAgentMetricsConfig())
    rng = np.random.default_rng(3)
    for scene_file in scene_files:
        scenario = scenario_pb2.Scenario.FromString(next(iter(tf.data.TFRecordDataset(scene_file))).numpy())
        for policy in ("logged_boxes", "odd_boxes"):
            rollouts = rollouts_of(scenario, policy, rng)
            submission_specs.validate_scenario_rollouts(rollouts, scenario, SG)
            tag = f"{scenario.scenario_id}__sg_{policy}"
            submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission(
                scenario_rollouts=[rollouts],
                submission_type=sim_agents_submission_pb2.SimAgentsChallengeSubmission.SIM_AGENTS_SUBMISSION,
                account_name="golden@example.com",
                unique_method_name="sg_" + policy,
                authors=["golden"],
                affiliation="golden",
                description=f"scenario-gen edge case {policy}",
                method_link="https://example.com",
                uses_lidar_data=False,
                uses_camera_data=False,
                uses_public_model_pretraining=False,
                num_model_parameters="0",
                acknowledge_complies_with_closed_loop_requirement=True,
            )
            with open(os.path.join(out_dir, tag + ".binproto.gz"), "wb") as f:
                f.write(gzip.compress(submission.SerializeToString(), mtime=0))
            log_f, sim_f = metric_features.compute_scenario_rollouts_features(scenario, rollouts, SG)
            m = metrics.compute_scenario_metrics_for_features_bundle(config, scenario.scenario_id, log_f, sim_f)
            values = {f.name: v for f, v in m.ListFields() if f.name != "scenario_id"}
            values["buckets"] = {f.name: v for f, v in metrics.aggregate_metrics_to_buckets(config, m).ListFields()}
            result = {
                "scenario_id": scenario.scenario_id,
                "policy": "sg_" + policy,
                "challenge": "scenario_gen",
                "n_evaluated_objects": len(rollouts.joint_scenes[0].simulated_trajectories),
                "metrics": {"scenario_gen_2025": values},
            }
            with open(os.path.join(out_dir, tag + ".json"), "w") as f:
                json.dump(result, f, indent=1, default=float)
            np.savez_compressed(
                os.path.join(out_dir, tag + ".features.npz"),
                **{"log_" + k: np.asarray(getattr(log_f, k)) for k in FIELDS},
                **{"sim_" + k: np.asarray(getattr(sim_f, k)) for k in FIELDS},
            )
            print(tag, "metametric", values["metametric"], flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:])
