"""Synthetic WOMD-like scenes and baseline sim agents: the demo (`fronts.demo_pipeline`) needs no dataset.

- `scenes`: deterministic scene generator (`generate_scenes(n, seed)` -> `Scenario` protos,
  `write_scenario_shards`), built from `roads` (lanes, lines, edges, crosswalks, stop bars),
  `signals` (fixed-time programs) and `engine` (closed-loop IDM traffic).
- `policies`: constant velocity, noisy log replay and IDM lane following for any scenario.
- `baselines`: a policy's rollouts of every scenario, written as an official-layout submission
  (`parse.submission_writer`).
"""
