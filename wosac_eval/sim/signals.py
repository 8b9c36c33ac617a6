"""Fixed-time traffic-signal programs for synthetic scenes.

States are the integer values of `TrafficSignalLaneState.State`.
"""

from __future__ import annotations

import numpy as np

UNKNOWN, ARROW_STOP, ARROW_CAUTION, ARROW_GO, STOP, CAUTION, GO = 0, 1, 2, 3, 4, 5, 6
STOP_STATES = (ARROW_STOP, STOP)
CAUTION_STATES = (ARROW_CAUTION, CAUTION)

YELLOW_S = 3.0
ALL_RED_S = 1.0


def two_phase_program(
    times: np.ndarray, green_a_s: float, green_b_s: float, offset_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """States over time of two conflicting phases (A then B), each green-yellow-red.

    Args:
      times: `(num_steps,)` seconds.
      offset_s: where in the cycle time 0 falls.
    Returns:
      Two `(num_steps,)` int arrays: the states of phase A and of phase B.
    """
    cycle = green_a_s + green_b_s + 2 * (YELLOW_S + ALL_RED_S)
    tc = (np.asarray(times) + offset_s) % cycle
    a_yellow = green_a_s
    b_green = green_a_s + YELLOW_S + ALL_RED_S
    b_yellow = b_green + green_b_s
    b_red = b_yellow + YELLOW_S
    state_a = np.select([tc < a_yellow, tc < a_yellow + YELLOW_S], [GO, CAUTION], STOP)
    state_b = np.select([tc < b_green, tc < b_yellow, tc < b_red], [STOP, GO, CAUTION], STOP)
    return state_a.astype(np.int64), state_b.astype(np.int64)


def intersection_program(times: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """E-W and N-S phases of a four-way intersection, with a random cycle offset."""
    green_ew, green_ns = rng.uniform(8.0, 14.0), rng.uniform(8.0, 14.0)
    offset = rng.uniform(0.0, green_ew + green_ns + 2 * (YELLOW_S + ALL_RED_S))
    ew, ns = two_phase_program(times, green_ew, green_ns, offset)
    return {"EW": ew, "NS": ns}


def midblock_program(times: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A pedestrian crossing: vehicles ("PED") get green, yellow, then red while people walk ("WALK")."""
    green, walk = rng.uniform(6.0, 12.0), rng.uniform(6.0, 9.0)
    offset = rng.uniform(0.0, green + walk + 2 * (YELLOW_S + ALL_RED_S))
    vehicles, pedestrians = two_phase_program(times, green, walk, offset)
    return {"PED": vehicles, "WALK": pedestrians}


def is_stop(states: np.ndarray) -> np.ndarray:
    return np.isin(states, STOP_STATES)


def is_caution(states: np.ndarray) -> np.ndarray:
    return np.isin(states, CAUTION_STATES)
