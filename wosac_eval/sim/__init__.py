"""Synthetic WOMD-like scenes and baseline sim agents: the demo (`fronts.demo_pipeline`) needs no dataset.

- `scenes`: deterministic scene generator (`generate_scenes(n, seed)` -> `Scenario` protos,
  `write_scenario_shards`), built in steps: `scene_recipes` (one recipe per kind of scene) populates
  `roads` (lanes, lines, edges, crosswalks, stop bars) under `signals` (fixed-time programs) with
  `scene_specs`, and `logged_scenes` simulates them with `engine` (closed-loop IDM traffic).
- `policies`: constant velocity, noisy log replay and IDM lane following for any scenario.
- `baselines`: a policy's rollouts of every scenario, written as an official-layout submission
  (`arrays.submission_writer`).
"""
