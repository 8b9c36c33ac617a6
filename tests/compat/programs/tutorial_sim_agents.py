"""The official Sim Agents tutorial (waymo-open-dataset 1.6.7, tutorial/tutorial_sim_agents.ipynb), as a script.

Its calls, in its order, with two kinds of change only:
- the imports: `waymo_open_dataset.*` -> `wosac_eval.compat.*` / `wosac_eval.protos.*`;
- TensorFlow: the records are read with `wosac_eval.read_scenarios` instead of `tf.data`, and the
  tutorial's tensor arithmetic is written with numpy (the compat modules hand out numpy arrays).

    python tutorial_sim_agents.py 'SCENARIOS_GLOB' OUTPUT_DIR

Prints what the tutorial prints, and last a line `RESULT <json>` for the tests.
"""

import glob
import json
import os
import sys
import tarfile

import matplotlib

matplotlib.use("Agg")
# Set matplotlib to jshtml so animations work with colab.
from matplotlib import rc  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import tqdm  # noqa: E402

# The official imports, changed.
from wosac_eval.protos import scenario_pb2  # noqa: E402
from wosac_eval.protos import sim_agents_submission_pb2  # noqa: E402
from wosac_eval.compat import trajectory_utils  # noqa: E402
from wosac_eval.compat import submission_specs  # noqa: E402
from wosac_eval.compat import visualizations  # noqa: E402
from wosac_eval.compat import metric_features  # noqa: E402
from wosac_eval.compat import metrics  # noqa: E402
from wosac_eval import read_scenarios  # noqa: E402  (instead of tf.data.TFRecordDataset)

rc("animation", html="jshtml")

VALIDATION_FILES, OUTPUT_ROOT_DIRECTORY = sys.argv[1], sys.argv[2]
os.makedirs(OUTPUT_ROOT_DIRECTORY, exist_ok=True)
rng = np.random.default_rng(0)  # instead of tf.random

filenames = sorted(glob.glob(VALIDATION_FILES))
dataset_iterator = read_scenarios(filenames)
scenario = next(dataset_iterator)
print(f"Checking type: {type(scenario)}")
print(f"Loaded scenario with ID: {scenario.scenario_id}")

challenge_type = submission_specs.ChallengeType.SIM_AGENTS
submission_config = submission_specs.get_submission_config(challenge_type)
print(f"Simulation length, in steps: {submission_config.n_simulation_steps}")
print(
    f"Duration of a step, in seconds: {submission_config.step_duration_seconds}s "
    f"(frequency: {1 / submission_config.step_duration_seconds}Hz)"
)
print(f"Number of parallel simulations per Scenario: {submission_config.n_rollouts}")

# Visualize scenario.
fig, ax = plt.subplots(1, 1, figsize=(10, 10))
visualizations.add_map(ax, scenario)


def plot_track_trajectory(track: scenario_pb2.Track) -> None:
    valids = np.array([state.valid for state in track.states])
    if np.any(valids):
        x = np.array([state.center_x for state in track.states])
        y = np.array([state.center_y for state in track.states])
        ax.plot(x[valids], y[valids], linewidth=5)


for track in scenario.tracks:
    plot_track_trajectory(track)
plt.show()

print(f"Objects to be resimulated: {submission_specs.get_sim_agent_ids(scenario, challenge_type)}")
print(f"Total objects to be resimulated: {len(submission_specs.get_sim_agent_ids(scenario, challenge_type))}")
fig, ax = plt.subplots(1, 1, figsize=(10, 10))
visualizations.add_map(ax, scenario)
for track in scenario.tracks:
    if track.id in submission_specs.get_sim_agent_ids(scenario, challenge_type):
        plot_track_trajectory(track)
plt.show()


def simulate_with_extrapolation(scenario: scenario_pb2.Scenario, print_verbose_comments: bool = True):
    vprint = print if print_verbose_comments else lambda arg: None
    logged_trajectories = trajectory_utils.ObjectTrajectories.from_scenario(scenario)
    vprint(f"Original shape of tensors inside trajectories: {logged_trajectories.valid.shape} (n_objects, n_steps)")
    logged_trajectories = logged_trajectories.gather_objects_by_id(
        np.asarray(submission_specs.get_sim_agent_ids(scenario, challenge_type))
    )
    logged_trajectories = logged_trajectories.slice_time(
        start_index=0, end_index=submission_config.current_time_index + 1
    )
    vprint(f"Modified shape of tensors inside trajectories: {logged_trajectories.valid.shape} (n_objects, n_steps)")
    vprint(f"Are all agents valid: {np.all(logged_trajectories.valid[:, -1])}")
    states = np.stack(
        [logged_trajectories.x, logged_trajectories.y, logged_trajectories.z, logged_trajectories.heading], axis=-1
    )
    n_objects, _, _ = states.shape
    last_velocities = states[:, -1, :3] - states[:, -2, :3]
    last_velocities = np.concatenate([last_velocities, np.zeros((n_objects, 1), np.float32)], axis=-1)
    vprint(f"Is any 2nd to last state invalid: {np.any(np.logical_not(logged_trajectories.valid[:, -2]))}")
    vprint(f"This will result in either min or max speed to be really large: {np.max(np.abs(last_velocities))}")
    valid_diff = np.logical_and(logged_trajectories.valid[:, -1], logged_trajectories.valid[:, -2])
    last_velocities = np.where(valid_diff[:, np.newaxis], last_velocities, np.zeros_like(last_velocities))
    vprint(f"Now this should be back to a normal value: {np.max(np.abs(last_velocities))}")
    NOISE_SCALE = 0.01
    max_action = np.max(last_velocities, axis=0)
    simulated_states = np.tile(states[np.newaxis, :, -1:, :], [submission_config.n_rollouts, 1, 1, 1])
    vprint(f"Shape: {simulated_states.shape}")
    for _ in range(submission_config.n_simulation_steps):
        current_state = simulated_states[:, :, -1, :]
        action_noise = rng.normal(0.0, NOISE_SCALE, current_state.shape).astype(np.float32)
        actions_with_noise = last_velocities[None, :, :] + (action_noise * max_action)
        next_state = current_state + actions_with_noise
        simulated_states = np.concatenate([simulated_states, next_state[:, :, None, :]], axis=2)
    simulated_states = simulated_states[:, :, 1:, :]
    vprint(f"Final simulated states shape: {simulated_states.shape}")
    return logged_trajectories, simulated_states


logged_trajectories, simulated_states = simulate_with_extrapolation(scenario, print_verbose_comments=True)

n_objects = logged_trajectories.valid.shape[0]
lengths = np.broadcast_to(
    logged_trajectories.length[:, 10, np.newaxis], (n_objects, submission_config.n_simulation_steps)
)
widths = np.broadcast_to(
    logged_trajectories.width[:, 10, np.newaxis], (n_objects, submission_config.n_simulation_steps)
)
fig, ax = plt.subplots(1, 1, figsize=(10, 10))
animation = visualizations.get_animated_states(
    fig,
    ax,
    scenario,
    simulated_states[0, :, :, 0],
    simulated_states[0, :, :, 1],
    simulated_states[0, :, :, 3],
    lengths,
    widths,
    color_idx=np.zeros((n_objects, 80), dtype=np.int32),
)
# A notebook shows the animation (rc jshtml): the same HTML, written to a file here.
with open(os.path.join(OUTPUT_ROOT_DIRECTORY, "animation.html"), "w") as f:
    f.write(animation.to_jshtml())


def joint_scene_from_states(states, object_ids) -> sim_agents_submission_pb2.JointScene:
    simulated_trajectories = []
    for i_object in range(len(object_ids)):
        simulated_trajectories.append(
            sim_agents_submission_pb2.SimulatedTrajectory(
                center_x=states[i_object, :, 0],
                center_y=states[i_object, :, 1],
                center_z=states[i_object, :, 2],
                heading=states[i_object, :, 3],
                object_id=object_ids[i_object],
            )
        )
    return sim_agents_submission_pb2.JointScene(simulated_trajectories=simulated_trajectories)


joint_scene = joint_scene_from_states(simulated_states[0, :, :, :], logged_trajectories.object_id)
submission_specs.validate_joint_scene(joint_scene, scenario, challenge_type)


def scenario_rollouts_from_states(scenario, states, object_ids) -> sim_agents_submission_pb2.ScenarioRollouts:
    joint_scenes = []
    for i_rollout in range(states.shape[0]):
        joint_scenes.append(joint_scene_from_states(states[i_rollout], object_ids))
    return sim_agents_submission_pb2.ScenarioRollouts(joint_scenes=joint_scenes, scenario_id=scenario.scenario_id)


scenario_rollouts = scenario_rollouts_from_states(scenario, simulated_states, logged_trajectories.object_id)
submission_specs.validate_scenario_rollouts(scenario_rollouts, scenario)

single_scene_features = metric_features.compute_metric_features(scenario, joint_scene)
print(f"Evaluated objects: {submission_specs.get_evaluation_sim_agent_ids(scenario, challenge_type)}")
print(f"Evaluated objects in features: {single_scene_features.object_id}")
print(f"Are all agents valid: {np.all(single_scene_features.valid)}")
print(f"ADE: {np.mean(single_scene_features.average_displacement_error)}")
fig, axes = plt.subplots(1, 4, figsize=(16, 4))
for i_object in range(len(single_scene_features.object_id)):
    _object_id = single_scene_features.object_id[i_object]
    axes[0].plot(single_scene_features.linear_speed[0, i_object, :], label=str(_object_id))
    axes[1].plot(single_scene_features.linear_acceleration[0, i_object, :], label=str(_object_id))
    axes[2].plot(single_scene_features.angular_speed[0, i_object, :], label=str(_object_id))
    axes[3].plot(single_scene_features.angular_acceleration[0, i_object, :], label=str(_object_id))
for ax, title in zip(axes, ["linear_speed", "linear_acceleration", "angular_speed", "angular_acceleration"]):
    ax.legend()
    ax.set_title(title)
plt.show()
print(f"Colliding objects: {single_scene_features.collision_per_step[0]}")
print(f"Offroad objects: {single_scene_features.offroad_per_step[0]}")

config = metrics.load_metrics_config(challenge_type)
scenario_metrics = metrics.compute_scenario_metrics_for_bundle(config, scenario, scenario_rollouts)
print(scenario_metrics)
plt.close("all")
# (Not in the tutorial: the rollouts scored above, kept for the tests to score them independently.)
with open(os.path.join(OUTPUT_ROOT_DIRECTORY, "first_scenario_rollouts.binproto"), "wb") as f:
    f.write(scenario_rollouts.SerializeToString())

# The submission: two scenarios per shard, one binproto per shard, a tar.gz of them.
os.makedirs(OUTPUT_ROOT_DIRECTORY, exist_ok=True)
output_filenames = []
for index, shard_filename in enumerate(tqdm.tqdm(filenames)):
    shard_suffix = f"-{index:05d}-of-{len(filenames):05d}"
    scenario_rollouts = []
    for n, scenario in enumerate(read_scenarios(shard_filename)):
        if n == 2:
            break
        logged_trajectories, simulated_states = simulate_with_extrapolation(scenario, print_verbose_comments=False)
        sr = scenario_rollouts_from_states(scenario, simulated_states, logged_trajectories.object_id)
        submission_specs.validate_scenario_rollouts(sr, scenario)
        scenario_rollouts.append(sr)
    shard_submission = sim_agents_submission_pb2.SimAgentsChallengeSubmission(
        scenario_rollouts=scenario_rollouts,
        submission_type=sim_agents_submission_pb2.SimAgentsChallengeSubmission.SIM_AGENTS_SUBMISSION,
        account_name="your_account@test.com",
        unique_method_name="sim_agents_tutorial",
        authors=["test"],
        affiliation="waymo",
        description="Submission from the Sim Agents tutorial",
        method_link="https://waymo.com/open/",
        uses_lidar_data=False,
        uses_camera_data=False,
        uses_public_model_pretraining=False,
        num_model_parameters="24",
        acknowledge_complies_with_closed_loop_requirement=True,
    )
    output_filename = f"submission.binproto{shard_suffix}"
    with open(os.path.join(OUTPUT_ROOT_DIRECTORY, output_filename), "wb") as f:
        f.write(shard_submission.SerializeToString())
    output_filenames.append(output_filename)
with tarfile.open(os.path.join(OUTPUT_ROOT_DIRECTORY, "submission.tar.gz"), "w:gz") as tar:
    for output_filename in output_filenames:
        tar.add(os.path.join(OUTPUT_ROOT_DIRECTORY, output_filename), arcname=output_filename)

# (Not in the tutorial: what the tests compare.)
np.savez(
    os.path.join(OUTPUT_ROOT_DIRECTORY, "single_scene_features.npz"),
    **{name: getattr(single_scene_features, name) for name in single_scene_features.__dataclass_fields__},
)
print(
    "RESULT "
    + json.dumps(
        {
            "scenario_id": scenario_metrics.scenario_id,
            "metametric": scenario_metrics.metametric,
            "shards": output_filenames,
        }
    )
)
