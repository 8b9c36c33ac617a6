"""Where a simulator fails: wosac-eval's diagnostics, beside the official metrics (which they do not change).

- `criticality_features`: per-step features of the logged scene alone (kinematics, interaction, map).
- `criticality_scores`: a scenario's criticality in [0, 1] from them, and its rarity within a set.
- `scenario_set_criticality`: a scenario set rated and ranked without a submission (`score --select`).
- `driving_scores`: the SDC's driving, nuPlan-style, from the metric features.
- `by_object_type`: the realism metrics per object type.
"""
