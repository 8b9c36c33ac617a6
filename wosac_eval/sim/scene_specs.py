"""What a synthetic scene is before simulation: its logged objects (`AgentSpec`) and the scene (`SceneSpec`).

Also the scene clock (`NUM_STEPS` steps of `DT` seconds, `TIMES`) and the spacing at which object paths are resampled.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wosac_eval.challenges import NUM_LOGGED_STEPS, STEP_SECONDS
from wosac_eval.sim import engine, roads

NUM_STEPS = NUM_LOGGED_STEPS  # 91
DT = STEP_SECONDS
TIMES = np.arange(NUM_STEPS) * DT

PATH_SPACING_M = 0.5


@dataclass
class AgentSpec:
    """One logged object before simulation. `path` is in the local frame of the network."""

    object_type: int
    length: float
    width: float
    height: float
    path: np.ndarray
    s_init: float
    v_init: float
    v0: np.ndarray  # (NUM_STEPS,) desired speed
    a_max: float = 1.5
    b_comf: float = 2.5
    headway: float = 1.3
    s0: float = 2.0
    margin: float = 0.3
    max_brake: float = engine.MAX_BRAKE
    moving: bool = True
    ignore_signals: bool = False
    stops: list[tuple[float, int]] = field(default_factory=list)  # (arc length, signal column)
    tags: set[str] = field(default_factory=set)


@dataclass
class SceneSpec:
    """Everything a scene recipe decides; `assemble` turns it into a Scenario proto."""

    scenario_id: str
    kind: str
    network: roads.RoadNetwork
    signal_states: dict[str, np.ndarray]  # group -> (NUM_STEPS,) states
    agents: list[AgentSpec]
    rotation: float
    translation: np.ndarray
    ground_z: float
    slope: np.ndarray
    blind_pairs: list[tuple[AgentSpec, AgentSpec]] = field(default_factory=list)  # (follower, leader)
    occlusion_level: float = 0.1
