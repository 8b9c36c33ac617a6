"""How far a submission may expand when it is read: bytes, members, messages.

Every place that expands input (a decompressing stream, a tar listing, a
protobuf parse) is bounded by one `InputLimits`, so a small hostile file (a
16 kB archive of millions of empty messages, 1 KB of bzip2 holding 1 GiB of
zeros) is refused with a message naming the limit, before memory is spent.

Messages are counted on the wire (`check_message_counts`) before a shard is
parsed: a parsed message costs ~60-100 bytes of memory whatever its wire size,
so an empty one (2 bytes on the wire) would multiply the shard's size 30-50
times. A genuine trajectory carries 80 or 91 steps of 4 floats (>= 1.3 kB), so
allowing one message per `message_bytes` bytes (past a fixed allowance) never
refuses a real submission and bounds the parse at a fraction of the shard.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator

from wosac_eval.parse import wire_walks
from wosac_eval.parse.errors import SizeLimitError

GiB = 1 << 30


@dataclasses.dataclass(frozen=True)
class InputLimits:
    """Bounds on reading one submission.

    Attributes:
      max_member_bytes: one shard, decompressed.
      max_total_bytes: the whole archive, decompressed (headers and skipped members included).
      max_members: entries of a tar archive (files, folders, documentation).
      max_compression_ratio: a compressed file may decompress to at most this many times its size...
      ratio_floor_bytes: ...once past this many bytes (small files may compress as well as they like).
      max_scenarios: `scenario_rollouts` entries of the whole submission.
      max_joint_scenes: `joint_scenes` of one `ScenarioRollouts` (the challenge needs 32).
      max_objects: `simulated_trajectories` of one `JointScene`.
      message_bytes, message_allowance: a shard may hold `message_allowance` messages plus one
        per `message_bytes` bytes.
    """

    max_member_bytes: int = 4 * GiB
    max_total_bytes: int = 256 * GiB  # a 64 GiB upload of float trajectories compresses 1.1-3x
    max_members: int = 100_000
    max_compression_ratio: float = 1000.0
    ratio_floor_bytes: int = 1 * GiB
    max_scenarios: int = 100_000
    max_joint_scenes: int = 128
    max_objects: int = 4096
    message_bytes: int = 512
    message_allowance: int = 10_000

    def total_bytes_for(self, compressed_size: int | None) -> tuple[int, str]:
        """The decompressed-size budget of a file, and the limit's name for messages.

        compressed_size: the file's size when it is compressed, None when it is not.
        """
        if compressed_size is None:
            return self.max_total_bytes, "max_total_bytes"
        by_ratio = max(self.ratio_floor_bytes, int(self.max_compression_ratio * compressed_size))
        if by_ratio < self.max_total_bytes:
            return by_ratio, (
                f"max_compression_ratio: {self.max_compression_ratio:g} times the "
                f"{compressed_size} compressed bytes, at least ratio_floor_bytes"
            )
        return self.max_total_bytes, "max_total_bytes"


# Field numbers on the wire (sim_agents_submission.proto); the levels below are `wire_walks.rollouts_census`'s.
_SUBMISSION_ROLLOUTS = 1  # SimAgentsChallengeSubmission.scenario_rollouts


class _Census:
    """Counts the fields of the walked levels of one shard, refusing past the limits."""

    def __init__(self, shard: str, size: int, limits: InputLimits) -> None:
        self.shard, self.limits = shard, limits
        self.budget = limits.message_allowance + size // limits.message_bytes
        self.messages = 0

    def count(self, span: int, where: str) -> None:
        """One more message, in a level of `span` bytes: SizeLimitError past the budget."""
        self.messages += 1
        if self.messages > self.budget:
            raise self.over_budget(span, where)

    def over_budget(self, span: int, where: str) -> SizeLimitError:
        return SizeLimitError(
            f"shard {self.shard}: more than {self.budget} messages in {span} bytes at {where} "
            f"(one per {self.limits.message_bytes} bytes plus {self.limits.message_allowance}: a real "
            "trajectory carries its steps); refused before parsing"
        )

    def fields(self, data: bytes, start: int, end: int, where: str) -> Iterator[tuple[int, int, int]]:
        """(field number, value start, value end) of each length-delimited field in data[start:end]; every
        field counts as one message. Malformed bytes end the walk (the parser reports them)."""
        pos = start
        while pos < end:
            key, shift = 0, 0
            while True:  # tag varint, inlined: once per trajectory (2x faster than wire.read_varint/skip_field)
                byte = data[pos]
                key |= (byte & 0x7F) << shift
                pos += 1
                if not byte & 0x80 or pos >= end or shift > 56:
                    break
                shift += 7
            self.count(end - start, where)
            wire_type = key & 7
            if wire_type == 2:
                length, shift = 0, 0
                while pos < end:
                    byte = data[pos]
                    length |= (byte & 0x7F) << shift
                    pos += 1
                    if not byte & 0x80 or shift > 56:
                        break
                    shift += 7
                if pos + length > end:
                    return
                yield key >> 3, pos, pos + length
                pos += length
            elif wire_type == 0:
                while pos < end and data[pos] & 0x80:
                    pos += 1
                pos += 1
            elif wire_type == 1:
                pos += 8
            elif wire_type == 5:
                pos += 4
            else:
                return


def check_message_counts(shard: str, data: bytes, limits: InputLimits | None = None) -> None:
    """Refuse a serialized `SimAgentsChallengeSubmission` holding more messages than the limits allow.

    Walks three levels of the wire format (scenario_rollouts, their joint_scenes, their trajectories)
    without parsing: about a microsecond per trajectory. Raises SizeLimitError naming the shard and the
    entry at fault. `limits`: default `InputLimits()`.
    """
    limits = InputLimits() if limits is None else limits
    census = _Census(shard, len(data), limits)
    scenarios = 0
    for number, start, end in census.fields(data, 0, len(data), "the top level"):
        if number == _SUBMISSION_ROLLOUTS:
            scenarios += 1
            _count_rollouts(census, data, start, end, scenarios - 1)


class ShardCensus:
    """`check_message_counts` of a shard read one top-level field at a time (`parse.shard_stream`): the
    same counts in the same order, so the same SizeLimitError at the same place, for a shard whose top
    level is well-formed.

    Args:
      shard: its name; size: its size in bytes (the budget); limits: default `InputLimits()`.
    """

    def __init__(self, shard: str, size: int, limits: InputLimits | None = None) -> None:
        self._census = _Census(shard, size, InputLimits() if limits is None else limits)
        self._size = size
        self.scenarios = 0

    def top_level_field(self, number: int, wire_type: int, data: bytes, start: int, end: int) -> None:
        """Count one top-level field and, for a scenario_rollouts, what it holds (its value: data[start:end])."""
        self._census.count(self._size, "the top level")
        if number == _SUBMISSION_ROLLOUTS and wire_type == 2:
            self.scenarios += 1
            _count_rollouts(self._census, data, start, end, self.scenarios - 1)


def _count_rollouts(census: _Census, data: bytes, start: int, end: int, index: int) -> None:
    """Count the messages of the shard's `index`th scenario_rollouts, data[start:end], and its joint scenes'
    (`wire_walks.rollouts_census`, a compiled walk: a Python walk cost 0.35 ms per real scene)."""
    shard, limits = census.shard, census.limits
    if index + 1 > limits.max_scenarios:
        raise SizeLimitError(
            f"shard {shard}: more than max_scenarios={limits.max_scenarios} scenario_rollouts; refused before parsing"
        )
    census.messages, outcome, joint_scene, span = wire_walks.rollouts_census(
        data, start, end, census.messages, census.budget, limits.max_joint_scenes, limits.max_objects
    )
    where = f"scenario_rollouts[{index}]"
    scene_where = f"{where}.joint_scenes[{joint_scene}]"
    if outcome == wire_walks.CENSUS_MESSAGES:
        raise census.over_budget(span, where if joint_scene < 0 else scene_where)
    if outcome == wire_walks.CENSUS_JOINT_SCENES:
        raise SizeLimitError(
            f"shard {shard}: {where} holds more than max_joint_scenes="
            f"{limits.max_joint_scenes} joint_scenes (the challenge asks for 32); refused before parsing"
        )
    if outcome == wire_walks.CENSUS_OBJECTS:
        raise SizeLimitError(
            f"shard {shard}: {scene_where} holds more than max_objects="
            f"{limits.max_objects} simulated_trajectories; refused before parsing"
        )


__all__ = ["InputLimits", "ShardCensus", "check_message_counts"]
