"""A WOSAC evaluator and per-step realism logger written for the official waymo-open-dataset package, as open-source
driving simulators write theirs, run on wosac-eval with no line changed but the first one (the opt-in).

It finds the official config under the package root, simulates the scenario with a constant-velocity policy,
validates and scores the rollouts, and logs the per-step realism features of the first rollout with the
official feature functions.

    python official_evaluator.py SCENARIO.binproto OUT_DIR

Writes OUT_DIR/rollouts.binproto and OUT_DIR/features.npz; prints a last line `RESULT <json>`.
"""

import wosac_eval.compat.official_names  # noqa: F401, I001  (the one line added to the official program)

import json
import os
import sys

import numpy as np
from google.protobuf import text_format

import waymo_open_dataset
from waymo_open_dataset.protos import map_pb2, scenario_pb2, sim_agents_metrics_pb2, sim_agents_submission_pb2
from waymo_open_dataset.utils import trajectory_utils
from waymo_open_dataset.utils.sim_agents import converters, submission_specs
from waymo_open_dataset.wdl_limited.sim_agents_metrics import (
    interaction_features,
    map_metric_features,
    metrics,
    traffic_light_features,
    trajectory_features,
)

CHALLENGE = submission_specs.ChallengeType.SIM_AGENTS
CONFIG_PATH = os.path.join(
    waymo_open_dataset.__path__[0], "wdl_limited/sim_agents_metrics/challenge_2025_sim_agents_config.textproto"
)


def load_config() -> sim_agents_metrics_pb2.SimAgentMetricsConfig:
    with open(CONFIG_PATH) as f:
        return text_format.Parse(f.read(), sim_agents_metrics_pb2.SimAgentMetricsConfig())


def constant_velocity_rollouts(scenario, n_rollouts, rng):
    """Every sim agent continues at its last logged velocity, with a little noise per rollout."""
    config = submission_specs.get_submission_config(CHALLENGE)
    now = config.current_time_index
    logged = trajectory_utils.ObjectTrajectories.from_scenario(scenario)
    agents = logged.gather_objects_by_id(submission_specs.get_sim_agent_ids(scenario, CHALLENGE))
    agents = agents.slice_time(0, now + 1)
    x, y, z, heading = (np.asarray(v) for v in (agents.x, agents.y, agents.z, agents.heading))
    velocity = (np.stack([x[:, -1] - x[:, -2], y[:, -1] - y[:, -2]], -1)) / config.step_duration_seconds
    steps = np.arange(1, config.n_simulation_steps + 1) * config.step_duration_seconds
    scenes = []
    for _ in range(n_rollouts):
        noisy = velocity + rng.normal(0, 0.3, velocity.shape)
        scene = sim_agents_submission_pb2.JointScene()
        for k, object_id in enumerate(np.asarray(agents.object_id)):
            scene.simulated_trajectories.append(
                sim_agents_submission_pb2.SimulatedTrajectory(
                    center_x=x[k, -1] + noisy[k, 0] * steps,
                    center_y=y[k, -1] + noisy[k, 1] * steps,
                    center_z=np.full(steps.shape, z[k, -1]),
                    heading=np.full(steps.shape, heading[k, -1]),
                    object_id=int(object_id),
                )
            )
        scenes.append(scene)
    return sim_agents_submission_pb2.ScenarioRollouts(scenario_id=scenario.scenario_id, joint_scenes=scenes)


def realism_log(scenario, joint_scene):
    """The per-step features of one rollout, for the evaluated objects: what a training-time logger records."""
    t = converters.joint_scene_to_trajectories(joint_scene, scenario)
    evaluated = np.isin(np.asarray(t.object_id), submission_specs.get_evaluation_sim_agent_ids(scenario, CHALLENGE))
    boxes = {"center_x": t.x, "center_y": t.y, "length": t.length, "width": t.width, "heading": t.heading}
    speed, accel, angular_speed, angular_accel = trajectory_features.compute_kinematic_features(
        t.x[evaluated], t.y[evaluated], t.z[evaluated], t.heading[evaluated], seconds_per_step=0.1
    )
    speed_valid, _ = trajectory_features.compute_kinematic_validity(t.valid[evaluated])
    distance = interaction_features.compute_distance_to_nearest_object(
        **boxes, center_z=t.z, height=t.height, valid=t.valid, evaluated_object_mask=evaluated
    )
    ttc = interaction_features.compute_time_to_collision_with_object_in_front(
        **boxes, valid=t.valid, evaluated_object_mask=evaluated, seconds_per_step=0.1
    )
    road_edges = [f.road_edge.polyline for f in scenario.map_features if f.HasField("road_edge")]
    road = map_metric_features.compute_distance_to_road_edge(
        **boxes,
        center_z=t.z,
        height=t.height,
        valid=t.valid,
        evaluated_object_mask=evaluated,
        road_edge_polylines=road_edges,
    )
    surface = map_pb2.LaneCenter.LaneType.TYPE_SURFACE_STREET
    lanes = [f for f in scenario.map_features if f.HasField("lane") and f.lane.type == surface]
    red = traffic_light_features.compute_red_light_violation(
        center_x=t.x,
        center_y=t.y,
        valid=t.valid,
        evaluated_object_mask=evaluated,
        lane_polylines=[f.lane.polyline for f in lanes],
        lane_ids=[f.id for f in lanes],
        traffic_signals=[list(s.lane_states) for s in scenario.dynamic_map_states],
    )
    return {
        "object_id": np.asarray(t.object_id)[evaluated],
        "linear_speed": speed.numpy(),
        "linear_acceleration": accel.numpy(),
        "angular_speed": angular_speed.numpy(),
        "angular_acceleration": angular_accel.numpy(),
        "speed_valid": speed_valid.numpy(),
        "distance_to_nearest_object": distance.numpy(),
        "collision": (distance < interaction_features.COLLISION_DISTANCE_THRESHOLD).numpy(),
        "time_to_collision": ttc.numpy(),
        "distance_to_road_edge": road.numpy(),
        "offroad": (road > map_metric_features.OFFROAD_DISTANCE_THRESHOLD).numpy(),
        "red_light_violation": red.numpy(),
    }


def main(scenario_path: str, out_dir: str) -> None:
    os.makedirs(out_dir, exist_ok=True)
    with open(scenario_path, "rb") as f:
        scenario = scenario_pb2.Scenario.FromString(f.read())
    config = load_config()
    rollouts = constant_velocity_rollouts(
        scenario, submission_specs.get_submission_config(CHALLENGE).n_rollouts, np.random.default_rng(0)
    )
    submission_specs.validate_scenario_rollouts(rollouts, scenario)
    scenario_metrics = metrics.compute_scenario_metrics_for_bundle(config, scenario, rollouts)
    buckets = metrics.aggregate_metrics_to_buckets(config, metrics.aggregate_scenario_metrics([scenario_metrics]))
    log = realism_log(scenario, rollouts.joint_scenes[0])
    with open(os.path.join(out_dir, "rollouts.binproto"), "wb") as f:
        f.write(rollouts.SerializeToString())
    np.savez(os.path.join(out_dir, "features.npz"), **log)
    reported = slice(submission_specs.get_submission_config(CHALLENGE).current_time_index + 1, None)
    print(f"Realism meta-metric: {scenario_metrics.metametric:.4f}; kinematic {buckets.kinematic_metrics:.4f}")
    print(
        "RESULT "
        + json.dumps(
            {
                "config_path": CONFIG_PATH,
                "metametric": scenario_metrics.metametric,
                "realism_meta_metric": buckets.realism_meta_metric,
                "collision_rate": float(log["collision"][:, reported].mean()),
                "offroad_rate": float(log["offroad"][:, reported].mean()),
                "metrics_module": metrics.__name__,
            }
        )
    )


if __name__ == "__main__":
    main(*sys.argv[1:])
