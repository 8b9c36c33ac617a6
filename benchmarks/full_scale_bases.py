"""The pool of base scenes of benchmarks/full_scale.py, each serialised once around a placeholder id.

A copy of a base is its bytes with the 16 placeholder id bytes replaced by the copy's own id (the same
length, so no varint moves): the real WOMD scenes of ../shared with their golden rollouts, synthetic scenes
of `wosac_eval.sim` with `idm` rollouts, and for Scenario Generation the golden synthetic scenes of
../shared/golden/scenario_gen with their golden submissions.
"""

from __future__ import annotations

import dataclasses
import zlib

import google_crc32c

from bench_env import SHARED
from wosac_eval.arrays.messages import rollouts_bytes
from wosac_eval.parse.tfrecord import iter_records
from wosac_eval.parse.wire import varint  # the protobuf varint the readers use
from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2 as sub_pb2
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import policy_rollouts


@dataclasses.dataclass(frozen=True)
class Layout:
    scenes: int
    shards: int
    seed: int

    def copies(self, k: int) -> range:
        """The copies (scenario indices) of shard k: contiguous, balanced."""
        return range(k * self.scenes // self.shards, (k + 1) * self.scenes // self.shards)

    def scenario_shard(self, k: int) -> str:
        return f"validation.tfrecord-{k:05d}-of-{self.shards:05d}"

    def submission_shard(self, k: int) -> str:
        return f"submission.binproto-{k:05d}-of-{self.shards:05d}"


PLACEHOLDER = b"<full-scale-id!>"  # 16 bytes, as a WOMD scenario id: copies patch these in place

# The real scenes of ../shared/womd and the golden submission used as each one's rollouts.
REAL_BASES = (
    ("637f20cafde22ff8", "motion_data_one_scenario.tfrecord", "637f20cafde22ff8__official_test_submission"),
    ("ee519cf571686d19", "womd_scenario_input.tfrecord", "ee519cf571686d19__constvel_noise"),
)
CHALLENGES = ("sim_agents", "scenario_gen")
# Scenario Generation: the golden scenes of ../shared/golden/scenario_gen (scene file, golden case), and the
# baseline policy that makes each real scene's rollouts (no golden case: the official code ran out of memory).
SG_GOLDEN_BASES = (
    ("synthetic-11-000-intersection", "synthetic-11-000-intersection__sg_logreplay_noise05"),
    ("synthetic-11-000-intersection", "synthetic-11-000-intersection__sg_wild_boxes"),
    ("synthetic-11-003-offroad", "synthetic-11-003-offroad__sg_constvel_noise"),
)
SG_REAL_POLICIES = ("log_replay_noise", "constant_velocity")  # in the order of REAL_BASES
SG_CONFIG = "scenario_gen_2025"  # the golden JSON's config name of the challenge's current leaderboard


def scenario_id(i: int, seed: int) -> str:
    """The id of copy `i`: 16 hex digits, distinct for distinct i (an odd multiplier is a bijection mod 2**64)."""
    return f"{(i * 0x9E3779B97F4A7C15 + seed * 0x632BE59BD9B4E019) & 0xFFFFFFFFFFFFFFFF:016x}"


def _split_at_id(data: bytes, what: str) -> tuple[bytes, bytes]:
    if data.count(PLACEHOLDER) != 1:
        raise RuntimeError(f"{what}: the placeholder id is not found exactly once")
    head, _, tail = data.partition(PLACEHOLDER)
    return head, tail


def _deflate(data: bytes) -> bytes:
    """Raw deflate of `data` from a fresh compressor, sync-flushed: it ends byte-aligned without a final
    block, so it can sit anywhere in a deflate stream (it refers to nothing before it)."""
    compressor = zlib.compressobj(6, zlib.DEFLATED, -15)
    return compressor.compress(data) + compressor.flush(zlib.Z_SYNC_FLUSH)


@dataclasses.dataclass
class Base:
    """One base scene, serialised around its placeholder id."""

    name: str
    source: str  # "womd" or "synthetic"
    tracks: int
    sim_agents: int
    scenario_head: bytes
    scenario_tail: bytes
    rollouts_head: bytes  # the ScenarioRollouts bytes before the id (its field header)
    rollouts_tail: bytes  # ... and after it (the 32 joint scenes)
    deflated_tail: bytes = b""
    scenario_head_crc: int = 0
    tail_crc32: int = 0
    golden: str = ""  # scenario gen: the golden case (../shared/golden/scenario_gen/<golden>.json) of its rollouts

    def __post_init__(self) -> None:
        if len(self.rollouts_head) > 16:
            raise RuntimeError(f"{self.name}: the scenario id is not the first field of its ScenarioRollouts")
        self.deflated_tail = _deflate(self.rollouts_tail)
        self.scenario_head_crc = google_crc32c.value(self.scenario_head)

    @property
    def scenario_bytes(self) -> int:
        return len(self.scenario_head) + 16 + len(self.scenario_tail)

    @property
    def rollouts_bytes(self) -> int:
        return len(self.rollouts_head) + 16 + len(self.rollouts_tail)

    @property
    def record_bytes(self) -> int:
        """A copy's TFRecord record: header, data, CRC."""
        return 12 + self.scenario_bytes + 4

    @property
    def field_header(self) -> bytes:
        """The `scenario_rollouts` (field 1) header of a copy's rollouts in its shard."""
        return b"\x0a" + varint(self.rollouts_bytes)

    @property
    def shard_bytes(self) -> int:
        """A copy's bytes in its (decompressed) shard."""
        return len(self.field_header) + self.rollouts_bytes

    @property
    def gz_bytes(self) -> int:
        """A copy's bytes in the submission's gzip stream (a stored block, then the deflated tail)."""
        return 5 + len(self.field_header) + len(self.rollouts_head) + 16 + len(self.deflated_tail)

    def summary(self) -> dict:
        out = {
            "name": self.name,
            "source": self.source,
            "tracks": self.tracks,
            "sim_agents": self.sim_agents,
            "scenario_bytes": self.scenario_bytes,
            "rollouts_bytes": self.rollouts_bytes,
            "rollouts_gz_bytes": self.gz_bytes,
        }
        if self.golden:
            out["golden"] = self.golden
        return out


def _sim_agents(scenario) -> int:
    t = scenario.current_time_index
    return sum(1 for track in scenario.tracks if len(track.states) > t and track.states[t].valid)


def _base(name: str, source: str, scenario, rollouts, golden: str = "") -> Base:
    scenario.scenario_id = PLACEHOLDER.decode()
    rollouts.scenario_id = PLACEHOLDER.decode()
    s_head, s_tail = _split_at_id(scenario.SerializeToString(), f"{name} scenario")
    r_head, r_tail = _split_at_id(rollouts.SerializeToString(), f"{name} rollouts")
    return Base(
        name, source, len(scenario.tracks), _sim_agents(scenario), s_head, s_tail, r_head, r_tail, golden=golden
    )


def base_pool(synthetic: int, seed: int, challenge: str = "sim_agents") -> list[Base]:
    """The real scenes with their golden rollouts, then `synthetic` generated scenes with idm rollouts,
    interleaved so that each shard mixes them."""
    if challenge == "scenario_gen":
        return scenario_gen_pool(synthetic, seed)
    real = []
    for sid, tfrecord, golden in REAL_BASES:
        record = next(iter(iter_records(SHARED / "womd" / tfrecord)))
        scenario = scenario_pb2.Scenario.FromString(record.data)
        shard = sub_pb2.SimAgentsChallengeSubmission.FromString((SHARED / "golden" / f"{golden}.binproto").read_bytes())
        rollouts = next(r for r in shard.scenario_rollouts if r.scenario_id == sid)
        real.append(_base(f"{sid} ({golden.split('__')[1]})", "womd", scenario, rollouts))
    synth = []
    if synthetic:
        for i in range(synthetic):
            scenario = scenes.generate_scene(seed, i)
            name = scenario.scenario_id
            scenario.scenario_id = PLACEHOLDER.decode()
            data = rollouts_bytes(policy_rollouts(scenario, "idm", seed))
            synth.append(_base(f"{name} (idm)", "synthetic", scenario, sub_pb2.ScenarioRollouts.FromString(data)))
    # real, synthetic..., real, synthetic... : the real scenes spread over the cycle
    pool, half = [], (len(synth) + 1) // 2
    pool += real[:1] + synth[:half] + real[1:] + synth[half:]
    return pool


def scenario_gen_pool(synthetic: int, seed: int) -> list[Base]:
    """Scenario Generation bases: the golden synthetic scenes of ../shared/golden/scenario_gen with their golden
    submissions, the real scenes with baseline rollouts (SG_REAL_POLICIES) and `synthetic` generated scenes with
    idm rollouts (91 steps, boxes and types: `policy_rollouts(challenge="scenario_gen")`), interleaved so that
    each shard mixes them."""

    def sg_rollouts(scenario, policy: str):
        rollouts = sub_pb2.ScenarioRollouts.FromString(
            rollouts_bytes(policy_rollouts(scenario, policy, seed, "scenario_gen"))
        )
        # The baselines leave the per-step validity out (the evaluator takes the log's, at step 10); the
        # challenge's submissions carry it, as the golden ones do: every generated step valid.
        for scene in rollouts.joint_scenes:
            for trajectory in scene.simulated_trajectories:
                if not trajectory.valid:
                    trajectory.valid.extend([True] * len(trajectory.center_x))
        return rollouts

    folder = SHARED / "golden" / "scenario_gen"
    golden = []
    for scene, case in SG_GOLDEN_BASES:
        record = next(iter(iter_records(folder / "scenes" / f"{scene}.tfrecord")))
        scenario = scenario_pb2.Scenario.FromString(record.data)
        shard = sub_pb2.SimAgentsChallengeSubmission.FromString((folder / f"{case}.binproto").read_bytes())
        rollouts = next(r for r in shard.scenario_rollouts if r.scenario_id == scenario.scenario_id)
        golden.append(_base(f"{scene} ({case.split('__')[1]})", "golden", scenario, rollouts, golden=case))
    real = []
    for (sid, tfrecord, _), policy in zip(REAL_BASES, SG_REAL_POLICIES):
        record = next(iter(iter_records(SHARED / "womd" / tfrecord)))
        scenario = scenario_pb2.Scenario.FromString(record.data)
        real.append(_base(f"{sid} ({policy})", "womd", scenario, sg_rollouts(scenario, policy)))
    synth = []
    if synthetic:
        for i in range(synthetic):
            scenario = scenes.generate_scene(seed, i)
            name = scenario.scenario_id
            synth.append(_base(f"{name} (idm)", "synthetic", scenario, sg_rollouts(scenario, "idm")))
    # golden, real, synthetic, golden, real, synthetic, ...: each kind spread over the cycle
    pool, kinds = [], [golden, real, synth]
    cuts = [[round(len(k) * j / 3) for j in range(4)] for k in kinds]
    for j in range(3):
        for kind, cut in zip(kinds, cuts):
            pool += kind[cut[j] : cut[j + 1]]
    return pool
