"""The official `converters.scenario_to_joint_scene` output for scenes, both challenges (run with the oracle's python).

    ~/.wosac-oracle/bin/python scripts/oracle_joint_scenes.py OUT_DIR SCENE.tfrecord [SCENE.tfrecord ...]

Writes OUT_DIR/<scenario_id>__<challenge>.joint_scene.binproto: what
`wosac_eval.compat.converters.scenario_to_joint_scene` must reproduce byte for byte.
"""

import sys
from pathlib import Path

import tensorflow as tf
from waymo_open_dataset.protos import scenario_pb2
from waymo_open_dataset.utils.sim_agents import converters, submission_specs


def main(out_dir: str, *scene_files: str) -> None:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for path in scene_files:
        for record in tf.data.TFRecordDataset(path):
            scenario = scenario_pb2.Scenario.FromString(record.numpy())
            for challenge in submission_specs.ChallengeType:
                scene = converters.scenario_to_joint_scene(scenario, challenge)
                name = f"{scenario.scenario_id}__{challenge.value}.joint_scene.binproto"
                (out / name).write_bytes(scene.SerializeToString())
                print(name, len(scene.simulated_trajectories), "objects")


if __name__ == "__main__":
    main(*sys.argv[1:])
