"""The official sim-agents modules of waymo-open-dataset 1.6.7, without TensorFlow (docs/official-api.md).

    waymo_open_dataset.protos.{scenario,map,sim_agents_submission,sim_agents_metrics}_pb2
        -> wosac_eval.protos.*
    waymo_open_dataset.utils.sim_agents.{submission_specs,converters,visualizations,test_utils}
        -> wosac_eval.compat.{submission_specs,converters,visualizations,test_utils}
    waymo_open_dataset.utils.trajectory_utils
        -> wosac_eval.compat.trajectory_utils
    waymo_open_dataset.wdl_limited.sim_agents_metrics.{metrics,metric_features,trajectory_features,
        interaction_features,map_metric_features,traffic_light_features,estimators}
        -> wosac_eval.compat.{...}

Same names, arguments, defaults, constants and messages; numpy arrays of the official shapes and dtypes
where the official code returns TensorFlow tensors; the same numbers (each function is a thin call of the
library's own pipeline or kernel, bit-identical per step to the official features). The official configs lie
under this package's folder at the official relative paths (`wdl_limited/sim_agents_metrics/...`).

Programs keep their `waymo_open_dataset` imports after one line, `import wosac_eval.compat.official_names`
(`official_finder`: what is served, worker processes, the rule when the official package is installed too).
"""
