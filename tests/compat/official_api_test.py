"""The rest of the official API that client programs call: trajectories, converters, features, pictures.

`trajectory_utils.ObjectTrajectories`, `converters.joint_scene_to_trajectories`
and `simulated_scenariogen_to_trajectories`, `metric_features`,
`metrics.compute_scenario_metrics_for_features_bundle` and `visualizations`,
checked against the scenarios' tracks, the official per-feature arrays
(golden cases: bit for bit, dtypes included) and the official metrics; and
the signatures of every public function of the official modules (1.6.7).
"""

from __future__ import annotations

import dataclasses
import inspect

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from support import golden  # noqa: E402
from support.paths import TEST_DATA  # noqa: E402
from wosac_eval.compat import (
    converters,
    metric_features,
    metrics,
    submission_specs,  # noqa: E402
    trajectory_utils,
    visualizations,
)
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2  # noqa: E402

CHALLENGE_TYPES = {
    "sim_agents": submission_specs.ChallengeType.SIM_AGENTS,
    "scenario_gen": submission_specs.ChallengeType.SCENARIO_GEN,
}
# Official dtypes of the features (`tf.convert_to_tensor` of Python ints gives int32).
FEATURE_DTYPES = {
    "object_id": np.int32,
    "object_type": np.int32,
    "valid": np.bool_,
    "collision_per_step": np.bool_,
    "offroad_per_step": np.bool_,
    "traffic_light_violation_per_step": np.bool_,
}


def _scene(name: str) -> scenario_pb2.Scenario:
    from wosac_eval.parse.scenarios import iter_scenarios

    return next(s for s, _ in iter_scenarios(TEST_DATA / "oracle" / "scenes" / name))


def _scenarios():
    """A repository scene everywhere, and the real WOMD scenario where ../shared is present."""
    params = [pytest.param("occlusion.tfrecord", id="occlusion")]
    params.append(pytest.param("637f20cafde22ff8", id="womd-637f20cafde22ff8"))
    return params


def _load(name: str) -> scenario_pb2.Scenario:
    if name.endswith(".tfrecord"):
        return _scene(name)
    from support.paths import require_shared

    require_shared("womd")
    return golden.scenario(name)


# -- trajectory_utils -------------------------------------------------------------------------------


@pytest.mark.parametrize("name", _scenarios())
def test_from_scenario_holds_every_track_in_track_order(name):
    scenario = _load(name)
    t = trajectory_utils.ObjectTrajectories.from_scenario(scenario)
    n, steps = len(scenario.tracks), len(scenario.tracks[0].states)
    for field, dtype in (
        ("x", np.float32),
        ("y", np.float32),
        ("z", np.float32),
        ("heading", np.float32),
        ("length", np.float32),
        ("width", np.float32),
        ("height", np.float32),
        ("valid", np.bool_),
    ):
        value = getattr(t, field)
        assert isinstance(value, np.ndarray) and value.dtype == dtype and value.shape == (n, steps), field
    assert t.object_id.dtype == np.int32 and t.object_type.dtype == np.int32
    assert t.object_id.tolist() == [track.id for track in scenario.tracks]
    assert t.object_type.tolist() == [track.object_type for track in scenario.tracks]
    proto_field = {"x": "center_x", "y": "center_y", "z": "center_z"}
    for k, track in enumerate(scenario.tracks):
        for field in ("x", "y", "z", "heading", "length", "width", "height", "valid"):
            expected = [getattr(s, proto_field.get(field, field)) for s in track.states]
            np.testing.assert_array_equal(
                getattr(t, field)[k], np.array(expected, np.bool_ if field == "valid" else np.float32)
            )


@pytest.mark.parametrize("name", _scenarios())
def test_from_scenario_is_the_library_log(name):
    """The same float32 values as the arrays the features are computed from."""
    from wosac_eval.arrays.scenario import scenario_arrays

    scenario = _load(name)
    t = trajectory_utils.ObjectTrajectories.from_scenario(scenario)
    log = scenario_arrays(scenario).log.take_ids(t.object_id.astype(np.int64))
    for field in ("x", "y", "z", "heading", "length", "width", "height", "valid", "object_type"):
        np.testing.assert_array_equal(getattr(t, field), getattr(log, field), err_msg=field)


def test_gather_and_slice_return_new_objects_with_the_official_semantics():
    scenario = _scene("occlusion.tfrecord")
    t = trajectory_utils.ObjectTrajectories.from_scenario(scenario)
    ids = submission_specs.get_sim_agent_ids(scenario, submission_specs.ChallengeType.SIM_AGENTS)
    wanted = list(reversed(ids))[:3]
    gathered = t.gather_objects_by_id(np.array(wanted, np.int32))
    assert gathered.object_id.tolist() == wanted  # the order asked for
    rows = [t.object_id.tolist().index(i) for i in wanted]
    for field in ("x", "heading", "length", "valid"):
        np.testing.assert_array_equal(getattr(gathered, field), getattr(t, field)[rows])
    assert gathered.gather_objects_by_id(wanted).object_id.tolist() == wanted
    np.testing.assert_array_equal(t.gather_objects_by_id(wanted).x, gathered.x)  # a list of ints works too
    # By position, repeats allowed (a gather).
    twice = t.gather_objects(np.array([1, 1, 0]))
    assert twice.object_id.tolist() == [t.object_id[1], t.object_id[1], t.object_id[0]]
    assert twice.x.shape == (3, t.x.shape[1])
    with pytest.raises(ValueError):
        t.gather_objects_by_id([max(ids) + 1000])
    with pytest.raises(IndexError):
        t.gather_objects([len(scenario.tracks)])
    with pytest.raises(ValueError):
        t.gather_objects([[0]])
    # slice_time(start_index, end_index): the time axis only, Python slice semantics.
    history = t.slice_time(start_index=0, end_index=11)
    assert history.x.shape == (t.x.shape[0], 11) and history.valid.shape == (t.x.shape[0], 11)
    np.testing.assert_array_equal(history.heading, t.heading[:, :11])
    future = t.slice_time(11)
    assert future.x.shape[1] == t.x.shape[1] - 11
    np.testing.assert_array_equal(future.width, t.width[:, 11:])
    assert t.slice_time(-2).x.shape[1] == 2
    assert future.object_id is t.object_id and future.object_type is t.object_type
    assert t.x.shape == (len(scenario.tracks), 91)  # unchanged
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.x = None


def test_gather_by_id_refuses_repeated_ids_among_the_trajectories():
    t = trajectory_utils.ObjectTrajectories.from_scenario(_scene("occlusion.tfrecord"))
    doubled = t.gather_objects([0, 0, 1])
    with pytest.raises(ValueError, match="more than once"):
        doubled.gather_objects_by_id([t.object_id[0]])
    assert doubled.gather_objects_by_id([t.object_id[1]]).object_id.tolist() == [t.object_id[1]]


def test_gather_works_on_batched_trajectories():
    """The object axis is the second last of time series and the last of ids, as officially."""
    t = trajectory_utils.ObjectTrajectories.from_scenario(_scene("occlusion.tfrecord"))
    batched = trajectory_utils.ObjectTrajectories(
        **{f: np.stack([getattr(t, f)] * 2) for f in ("x", "y", "z", "heading", "length", "width", "height", "valid")},
        object_id=t.object_id,
        object_type=np.stack([t.object_type] * 2),
    )
    picked = batched.gather_objects([2, 0])
    assert picked.x.shape == (2, 2, 91) and picked.object_type.shape == (2, 2)
    np.testing.assert_array_equal(picked.y[1], t.y[[2, 0]])


# -- converters --------------------------------------------------------------------------------------


def _case(case_set_name: str, case: str):
    case_set = next(s for s in golden.SETS if s.name == case_set_name)
    rollouts = golden.rollouts(case_set, case)
    return case_set, golden.scenario(rollouts.scenario_id), rollouts


@pytest.mark.parametrize("use_log_validity", [False, True])
def test_joint_scene_to_trajectories_prepends_the_logged_history(use_log_validity):
    _, scenario, rollouts = _case("oracle", "synthetic-7-000-occlusion__wild")
    scene = rollouts.joint_scenes[5]
    t = converters.joint_scene_to_trajectories(scene, scenario, use_log_validity=use_log_validity)
    ids = [s.object_id for s in scene.simulated_trajectories]
    assert t.object_id.dtype == np.int32 and t.object_id.tolist() == ids
    log = trajectory_utils.ObjectTrajectories.from_scenario(scenario).gather_objects_by_id(ids)
    assert t.x.shape == (len(ids), 91) and t.x.dtype == np.float32 and t.valid.dtype == np.bool_
    for field, proto in (("x", "center_x"), ("y", "center_y"), ("z", "center_z"), ("heading", "heading")):
        np.testing.assert_array_equal(getattr(t, field)[:, :11], getattr(log, field)[:, :11])
        np.testing.assert_array_equal(
            getattr(t, field)[:, 11:], np.array([getattr(s, proto) for s in scene.simulated_trajectories], np.float32)
        )
    for field in ("length", "width", "height"):  # frozen at the current step
        np.testing.assert_array_equal(
            getattr(t, field),
            np.concatenate([getattr(log, field)[:, :11], np.repeat(getattr(log, field)[:, 10:11], 80, axis=1)], 1),
        )
    np.testing.assert_array_equal(t.valid[:, :11], log.valid[:, :11])
    np.testing.assert_array_equal(t.valid[:, 11:], log.valid[:, 11:] if use_log_validity else True)
    np.testing.assert_array_equal(t.object_type, log.object_type)


def test_joint_scene_to_trajectories_is_what_the_features_see():
    """The library's composite of a rollout (`arrays.samples`), object by object."""
    from wosac_eval.arrays.rollouts import rollout_arrays
    from wosac_eval.arrays.samples import rollout_samples
    from wosac_eval.arrays.scenario import scenario_arrays

    _, scenario, rollouts = _case("oracle", "synthetic-7-000-dense-following__constvel_noise")
    composite, _ = rollout_samples(scenario_arrays(scenario), rollout_arrays(rollouts))
    for r in (0, 31):
        t = converters.joint_scene_to_trajectories(rollouts.joint_scenes[r], scenario)
        ours = t.gather_objects_by_id(composite.object_id[r].astype(np.int32))
        for field in ("x", "y", "z", "heading", "length", "width", "height", "valid"):
            np.testing.assert_array_equal(getattr(ours, field), getattr(composite, field)[r], err_msg=field)


def test_simulated_scenariogen_to_trajectories_takes_the_submitted_boxes():
    _, scenario, rollouts = _case("oracle_scenario_gen", "synthetic-5-001-red-light__sg_constvel_noise")
    scene = rollouts.joint_scenes[2]
    challenge = submission_specs.ChallengeType.SCENARIO_GEN
    t = converters.simulated_scenariogen_to_trajectories(scene, scenario, challenge)
    trajectories = scene.simulated_trajectories
    assert t.object_id.dtype == np.int32 and t.object_id.tolist() == [s.object_id for s in trajectories]
    assert t.object_type.dtype == np.int32 and t.object_type.tolist() == [s.object_type for s in trajectories]
    for field, proto in (("x", "center_x"), ("heading", "heading"), ("length", "length"), ("height", "height")):
        value = getattr(t, field)
        assert value.dtype == np.float32 and value.shape == (len(trajectories), 91)
        np.testing.assert_array_equal(value, np.array([getattr(s, proto) for s in trajectories], np.float32))
    # Valid wherever the logged object is valid at the current step, whatever was submitted.
    log = trajectory_utils.ObjectTrajectories.from_scenario(scenario).gather_objects_by_id(t.object_id)
    np.testing.assert_array_equal(t.valid, np.repeat(log.valid[:, 10:11], 91, axis=1))


def test_converters_name_a_foreign_object():
    scenario = _scene("occlusion.tfrecord")
    scene = converters.scenario_to_joint_scene(scenario)
    scene.simulated_trajectories[0].object_id = 987654
    with pytest.raises(ValueError, match="987654"):
        converters.joint_scene_to_trajectories(scene, scenario)


# -- metric_features and the features bundle ----------------------------------------------------------


def _assert_official_features(ours, expected, prefix: str, rows=slice(None), where: str = "") -> None:
    names = [f.name for f in dataclasses.fields(metric_features.MetricFeatures)]
    for name in names:
        if prefix + name not in expected:
            continue
        actual = getattr(ours, name)
        wanted = expected[prefix + name]
        if name != "object_id":
            wanted = wanted[rows]
        assert isinstance(actual, np.ndarray), name
        assert actual.dtype == wanted.dtype == FEATURE_DTYPES.get(name, np.float32), (where, name, actual.dtype)
        assert actual.shape == wanted.shape, (where, name, actual.shape, wanted.shape)
        np.testing.assert_array_equal(actual, wanted, err_msg=f"{where}: {prefix}{name}")


@pytest.mark.parametrize(("case_set", "case"), golden.all_cases())
def test_rollouts_features_are_the_official_arrays_bit_for_bit(case_set, case):
    golden.skip_if_absent(case_set, case)
    rollouts = golden.rollouts(case_set, case)
    scenario = golden.scenario(rollouts.scenario_id)
    log, sim = metric_features.compute_scenario_rollouts_features(
        scenario, rollouts, CHALLENGE_TYPES[case_set.challenge]
    )
    assert isinstance(log, metric_features.MetricFeatures) and isinstance(sim, metric_features.MetricFeatures)
    expected = golden.expected_features(case_set, case)
    _assert_official_features(log, expected, "log_", where=case)
    _assert_official_features(sim, expected, "sim_", where=case)
    assert log.valid.shape[0] == 1 and sim.valid.shape[0] == len(rollouts.joint_scenes)


@pytest.mark.parametrize(("case_set", "case"), golden.all_cases())
def test_features_bundle_gives_the_official_metrics(case_set, case):
    golden.skip_if_absent(case_set, case)
    rollouts = golden.rollouts(case_set, case)
    scenario = golden.scenario(rollouts.scenario_id)
    challenge = CHALLENGE_TYPES[case_set.challenge]
    log, sim = metric_features.compute_scenario_rollouts_features(scenario, rollouts, challenge)
    for config_name in case_set.configs:
        config = golden.config(case_set, config_name)
        result = metrics.compute_scenario_metrics_for_features_bundle(config, scenario.scenario_id, log, sim)
        assert result.DESCRIPTOR.name == "SimAgentMetrics" and result.scenario_id == scenario.scenario_id
        for field, value in golden.expected_metrics(case_set, case, config_name).items():
            if field != "buckets":
                assert getattr(result, field) == pytest.approx(value, abs=1e-5), (config_name, field)
        bundle = metrics.compute_scenario_metrics_for_bundle(config, scenario, rollouts, challenge_type=challenge)
        assert result == bundle  # the same message, field for field


def test_features_bundle_reads_any_arrays():
    """Features rebuilt by a client (lists, another array type) give the same message."""
    _, scenario, rollouts = _case("oracle", "synthetic-7-000-collision__logreplay_noise05")
    log, sim = metric_features.compute_scenario_rollouts_features(
        scenario, rollouts, submission_specs.ChallengeType.SIM_AGENTS
    )
    config = metrics.load_metrics_config(submission_specs.ChallengeType.SIM_AGENTS)
    expected = metrics.compute_scenario_metrics_for_features_bundle(config, "x", log, sim)
    as_lists = metric_features.MetricFeatures(
        **{f.name: getattr(sim, f.name).tolist() for f in dataclasses.fields(sim)}
    )
    assert metrics.compute_scenario_metrics_for_features_bundle(config, "x", log, as_lists) == expected


@pytest.mark.parametrize(
    ("case_set_name", "case", "rollout"),
    [
        ("oracle", "synthetic-7-000-red-light__constvel_noise", 7),
        ("oracle", "synthetic-7-000-occlusion__wild", 31),
        ("oracle_scenario_gen", "synthetic-5-001-red-light__sg_constvel_noise", 3),
        ("shared", "637f20cafde22ff8__official_test_submission", 12),
        ("shared_scenario_gen", "synthetic-11-000-intersection__sg_wild_boxes", 20),
    ],
)
def test_one_joint_scene_features_are_the_official_sample(case_set_name, case, rollout):
    case_set = next(s for s in golden.SETS if s.name == case_set_name)
    golden.skip_if_absent(case_set, case if case in case_set.cases else None)
    rollouts = golden.rollouts(case_set, case)
    scenario = golden.scenario(rollouts.scenario_id)
    challenge = CHALLENGE_TYPES[case_set.challenge]
    expected = golden.expected_features(case_set, case)
    one = metric_features.compute_metric_features(scenario, rollouts.joint_scenes[rollout], challenge)
    _assert_official_features(one, expected, "sim_", slice(rollout, rollout + 1), where=f"{case} rollout {rollout}")
    # The log's features: the logged scene as a joint scene, with the log's validity.
    logged = converters.scenario_to_joint_scene(scenario, challenge)
    log = metric_features.compute_metric_features(scenario, logged, challenge, use_log_validity=True)
    _assert_official_features(log, expected, "log_", where=f"{case} log")


def test_one_joint_scene_with_log_validity_counts_the_logs_steps():
    """A simulated scene with the log's validity: the features are computed with the logged validity mask
    (as the official code does for any joint scene given with the flag)."""
    _, scenario, rollouts = _case("oracle", "synthetic-7-000-occlusion__wild")
    scene = rollouts.joint_scenes[0]
    flagged = metric_features.compute_metric_features(scenario, scene, use_log_validity=True)
    plain = metric_features.compute_metric_features(scenario, scene)
    log = metric_features.compute_metric_features(
        scenario, converters.scenario_to_joint_scene(scenario), use_log_validity=True
    )
    np.testing.assert_array_equal(flagged.valid, log.valid)
    assert plain.valid.all() and not log.valid.all()  # the occlusion scene has logged gaps
    np.testing.assert_array_equal(flagged.linear_speed, plain.linear_speed)  # kinematics ignore validity
    np.testing.assert_array_equal(flagged.average_displacement_error, plain.average_displacement_error)


def test_metric_features_fields_are_the_official_ones():
    assert [f.name for f in dataclasses.fields(metric_features.MetricFeatures)] == [
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
    ]


# -- visualizations ----------------------------------------------------------------------------------


def test_add_map_draws_road_edges_and_road_lines():
    import matplotlib.pyplot as plt

    scenario = _scene("occlusion.tfrecord")
    fig, ax = plt.subplots()
    try:
        visualizations.add_map(ax, scenario)
        kinds = [f.WhichOneof("feature_data") for f in scenario.map_features]
        assert len(ax.lines) == kinds.count("road_edge") + kinds.count("road_line") > 0
        assert {line.get_linestyle() for line in ax.lines} == {"--"}
        assert {line.get_alpha() for line in ax.lines} <= {1.0, 0.5}
        edge = next(f.road_edge for f in scenario.map_features if f.HasField("road_edge"))
        np.testing.assert_array_equal(
            ax.lines[[k for k in kinds if k in ("road_edge", "road_line")].index("road_edge")].get_xdata(),
            [p.x for p in edge.polyline],
        )
    finally:
        plt.close(fig)


def test_bbox_patch_is_the_box():
    patch = visualizations.get_bbox_patch(10.0, -3.0, 0.6, 4.5, 2.0, color_idx=2)
    corners = patch.get_corners()
    np.testing.assert_allclose(corners.mean(axis=0), [10.0, -3.0], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(corners[1] - corners[0]), 4.5)
    np.testing.assert_allclose(np.linalg.norm(corners[2] - corners[1]), 2.0)
    assert patch.get_angle() == pytest.approx(np.rad2deg(0.6))
    np.testing.assert_allclose(patch.get_facecolor(), [*visualizations.WAYMO_COLORS[2], 0.5])
    assert visualizations.WAYMO_COLORS.shape == (6, 3)


def test_animated_states_is_a_func_animation_over_the_map(tmp_path):
    import matplotlib.pyplot as plt
    from matplotlib import animation

    scenario = _scene("occlusion.tfrecord")
    t = trajectory_utils.ObjectTrajectories.from_scenario(scenario).slice_time(10, 13)
    fig, ax = plt.subplots(1, 1, figsize=(4, 4))
    colours = np.tile(np.arange(t.x.shape[0])[:, None] % 6, (1, 3))
    anim = visualizations.get_animated_states(
        fig, ax, scenario, t.x, t.y, t.heading, t.length, t.width, color_idx=colours
    )
    assert isinstance(anim, animation.FuncAnimation)
    assert not plt.fignum_exists(fig.number)  # closed, as officially
    assert len(ax.lines) > 0  # the map
    anim.save(tmp_path / "states.gif", writer=animation.PillowWriter(fps=10))
    assert (tmp_path / "states.gif").stat().st_size > 0
    assert len(ax.patches) == t.x.shape[0]  # one box per object at the last frame, earlier ones removed
    last = ax.patches[0]
    np.testing.assert_allclose(last.get_corners().mean(axis=0), [t.x[0, -1], t.y[0, -1]], atol=1e-3)


# -- the official signatures -------------------------------------------------------------------------

# Every public function of the official modules (1.6.7): its parameters in order, and the defaults it has.
_REQUIRED = inspect.Parameter.empty
OFFICIAL_SIGNATURES = {
    trajectory_utils: {
        "ObjectTrajectories.slice_time": [("start_index", 0), ("end_index", None)],
        "ObjectTrajectories.gather_objects": [("object_indices", _REQUIRED)],
        "ObjectTrajectories.gather_objects_by_id": [("object_ids", _REQUIRED)],
        "ObjectTrajectories.from_scenario": [("scenario", _REQUIRED)],
    },
    converters: {
        "scenario_to_joint_scene": [("scenario", _REQUIRED), ("challenge_type", "sim_agents")],
        "joint_scene_to_trajectories": [
            ("joint_scene", _REQUIRED),
            ("scenario", _REQUIRED),
            ("use_log_validity", False),
        ],
        "simulated_scenariogen_to_trajectories": [
            ("joint_scene", _REQUIRED),
            ("scenario", _REQUIRED),
            ("challenge_type", _REQUIRED),
        ],
    },
    submission_specs: {
        "get_submission_config": [("challenge_type", _REQUIRED)],
        "get_sim_agent_ids": [("scenario", _REQUIRED), ("challenge_type", _REQUIRED)],
        "get_evaluation_sim_agent_ids": [("scenario", _REQUIRED), ("challenge_type", _REQUIRED)],
        "validate_joint_scene": [
            ("joint_scene", _REQUIRED),
            ("original_scenario", _REQUIRED),
            ("challenge_type", _REQUIRED),
        ],
        "validate_scenario_rollouts": [
            ("scenario_rollouts", _REQUIRED),
            ("original_scenario", _REQUIRED),
            ("challenge_type", "sim_agents"),
        ],
        "SubmissionConfig.is_valid_sim_agent": [("track", _REQUIRED)],
    },
    metrics: {
        "load_metrics_config": [("challenge_type", _REQUIRED)],
        "compute_scenario_metrics_for_bundle": [
            ("config", _REQUIRED),
            ("scenario", _REQUIRED),
            ("scenario_rollouts", _REQUIRED),
            ("challenge_type", "sim_agents"),
        ],
        "compute_scenario_metrics_for_features_bundle": [
            ("config", _REQUIRED),
            ("scenario_id", _REQUIRED),
            ("log_features", _REQUIRED),
            ("sim_features", _REQUIRED),
        ],
        "aggregate_scenario_metrics": [("all_scenario_metrics", _REQUIRED)],
        "aggregate_metrics_to_buckets": [("config", _REQUIRED), ("metrics", _REQUIRED)],
    },
    metric_features: {
        "compute_metric_features": [
            ("scenario", _REQUIRED),
            ("joint_scene", _REQUIRED),
            ("challenge_type", "sim_agents"),
            ("use_log_validity", False),
        ],
        "compute_scenario_rollouts_features": [
            ("scenario", _REQUIRED),
            ("scenario_rollouts", _REQUIRED),
            ("challenge_type", _REQUIRED),
        ],
    },
    visualizations: {
        "add_map": [("axis", _REQUIRED), ("scenario", _REQUIRED)],
        "add_road_edge": [("axis", _REQUIRED), ("road_edge", _REQUIRED)],
        "add_road_line": [("axis", _REQUIRED), ("road_line", _REQUIRED)],
        "get_bbox_patch": [
            ("x", _REQUIRED),
            ("y", _REQUIRED),
            ("bbox_yaw", _REQUIRED),
            ("length", _REQUIRED),
            ("width", _REQUIRED),
            ("color_idx", 0),
        ],
        "add_all_current_objects": [
            ("axis", _REQUIRED),
            ("x", _REQUIRED),
            ("y", _REQUIRED),
            ("yaw", _REQUIRED),
            ("length", _REQUIRED),
            ("width", _REQUIRED),
            ("color_idx", _REQUIRED),
        ],
        "get_animated_states": [
            ("fig", _REQUIRED),
            ("axis", _REQUIRED),
            ("scenario", _REQUIRED),
            ("x", _REQUIRED),
            ("y", _REQUIRED),
            ("yaw", _REQUIRED),
            ("length", _REQUIRED),
            ("width", _REQUIRED),
            ("color_idx", _REQUIRED),
        ],
    },
}
OFFICIAL_CLASSES = {
    trajectory_utils: ["ObjectTrajectories"],
    submission_specs: ["ChallengeType", "SubmissionConfig"],
    metric_features: ["MetricFeatures"],
    visualizations: [],
}


@pytest.mark.parametrize("module", list(OFFICIAL_SIGNATURES), ids=lambda m: m.__name__.rsplit(".", 1)[-1])
def test_every_official_function_is_there_with_its_parameters(module):
    for name, official in OFFICIAL_SIGNATURES[module].items():
        target = module
        for part in name.split("."):
            target = getattr(target, part)
        params = [p for p in inspect.signature(target).parameters.values() if p.name not in ("self", "cls")]
        assert [p.name for p in params[: len(official)]] == [n for n, _ in official], name
        for param, (_, default) in zip(params, official):
            if default is _REQUIRED:
                continue  # a default added here only widens what runs
            assert param.default is not _REQUIRED and param.default == default, (name, param.name)
        assert all(p.default is not _REQUIRED for p in params[len(official) :]), f"{name}: extra required parameter"
    for name in OFFICIAL_CLASSES.get(module, []):
        assert inspect.isclass(getattr(module, name)), name
    assert [f.name for f in dataclasses.fields(trajectory_utils.ObjectTrajectories)] == [
        "x",
        "y",
        "z",
        "heading",
        "length",
        "width",
        "height",
        "valid",
        "object_id",
        "object_type",
    ]
    assert [f.name for f in dataclasses.fields(submission_specs.SubmissionConfig)] == [
        "current_time_index",
        "n_simulation_steps",
        "n_rollouts",
        "step_duration_seconds",
    ]
    assert [c.value for c in submission_specs.ChallengeType] == ["sim_agents", "scenario_gen"]
    assert [c.name for c in submission_specs.ChallengeType] == ["SIM_AGENTS", "SCENARIO_GEN"]


def test_submission_specs_public_names_are_the_official_ones():
    official = {
        "ChallengeType",
        "SubmissionConfig",
        "get_submission_config",
        "get_sim_agent_ids",
        "get_evaluation_sim_agent_ids",
        "validate_joint_scene",
        "validate_scenario_rollouts",
    }
    assert official <= set(dir(submission_specs))
    assert submission_specs.get_submission_config(submission_specs.ChallengeType.SCENARIO_GEN).n_simulation_steps == 91


def test_arrays_answer_numpy_as_the_official_tensors_do():
    """Client code ends with `.numpy()` (e.g. a parity script converting every feature): it runs unchanged."""
    _, scenario, rollouts = _case("oracle", "synthetic-7-000-collision__logreplay_noise05")
    log, sim = metric_features.compute_scenario_rollouts_features(
        scenario, rollouts, submission_specs.ChallengeType.SIM_AGENTS
    )
    for features in (log, sim, metric_features.compute_metric_features(scenario, rollouts.joint_scenes[0])):
        for field in dataclasses.fields(metric_features.MetricFeatures):
            value = getattr(features, field.name)
            plain = value.numpy()
            assert type(plain) is np.ndarray and plain.dtype == value.dtype
            np.testing.assert_array_equal(plain, value)
    t = trajectory_utils.ObjectTrajectories.from_scenario(scenario)
    assert t.object_id.numpy().tolist() == [track.id for track in scenario.tracks]
    picked = t.gather_objects_by_id(t.object_id[:2]).slice_time(0, 11)
    for value in (picked.x, picked.valid, picked.object_id, t.gather_objects([0]).object_type):
        assert type(value.numpy()) is np.ndarray
    converted = converters.joint_scene_to_trajectories(rollouts.joint_scenes[0], scenario)
    assert all(
        type(getattr(converted, f.name).numpy()) is np.ndarray
        for f in dataclasses.fields(trajectory_utils.ObjectTrajectories)
    )
    plain = t.x.numpy()
    plain[0, 0] = -1.0  # a copy, as a tensor's
    assert t.x[0, 0] != -1.0
