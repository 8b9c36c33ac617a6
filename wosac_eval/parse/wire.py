"""Reading the packed coordinates of `SimulatedTrajectory` messages straight from the wire.

Protobuf serialises a parsed message canonically (known fields in field-number
order, each packed field as one block), so a trajectory whose `center_x`,
`center_y`, `center_z` and `heading` (fields 2 to 5) hold `num_steps` values
each serialises to bytes that start with four blocks "tag, length, values".
Stacking those prefixes gives every trajectory's coordinates as one float32
array without a Python loop over values; trajectories laid out otherwise are
reported as irregular, for a field-by-field fallback.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

COORDINATE_FIELDS = ("center_x", "center_y", "center_z", "heading")


def varint(value: int) -> bytes:
    """Protobuf base-128 varint of a non-negative integer."""
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def packed_headers(num_steps: int) -> np.ndarray:
    """Wire headers (tag, byte length) of fields 2..5 with `num_steps` floats each, uint8 `(4, header)`."""
    length = varint(4 * num_steps)
    return np.array([[(number << 3) | 2, *length] for number in (2, 3, 4, 5)], dtype=np.uint8)


def packed_coordinates(trajectories: Sequence, num_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Coordinates of the regularly laid out trajectories.

    Args:
      trajectories: `SimulatedTrajectory` messages.
      num_steps: the expected number of values per field.
    Returns:
      (regular, values): bool `(num_trajectories,)`, True where the four fields
      hold exactly `num_steps` values in canonical layout; float32
      `(num_regular, 4, num_steps)` for those, fields in `COORDINATE_FIELDS` order.
    """
    n = len(trajectories)
    headers = packed_headers(num_steps)
    block = headers.shape[1] + 4 * num_steps
    prefix = 4 * block
    heads = [t.SerializeToString()[:prefix] for t in trajectories]
    long_enough = np.fromiter(map(len, heads), dtype=np.int64, count=n) == prefix
    if not long_enough.all():
        heads = [h.ljust(prefix, b"\0") for h in heads]
    stacked = np.frombuffer(b"".join(heads), dtype=np.uint8).reshape(n, 4, block)
    regular = long_enough & (stacked[:, :, : headers.shape[1]] == headers).all(axis=(1, 2))
    values = np.ascontiguousarray(stacked[regular, :, headers.shape[1]:]).view("<f4").astype(np.float32)
    return regular, values
