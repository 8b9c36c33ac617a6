"""The official module layout, so code written for waymo-open-dataset runs by changing its imports.

    waymo_open_dataset.protos.{scenario,sim_agents_submission,sim_agents_metrics}_pb2
        -> wosac_eval.protos.{scenario,sim_agents_submission,sim_agents_metrics}_pb2
    waymo_open_dataset.utils.sim_agents.submission_specs
        -> wosac_eval.compat.submission_specs
    waymo_open_dataset.utils.sim_agents.converters
        -> wosac_eval.compat.converters
    waymo_open_dataset.utils.sim_agents.visualizations
        -> wosac_eval.compat.visualizations
    waymo_open_dataset.utils.trajectory_utils
        -> wosac_eval.compat.trajectory_utils
    waymo_open_dataset.wdl_limited.sim_agents_metrics.metric_features
        -> wosac_eval.compat.metric_features
    waymo_open_dataset.wdl_limited.sim_agents_metrics.metrics
        -> wosac_eval.compat.metrics

Same names, arguments and return types (protobuf messages; numpy arrays of
the official shapes and dtypes where the official code returns TensorFlow
tensors), the same numbers (the features and metrics are wosac-eval's,
bit-identical per step to the official ones), without TensorFlow. Each
function is a thin shim over the library's own pipeline; new code can call
`wosac_eval.score_scenario` and friends directly.
"""
