"""Full scale: a validation-size workload in the official layout, and every path measured on it.

The workload (cached in --workdir, rebuilt only when its parameters change):

- a scenario set of N scenarios (default 44,097, the WOMD validation set) as TFRecord shards
  `validation.tfrecord-0000k-of-0000S` (S: 150 at full size, the official count; about 294 scenarios
  per shard at any size);
- the matching submission in the official layout: one `submission.tar.gz` holding the shards
  `submission.binproto-0000k-of-0000S`, shard k covering the scenarios of scenario shard k, each a
  `SimAgentsChallengeSubmission` with every metadata field the challenge asks for.

The N scenarios are copies of a pool of base scenes, taken in turn: the two real WOMD scenes of
../shared (with their golden 32-rollout submissions) and `--synthetic` scenes of `wosac_eval.sim`
(one per recipe, with `idm` rollouts), every copy under its own 16-hex-digit scenario id. Each base
is serialised once with a placeholder id; a copy is its bytes with the 16 id bytes replaced (the
same length, so no varint moves). The TFRecord CRC32C of a copy is one pass of the hardware CRC;
the submission's gzip stream is stitched from each base's rollouts deflated once (raw deflate,
sync-flushed, so that pieces concatenate) and stored blocks for what changes per copy (the
`scenario_rollouts` field header and id, tar headers, shard metadata), with the gzip CRC32 computed
over the raw bytes. Memory stays at the pool's size whatever N is; the build is bound by disk speed.

Then each path runs as its own subprocess, sampled every 0.2 s for the peak RSS (VmHWM) of every
process of its tree and the disk use of the folders it writes:

- validate:  `wosac-eval validate --json --workers K`
- cli:       `wosac-eval score --workers K -o result.json` (default analysis), the first run against the
             scenario set: every path but cli-again starts with an empty criticality cache
             (`WORKDIR/runs/criticality.sqlite3`, `analysis.criticality_cache`)
- cli-again: the same command again, the scenes' criticality kept by the cli path read from the cache
             (what scoring the next checkpoint against the same set costs); with the core in the same
             run, its CPU per scene over the core too
- core:      the scoring core the cli path is measured against: one copy of each base scene scored on
             one core (`score_scenario` of its protobuf bytes, parsing included, as `score_speed.py`
             measures one scene: median of --core-repeat runs after a warm-up), weighted by the base's
             copies; with the cli path in the same run, the cli path's CPU per scene over it
- cli-objects: the same with `--per-object`: every evaluated object's values streamed through the run's
             journal into the side file `result.objects.jsonl`; its size, its objects, and its wall and
             CPU time against the cli path's of the same run (the goal: at most 10 % more, in bounded memory)
- service:   `wosac-server serve` (API + 1 worker, K scoring processes per job) on 127.0.0.1 with a
             temporary data dir; the submission uploaded with `wosac_eval.client.submit` (a resumable
             httpx upload of 64 MiB chunks when that client is not installed), scored and published
- ray:       `score_submission(engine="ray")` on a `ray.cluster_utils.Cluster` (a head without
             CPUs and K+1 nodes of one CPU), one node killed without warning at --ray-kill-at of the
             scenarios; inside a loopback-only network (and PID) namespace (`unshare`, as root)
- interrupt: the cli command killed (SIGKILL, its whole process group) once its journal
             (`result.json.journal`) holds --interrupt-at of the scenarios, then run again: the
             extra cost of the interruption

and every scoring path's result document is compared with the first one got on this workload, in
this run or an earlier one (`WORKDIR/runs/reference.json`; --new-reference forgets it): per-scenario
rows, buckets, aggregate and the rest, timing fields aside. Copies of one base scene must score
alike, and the real scenes' copies are checked against the official implementation's golden
meta-metric. A folder's disk use is its allocated blocks.

`--challenge scenario_gen` does the same for the Scenario Generation challenge (in its own default workdir,
`full-scale-scenario_gen`): each submission holds 32 rollouts of all 91 steps of every object valid at step
10, with per-step box sizes, validity and object type, and every path runs with `--challenge scenario_gen`
(the service's upload and leaderboard, Ray's `score_submission(challenge=...)` alike). Its base pool: the
synthetic scenes of ../shared/golden/scenario_gen/scenes with their golden submissions (each copy checked
against the official implementation's `scenario_gen_2025` meta-metric), the two real WOMD scenes with
baseline rollouts (`log_replay_noise`, `constant_velocity`; there is no golden for them: the official code
ran out of memory) and `--synthetic` scenes of `wosac_eval.sim` with `idm` rollouts, the rollouts made by
`wosac_eval.sim.baselines.policy_rollouts(..., challenge="scenario_gen")` (with the per-step `valid` the
baselines leave out added, all true, as in the golden submissions).

Usage:
  python benchmarks/full_scale.py [--scenes 44097] [--paths validate,cli,service,ray,interrupt]
      [--workdir DIR] [--workers K] [--synthetic 10] [--shards S] [--json summary.json]
  python benchmarks/full_scale.py --scenes 2000 --paths none      # build (or reuse) only
  python benchmarks/full_scale.py --challenge scenario_gen --scenes 4000 --paths validate,cli,service

Never fills the disk: the build, and each path that writes a copy of the submission (the service),
first check that at least --disk-margin-gb (default 20) stay free after it, and stop or skip saying so.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
import zlib
from collections.abc import Callable
from pathlib import Path

from bench_env import REPO, SHARED, VALIDATION_SET
from wosac_eval.parse.wire import varint  # the protobuf varint the readers use
from wosac_eval.runtime.cache_dirs import user_cache_dir

OFFICIAL_SHARDS = 150  # validation.tfrecord-0000k-of-00150
PER_SHARD = math.ceil(VALIDATION_SET / OFFICIAL_SHARDS)  # 294 scenarios per official shard
PLACEHOLDER = b"<full-scale-id!>"  # 16 bytes, as a WOMD scenario id: copies patch these in place
LAYOUT_VERSION = 1  # bump when the bytes a build writes change
ALL_PATHS = ("validate", "cli", "cli-again", "core", "cli-objects", "service", "ray", "interrupt")
CRITICALITY_CACHE = "criticality.sqlite3"  # in WORKDIR/runs: emptied before every path but cli-again
METHOD = "full-scale-benchmark"
MiB = 1 << 20
GiB = 1 << 30

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


def _mask(crc: int) -> int:
    """A CRC32C rotated and offset as the TFRecord format stores it."""
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


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


# ---------------------------------------------------------------------------------------------------
# The pool of base scenes


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
        import google_crc32c

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
    from wosac_eval.parse.tfrecord import iter_records
    from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2 as sub_pb2

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
        from wosac_eval.arrays.messages import rollouts_bytes
        from wosac_eval.sim import scenes
        from wosac_eval.sim.baselines import policy_rollouts

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
    from wosac_eval.arrays.messages import rollouts_bytes
    from wosac_eval.parse.tfrecord import iter_records
    from wosac_eval.protos import scenario_pb2, sim_agents_submission_pb2 as sub_pb2
    from wosac_eval.sim.baselines import policy_rollouts

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
        from wosac_eval.sim import scenes

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


# ---------------------------------------------------------------------------------------------------
# Writing the workload


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


SG_DESCRIPTION = (
    "Validation-size Scenario Generation workload of benchmarks/full_scale.py: copies of the golden "
    "synthetic scenes with their golden submissions, of real WOMD scenes and of synthetic scenes with "
    "baseline rollouts (91 steps, box sizes and object types)."
)


def metadata_bytes(challenge: str = "sim_agents") -> bytes:
    """The submission's metadata fields (every one the challenge requires, and the recommended link)."""
    from wosac_eval.arrays.submission_writer import SubmissionMetadata
    from wosac_eval.protos import sim_agents_submission_pb2 as sub_pb2

    message = sub_pb2.SimAgentsChallengeSubmission()
    SubmissionMetadata(
        unique_method_name=METHOD,
        account_name="full-scale@example.com",
        authors=["wosac-eval benchmark", "A. Nother"],
        affiliation="wosac-eval",
        description=SG_DESCRIPTION
        if challenge == "scenario_gen"
        else "Validation-size workload of benchmarks/full_scale.py: copies of real WOMD scenes with their "
        "golden rollouts and of synthetic scenes with idm rollouts.",
        method_link="https://github.com/waymo-research/waymo-open-dataset",
        num_model_parameters="1.5M",
    ).fill(message)
    return message.SerializeToString()


def predicted_sizes(pool: list[Base], layout: Layout, challenge: str = "sim_agents") -> dict:
    """Bytes the build writes (exact for the scenario set, within a few kB for the archive)."""
    counts = [0] * len(pool)
    for i in range(len(pool)):
        counts[i] = len(range(i, layout.scenes, len(pool)))
    meta = len(metadata_bytes(challenge))
    scen = sum(c * b.record_bytes for c, b in zip(counts, pool))
    raw = sum(c * b.shard_bytes for c, b in zip(counts, pool)) + layout.shards * (meta + 1024)
    gz = sum(c * b.gz_bytes for c, b in zip(counts, pool)) + layout.shards * (600 + meta + 1100) + 20
    return {"scenario_bytes": scen, "submission_bytes": gz, "submission_raw_bytes": raw}


def write_scenarios(pool: list[Base], layout: Layout, folder: Path) -> int:
    """The scenario set as TFRecord shards; returns the bytes written."""
    import google_crc32c

    folder.mkdir(parents=True, exist_ok=True)
    total = 0
    for k in range(layout.shards):
        with open(folder / layout.scenario_shard(k), "wb", buffering=16 * MiB) as f:
            for i in layout.copies(k):
                base, sid = pool[i % len(pool)], scenario_id(i, layout.seed).encode()
                length = struct.pack("<Q", base.scenario_bytes)
                crc = google_crc32c.extend(google_crc32c.extend(base.scenario_head_crc, sid), base.scenario_tail)
                f.write(length + struct.pack("<I", _mask(google_crc32c.value(length))))
                f.write(base.scenario_head)
                f.write(sid)
                f.write(base.scenario_tail)
                f.write(struct.pack("<I", _mask(crc)))
                total += base.record_bytes
    return total


class GzipStitcher:
    """A gzip file written from deflate pieces: stored blocks of raw bytes, and deflated pieces (from
    `_deflate`) with their raw bytes for the CRC. The stream ends with an empty final block."""

    def __init__(self, f):
        self.f, self.crc, self.size = f, 0, 0
        f.write(b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\xff")  # no name, mtime 0, unknown OS

    def stored(self, data: bytes) -> None:
        for i in range(0, len(data), 0xFFFF):
            chunk = data[i : i + 0xFFFF]
            self.f.write(b"\x00" + struct.pack("<HH", len(chunk), len(chunk) ^ 0xFFFF) + chunk)
        self.crc, self.size = zlib.crc32(data, self.crc), self.size + len(data)

    def deflated(self, packed: bytes, raw: bytes) -> None:
        self.f.write(packed)
        self.crc, self.size = zlib.crc32(raw, self.crc), self.size + len(raw)

    def close(self) -> None:
        self.f.write(b"\x01\x00\x00\xff\xff" + struct.pack("<II", self.crc, self.size & 0xFFFFFFFF))


def write_submission(pool: list[Base], layout: Layout, path: Path, challenge: str = "sim_agents") -> tuple[int, int]:
    """The submission .tar.gz; returns (bytes written, bytes of the tar inside)."""
    meta = metadata_bytes(challenge)
    with open(path, "wb", buffering=16 * MiB) as f:
        gz = GzipStitcher(f)
        for k in range(layout.shards):
            copies = layout.copies(k)
            size = sum(pool[i % len(pool)].shard_bytes for i in copies) + len(meta)
            info = tarfile.TarInfo(layout.submission_shard(k))
            info.size, info.mode, info.mtime = size, 0o644, 0
            gz.stored(info.tobuf(format=tarfile.USTAR_FORMAT))
            for i in copies:
                base = pool[i % len(pool)]
                gz.stored(base.field_header + base.rollouts_head + scenario_id(i, layout.seed).encode())
                gz.deflated(base.deflated_tail, base.rollouts_tail)
            gz.stored(meta + b"\0" * (-size % 512))
        end = b"\0" * 1024
        gz.stored(end + b"\0" * (-(gz.size + len(end)) % tarfile.RECORDSIZE))  # as tar pads its last record
        tar_bytes = gz.size
        gz.close()
    return path.stat().st_size, tar_bytes


def _build_key(args) -> dict:
    from wosac_eval.sim import scenes

    key = {
        "layout_version": LAYOUT_VERSION,
        "generator_version": scenes.GENERATOR_VERSION,
        "scenes": args.scenes,
        "shards": args.shards,
        "synthetic": args.synthetic,
        "seed": args.seed,
    }
    if args.challenge != "sim_agents":  # a Sim Agents key (and so its cached builds) stays as it was
        key["challenge"] = args.challenge
    return key


def disk_free(path: Path) -> int:
    path.mkdir(parents=True, exist_ok=True)
    return shutil.disk_usage(path).free


def folder_bytes(path: Path) -> int:
    """Allocated bytes of a file or of everything under a folder (0 when gone)."""
    total = 0
    try:
        if path.is_file():
            return path.stat().st_blocks * 512
        for root, _, files in os.walk(path):
            for name in files:
                try:
                    total += os.lstat(os.path.join(root, name)).st_blocks * 512
                except OSError:
                    pass
    except OSError:
        pass
    return total


def build(args) -> dict:
    """The workload in `args.workdir/build`, reused when its manifest matches; returns the manifest."""
    out = args.workdir / "build"
    manifest_path = out / "manifest.json"
    key = _build_key(args)
    if manifest_path.exists():
        manifest = json.loads(manifest_path.read_text())
        files_ok = (out / "submission.tar.gz").is_file() and (out / "submission.tar.gz").stat().st_size == manifest[
            "submission_bytes"
        ]
        if manifest.get("key") == key and files_ok:
            manifest["reused"] = True
            return manifest
    old = folder_bytes(out)
    started = time.perf_counter()
    pool = base_pool(args.synthetic, args.seed, args.challenge)
    pool_s = time.perf_counter() - started
    layout = Layout(args.scenes, args.shards, args.seed)
    predicted = predicted_sizes(pool, layout, args.challenge)
    need = predicted["scenario_bytes"] + predicted["submission_bytes"]
    free = disk_free(args.workdir) + old
    if free - need < args.disk_margin_gb * GiB:
        sys.exit(
            f"not building: the workload needs {need / GiB:.1f} GiB and {free / GiB:.1f} GiB are free "
            f"(counting the {old / GiB:.1f} GiB of the previous build it replaces); at least "
            f"{args.disk_margin_gb} GiB must stay free (--disk-margin-gb). Try a smaller --scenes or --synthetic."
        )
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    t = time.perf_counter()
    scenario_bytes = write_scenarios(pool, layout, out / "scenarios")
    scenarios_s = time.perf_counter() - t
    t = time.perf_counter()
    submission_bytes, tar_bytes = write_submission(pool, layout, out / "submission.tar.gz", args.challenge)
    submission_s = time.perf_counter() - t
    manifest = {
        "key": key,
        "bases": [b.summary() for b in pool],
        "scenes": args.scenes,
        "shards": args.shards,
        "seed": args.seed,
        "scenario_bytes": scenario_bytes,
        "submission_bytes": submission_bytes,
        "submission_tar_bytes": tar_bytes,
        "submission_raw_bytes": predicted["submission_raw_bytes"],
        "pool_s": round(pool_s, 2),
        "scenarios_s": round(scenarios_s, 2),
        "submission_s": round(submission_s, 2),
        "reused": False,
    }
    manifest_path.write_text(json.dumps(manifest, indent=1))  # last: a build cut short is never reused
    return manifest


def print_build(manifest: dict, workdir: Path) -> None:
    n, bases = manifest["scenes"], manifest["bases"]
    how = (
        "reused from an earlier run"
        if manifest["reused"]
        else (
            f"built in {manifest['pool_s'] + manifest['scenarios_s'] + manifest['submission_s']:.1f} s: base pool "
            f"{manifest['pool_s']:.1f} s, scenario set {manifest['scenarios_s']:.1f} s, "
            f"submission {manifest['submission_s']:.1f} s"
        )
    )
    what = " of Scenario Generation" if manifest["key"].get("challenge") == "scenario_gen" else ""
    print(f"workload: {n} scenarios{what} in {manifest['shards']} shards ({workdir / 'build'}), {how}")
    print(
        f"  {'base scene (each a share of 1/%d of the copies)' % len(bases):58s} {'tracks':>6s} {'agents':>6s} "
        f"{'scenario kB':>11s} {'rollouts kB':>11s} {'in .tar.gz':>10s}"
    )
    for b in bases:
        print(
            f"  {b['name']:58s} {b['tracks']:6d} {b['sim_agents']:6d} {b['scenario_bytes'] / 1e3:11.0f} "
            f"{b['rollouts_bytes'] / 1e3:11.0f} {b['rollouts_gz_bytes'] / 1e3:10.0f}"
        )
    per = lambda key: manifest[key] / n / 1e3  # noqa: E731
    print(
        f"  scenario set: {manifest['scenario_bytes'] / GiB:.2f} GiB ({per('scenario_bytes'):.0f} kB per scenario); "
        f"submission.tar.gz: {manifest['submission_bytes'] / GiB:.2f} GiB ({per('submission_bytes'):.0f} kB per "
        f"scenario), {manifest['submission_tar_bytes'] / GiB:.2f} GiB decompressed "
        f"({manifest['submission_tar_bytes'] / manifest['submission_bytes']:.2f}x)"
    )
    scale = VALIDATION_SET / n
    if n != VALIDATION_SET:
        print(
            f"  at {VALIDATION_SET} scenarios: scenario set {manifest['scenario_bytes'] * scale / GiB:.1f} GiB + "
            f"submission {manifest['submission_bytes'] * scale / GiB:.1f} GiB "
            f"({manifest['submission_tar_bytes'] * scale / GiB:.1f} GiB decompressed); the service path "
            f"stores another copy of the submission"
        )


# ---------------------------------------------------------------------------------------------------
# Measuring a process tree


def _parents() -> dict[int, tuple[int, int]]:
    """{pid: (parent pid, start time)} of every process (from /proc/<pid>/stat): pid and start time
    name a process even where its pid is reused later."""
    out = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat", "rb") as f:
                    fields = f.read().rsplit(b")", 1)[1].split()
                out[int(entry)] = (int(fields[1]), int(fields[19]))
            except (OSError, IndexError, ValueError):
                pass
    return out


def _hwm_kib(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status", "rb") as f:
            for line in f:
                if line.startswith(b"VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().rstrip(b"\0").replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


class TreeWatch:
    """Samples, every `interval` s until stopped, the peak RSS (VmHWM) of every process descending
    from `root` (the root included) and the allocated bytes of `dirs`."""

    def __init__(self, root: int, dirs: dict[str, Path] | None = None, interval: float = 0.2):
        self.root, self.dirs, self.interval = root, dirs or {}, interval
        self.procs: dict[tuple[int, int], dict] = {}  # (pid, start time) -> {"cmd", "depth", "hwm_kib"}
        self.disk_peak = {name: 0 for name in self.dirs}
        self.alive: list[tuple[tuple[int, int], ...]] = []  # the tree's processes at each sample
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        parents = _parents()
        children: dict[int, list[int]] = {}
        for pid, (ppid, _) in parents.items():
            children.setdefault(ppid, []).append(pid)
        frontier, depth, seen = [self.root], 0, []
        while frontier:
            nxt = []
            for pid in frontier:
                if pid not in parents:
                    continue
                key = (pid, parents[pid][1])
                seen.append(key)
                hwm = _hwm_kib(pid)
                entry = self.procs.get(key)
                if entry is None:
                    entry = self.procs[key] = {"cmd": _cmdline(pid), "depth": depth, "hwm_kib": 0}
                entry["hwm_kib"] = max(entry["hwm_kib"], hwm)
                nxt += children.get(pid, [])
            frontier, depth = nxt, depth + 1
        self.alive.append(tuple(seen))
        for name, path in self.dirs.items():
            self.disk_peak[name] = max(self.disk_peak[name], folder_bytes(path))

    def _run(self) -> None:
        while not self._stop.is_set():
            self._sample()
            self._stop.wait(self.interval)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        for name, path in self.dirs.items():
            self.disk_peak[name] = max(self.disk_peak[name], folder_bytes(path))

    def listing(self, role: Callable[[dict], str | None], limit: int = 200) -> list[list]:
        """[role, peak MiB, command line (cut)] of each process seen, largest first."""
        rows = [[role(e), round(e["hwm_kib"] / 1024, 1), e["cmd"][:160]] for e in self.procs.values()]
        return sorted(rows, key=lambda r: -r[1])[:limit]

    def peaks(self, role: Callable[[dict], str | None]) -> dict[str, dict]:
        """{role: {"count", "at_once", "max_mib", "each_mib"}} of the processes `role` names (None: not
        shown); `at_once`: the most of them seen alive in one sample."""
        out: dict[str, dict] = {}
        roles = {key: role(entry) for key, entry in self.procs.items()}
        for key, entry in self.procs.items():
            name = roles[key]
            if name is None or not entry["hwm_kib"]:
                continue
            r = out.setdefault(name, {"count": 0, "at_once": 0, "max_mib": 0.0, "each_mib": []})
            r["count"] += 1
            r["each_mib"].append(round(entry["hwm_kib"] / 1024, 1))
            r["max_mib"] = max(r["max_mib"], entry["hwm_kib"] / 1024)
        for pids in self.alive:
            counts: dict[str, int] = {}
            for key in pids:
                if roles.get(key) in out:
                    counts[roles[key]] = counts.get(roles[key], 0) + 1
            for name, count in counts.items():
                out[name]["at_once"] = max(out[name]["at_once"], count)
        for r in out.values():
            r["max_mib"] = round(r["max_mib"], 1)
            r["each_mib"].sort(reverse=True)
        return out


def by_depth(*names: str) -> Callable[[dict], str | None]:
    """Role by depth in the tree: names[0] the root, names[1] its children, ...; deeper: the last name."""
    return lambda entry: names[min(entry["depth"], len(names) - 1)]


@dataclasses.dataclass
class Run:
    rc: int
    wall_s: float
    stdout: str
    stderr: str
    watch: TreeWatch
    cpu_s: float = 0.0  # CPU seconds of the process and the descendants it waited for


def run_watched(
    cmd: list[str],
    run_dir: Path,
    name: str,
    *,
    dirs: dict[str, Path] | None = None,
    env: dict | None = None,
    timeout: float | None = None,
    poll: Callable[[subprocess.Popen], None] | None = None,
) -> Run:
    """Runs `cmd` in its own session, watched; `poll(process)` is called every 0.05 s while it runs.
    Its CPU time is the rusage of the process and of every descendant it waited for (os.wait4)."""
    out, err = run_dir / f"{name}.stdout", run_dir / f"{name}.stderr"
    usage = None
    with open(out, "wb") as o, open(err, "wb") as e:
        started = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=o, stderr=e, env=env, cwd=REPO, start_new_session=True)
        watch = TreeWatch(proc.pid, dirs)
        try:
            while True:
                pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
                if pid:
                    proc.returncode = os.waitstatus_to_exitcode(status)
                    break
                if poll is not None:
                    poll(proc)
                if timeout is not None and time.perf_counter() - started > timeout:
                    os.killpg(proc.pid, signal.SIGKILL)
                time.sleep(0.05)
        except BaseException:
            if proc.returncode is None:
                os.killpg(proc.pid, signal.SIGKILL)
            raise
        finally:
            if proc.returncode is None:
                _, status, usage = os.wait4(proc.pid, 0)
                proc.returncode = os.waitstatus_to_exitcode(status)
            wall = time.perf_counter() - started
            watch.stop()
    cpu = usage.ru_utime + usage.ru_stime if usage is not None else 0.0
    return Run(proc.returncode, wall, out.read_text(errors="replace"), err.read_text(errors="replace"), watch, cpu)


# ---------------------------------------------------------------------------------------------------
# Comparing result documents

_TIMING = re.compile(r"(^|_)(elapsed|seconds|wall|timing|timings|duration|started|finished)(_|$)|(_s|_at)$")


def _strip_timing(value):
    if isinstance(value, dict):
        return {k: _strip_timing(v) for k, v in value.items() if not _TIMING.search(k)}
    if isinstance(value, list):
        return [_strip_timing(v) for v in value]
    return value


def _sha(value) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, allow_nan=True).encode()).hexdigest()[:16]


def digest_result(path: Path, layout: Layout, pool_size: int) -> dict:
    """Digests of a result document's parts (timing fields aside), and whether the copies of each base
    scene scored alike."""
    doc = _strip_timing(json.loads(path.read_text()))
    rows = doc.get("scenarios", [])
    index = {scenario_id(i, layout.seed): i for i in range(layout.scenes)}
    per_base: dict[int, set] = {}
    first_of_base: dict[int, dict] = {}
    for row in rows:
        i = index.get(row.get("scenario_id"))
        if i is None:
            continue
        body = {k: v for k, v in row.items() if k != "scenario_id"}
        per_base.setdefault(i % pool_size, set()).add(_sha(body))
        first_of_base.setdefault(i % pool_size, row)
    # "per_object" names a side file (score --per-object): not a score, so the paths compare without it
    rest = {k: v for k, v in doc.items() if k not in ("scenarios", "buckets", "aggregate", "per_object")}
    return {
        "rows": _sha(rows),
        "buckets": _sha(doc.get("buckets")),
        "aggregate": _sha(doc.get("aggregate")),
        "rest": _sha(rest),
        "num_scenarios": len(rows),
        "metametric": (doc.get("aggregate") or {}).get("metametric"),
        "copies_alike": all(len(s) == 1 for s in per_base.values()) and len(per_base) == pool_size,
        "base_metametric": {b: first_of_base[b].get("metametric") for b in sorted(first_of_base)},
    }


def same_as(reference: dict | None, digest: dict | None) -> str:
    if reference is None or digest is None:
        return "-"
    parts = [p for p in ("rows", "buckets", "aggregate", "rest") if reference[p] != digest[p]]
    return "yes" if not parts else "NO: " + ",".join(parts)


# ---------------------------------------------------------------------------------------------------
# The paths


def _env() -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("WOSAC_")}
    if CACHE_FILE is not None:  # the workload's own cache of scenes' criticality, never the user's
        env["WOSAC_CRITICALITY_CACHE"] = str(CACHE_FILE)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    env.setdefault("OMP_NUM_THREADS", "1")
    return env


CACHE_FILE: Path | None = None  # set by main: WORKDIR/runs/CRITICALITY_CACHE


def empty_criticality_cache() -> None:
    """A first run against the scenario set: no scene's criticality kept yet."""
    if CACHE_FILE is not None:
        for suffix in ("", "-wal", "-shm"):
            Path(f"{CACHE_FILE}{suffix}").unlink(missing_ok=True)


PYTHON = os.path.abspath(sys.executable)  # ".." collapsed, symbolic links kept (a venv's python is one)


def _cli(*args: str) -> list[str]:
    return [PYTHON, "-m", "wosac_eval.fronts.cli", *args]


def _paths(build_dir: Path) -> tuple[Path, Path]:
    return build_dir / "scenarios", build_dir / "submission.tar.gz"


def path_validate(ctx) -> dict:
    scenarios, submission = _paths(ctx.build)
    cmd = _cli(
        "validate",
        "--scenarios",
        str(scenarios),
        "--submission",
        str(submission),
        "--json",
        "--workers",
        str(ctx.workers),
        *ctx.challenge_args,
    )
    run = run_watched(cmd, ctx.runs, "validate", env=_env())
    row = ctx.row(
        "validate",
        f"wosac-eval validate --workers {ctx.workers}{ctx.challenge_flag}",
        run,
        run.watch.peaks(by_depth("main", "workers")),
        disk=0,
    )
    try:
        report = json.loads(run.stdout)
        stats = report["stats"]
        row["note"] = (
            f"{'valid' if report['valid'] else 'INVALID'}, {report['errors']} error(s), "
            f"{report['warnings']} warning(s), {stats['scenarios_valid']}/{stats['scenarios_expected']} "
            f"scenarios valid"
        )
        row["ok"] = report["valid"] and stats["scenarios_valid"] == ctx.layout.scenes
    except (ValueError, KeyError):
        row["note"], row["ok"] = f"exit {run.rc}: {run.stderr.strip()[-300:]}", False
    return row


def _score_command(ctx, scenarios: Path, submission: Path, out: Path, *extra: str) -> list[str]:
    """`wosac-eval score` of the workload with one worker per core into `out` (the cli, cli-objects and
    interrupt paths)."""
    return _cli(
        "score", "--scenarios", str(scenarios), "--submission", str(submission), "--workers", str(ctx.workers),
        *extra, "-o", str(out), *ctx.challenge_args,
    )  # fmt: skip


def path_cli(ctx, name: str = "cli") -> dict:
    scenarios, submission = _paths(ctx.build)
    out = ctx.runs / name / "result.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.unlink(missing_ok=True)
    cmd = _score_command(ctx, scenarios, submission, out)
    run = run_watched(cmd, ctx.runs, name, env=_env(), dirs={"out": out.parent})
    again = " (criticality kept by the cli path)" if name == "cli-again" else ""
    row = ctx.row(
        name,
        f"wosac-eval score --workers {ctx.workers}{ctx.challenge_flag} -o R.json{again}",
        run,
        run.watch.peaks(by_depth("main", "workers")),
        disk=run.watch.disk_peak["out"],
    )
    if name == "cli-again":
        ctx.cli_again_cpu = run.cpu_s if run.rc == 0 else None
    else:
        ctx.cli_wall = run.wall_s if run.rc == 0 else None
        ctx.cli_cpu = run.cpu_s if run.rc == 0 else None
    if out.exists():
        row["note"] = f"result document {out.stat().st_size / MiB:.1f} MiB"
    return ctx.with_result(row, out, run)


# One core, protobuf bytes in, metrics out: `stage_timing.score_bytes`, what benchmarks/score_speed.py times for
# one scene, here for each base scene of the workload (argv: benchmarks/, the folder of base-K.scenario /
# base-K.rollouts, repeats, challenge).
CORE_SCRIPT = """
import json, sys
from pathlib import Path
sys.path.insert(0, sys.argv[1])
from stage_timing import median_time, score_bytes
from wosac_eval import challenges
from wosac_eval.runtime.allocator import keep_freed_memory
from wosac_eval.scoring.scenario import resolve_config

keep_freed_memory()
folder, repeat, challenge = Path(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
config = resolve_config(None, challenges.as_challenge(challenge))
medians = []
for k in range(len(list(folder.glob("base-*.scenario")))):
    raw_scenario = (folder / f"base-{k}.scenario").read_bytes()
    raw_rollouts = (folder / f"base-{k}.rollouts").read_bytes()
    medians.append(median_time(lambda: score_bytes(raw_scenario, raw_rollouts, config, challenge), repeat)[0])
print(json.dumps(medians))
"""


def path_core(ctx) -> dict:
    """The scoring core on one core: each base scene's median seconds, weighted by its copies."""
    pool = base_pool(ctx.manifest["key"]["synthetic"], ctx.manifest["key"]["seed"], ctx.challenge)
    folder = ctx.runs / "core"
    folder.mkdir(parents=True, exist_ok=True)
    for k, base in enumerate(pool):  # each base under a copy's id (the placeholder's length)
        sid = scenario_id(k, ctx.layout.seed).encode()
        (folder / f"base-{k}.scenario").write_bytes(base.scenario_head + sid + base.scenario_tail)
        (folder / f"base-{k}.rollouts").write_bytes(base.rollouts_head + sid + base.rollouts_tail)
    env = {**_env(), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    cmd = [PYTHON, "-c", CORE_SCRIPT, str(Path(__file__).resolve().parent), str(folder), str(ctx.core_repeat),
           ctx.challenge]  # fmt: skip
    run = run_watched(cmd, ctx.runs, "core", env=env)
    row = ctx.row("core", f"score_scenario of each base scene, one core, median of {ctx.core_repeat}", run,
                  run.watch.peaks(by_depth("main")), disk=0)  # fmt: skip
    row["scenes_per_s"] = 0.0  # one core, not the run's wall: set below from the per-scene cost
    if run.rc != 0:
        row["ok"], row["note"] = False, f"exit {run.rc}: {run.stderr.strip()[-500:]}"
        return row
    medians = json.loads(run.stdout.strip().splitlines()[-1])
    copies = [len(range(k, ctx.layout.scenes, len(pool))) for k in range(len(pool))]  # copy i is base i % P
    per_scene = sum(m * c for m, c in zip(medians, copies)) / sum(copies)
    row["core_s_per_scene"] = per_scene
    row["scenes_per_s"] = round(1 / per_scene, 2)
    row["base_medians_s"] = medians
    row["note"] = (
        f"{per_scene * 1e3:.1f} ms per scene (bases {min(medians) * 1e3:.1f}-{max(medians) * 1e3:.1f} ms, "
        f"weighted by their copies)"
    )
    if ctx.cli_cpu is not None:
        cli = ctx.cli_cpu / ctx.layout.scenes
        row["cli_s_per_scene"] = cli
        row["cli_over_core"] = cli / per_scene
        row["note"] += f"; the cli path {cli * 1e3:.1f} ms per scene per core: {cli / per_scene:.2f}x the core"
    if ctx.cli_again_cpu is not None:
        again = ctx.cli_again_cpu / ctx.layout.scenes
        row["cli_again_s_per_scene"] = again
        row["cli_again_over_core"] = again / per_scene
        row["note"] += f"; again {again * 1e3:.1f} ms: {again / per_scene:.2f}x"
    return row


def path_cli_objects(ctx) -> dict:
    """The cli path with `--per-object`: what the side file costs (time, memory, disk) over the plain run."""
    scenarios, submission = _paths(ctx.build)
    out = ctx.runs / "cli-objects" / "result.json"
    objects = out.with_name("result.objects.jsonl")
    out.parent.mkdir(parents=True, exist_ok=True)
    for stale in (out, objects, out.with_name(out.name + ".journal")):
        stale.unlink(missing_ok=True)
    cmd = _score_command(ctx, scenarios, submission, out, "--per-object")
    run = run_watched(cmd, ctx.runs, "cli-objects", env=_env(), dirs={"out": out.parent})
    row = ctx.row(
        "cli-objects",
        f"wosac-eval score --workers {ctx.workers}{ctx.challenge_flag} --per-object -o R.json",
        run,
        run.watch.peaks(by_depth("main", "workers")),
        disk=run.watch.disk_peak["out"],
    )
    if out.exists() and objects.exists():
        size = objects.stat().st_size
        num_objects = json.loads(out.read_text()).get("per_object", {}).get("num_objects")
        row["objects_bytes"], row["num_objects"] = size, num_objects
        row["note"] = (
            f"result document {out.stat().st_size / MiB:.1f} MiB; side file {size / MiB:.1f} MiB "
            f"({num_objects} objects, {size / ctx.layout.scenes / 1024:.1f} KiB per scene)"
        )
        if ctx.cli_wall:
            row["vs_cli_wall"] = round(run.wall_s / ctx.cli_wall - 1, 4)
            row["vs_cli_cpu"] = round(run.cpu_s / ctx.cli_cpu - 1, 4) if ctx.cli_cpu else None
            row["note"] += f"; against the cli path: wall {100 * row['vs_cli_wall']:+.1f} %" + (
                f", CPU {100 * row['vs_cli_cpu']:+.1f} %" if row["vs_cli_cpu"] is not None else ""
            )
        else:
            row["note"] += "; run the cli path before it (--paths cli,cli-objects) for its cost relative to it"
        objects.unlink()  # large at full size: its size is what is reported
    elif run.rc == 0:
        row["ok"], row["note"] = False, "no side file written"
    return ctx.with_result(row, out, run)


def journal_available() -> str | None:
    """Why the interruption row cannot run, or None (the journal of `wosac-eval score -o`)."""
    help_text = subprocess.run(_cli("score", "--help"), capture_output=True, text=True, env=_env(), cwd=REPO).stdout
    if "journal" not in help_text:
        return (
            "`wosac-eval score -o R.json` keeps no journal in this checkout (R.json.journal), so a rerun cannot resume"
        )
    return None


def path_interrupt(ctx) -> dict:
    why = journal_available()
    if why:
        return ctx.skipped("interrupt", why)
    scenarios, submission = _paths(ctx.build)
    folder = ctx.runs / "interrupt"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    out = folder / "result.json"
    journal = folder / "result.json.journal"
    cmd = _score_command(ctx, scenarios, submission, out)
    target = max(1, min(ctx.layout.scenes - 1, math.ceil(ctx.interrupt_at * ctx.layout.scenes)))
    state = {"offset": 0, "rows": -1, "killed_at": None}  # rows: lines after the journal's header

    def poll(proc: subprocess.Popen) -> None:
        if state["killed_at"] is not None or not journal.exists():
            return
        with open(journal, "rb") as f:
            f.seek(state["offset"])
            data = f.read()
        complete = data.rfind(b"\n") + 1
        state["offset"] += complete
        state["rows"] += data.count(b"\n", 0, complete)
        if state["rows"] >= target:
            os.killpg(proc.pid, signal.SIGKILL)  # the command and its worker processes, at once
            state["killed_at"] = state["rows"]

    first = run_watched(cmd, ctx.runs, "interrupt-1", env=_env(), dirs={"out": folder}, poll=poll)
    if state["killed_at"] is None:
        return ctx.skipped(
            "interrupt",
            f"the run ended (exit {first.rc}) before its journal held {target} "
            f"scenarios; nothing to interrupt at this size",
        )
    second = run_watched(cmd, ctx.runs, "interrupt-2", env=_env(), dirs={"out": folder})
    peaks = {}
    for label, run in (("killed run", first), ("rerun", second)):
        for role, r in run.watch.peaks(by_depth("main", "workers")).items():
            peaks[f"{role} ({label})"] = r
    merged = Run(
        second.rc, first.wall_s + second.wall_s, second.stdout, second.stderr, second.watch, first.cpu_s + second.cpu_s
    )
    row = ctx.row(
        "interrupt",
        f"score -o R.json, SIGKILL at {state['killed_at']}/{ctx.layout.scenes}, rerun",
        merged,
        peaks,
        disk=max(first.watch.disk_peak["out"], second.watch.disk_peak["out"]),
    )
    resumed = "resum" in second.stderr.lower()  # the command says it resumes from the journal
    extra = (
        f"{first.wall_s + second.wall_s - ctx.cli_wall:+.1f} s against the uninterrupted cli run"
        if ctx.cli_wall
        else "no uninterrupted cli run to compare"
    )
    share = f", {100 * second.wall_s / ctx.cli_wall:.0f}% of the uninterrupted cli run" if ctx.cli_wall else ""
    row["note"] = (
        f"killed after {first.wall_s:.1f} s with {state['killed_at']} scenarios journaled; rerun "
        f"{second.wall_s:.1f} s{share} ({'resumed' if resumed else 'DID NOT RESUME'}, "
        f"{ctx.layout.scenes - state['killed_at']} left to score); extra cost {extra}"
    )
    row["interrupt"] = {
        "killed_after_s": round(first.wall_s, 2),
        "journaled": state["killed_at"],
        "rerun_s": round(second.wall_s, 2),
        "resumed": resumed,
        "rerun_share": round(second.wall_s / ctx.cli_wall, 4) if ctx.cli_wall else None,
        "extra_s": round(first.wall_s + second.wall_s - ctx.cli_wall, 2) if ctx.cli_wall else None,
    }
    return ctx.with_result(row, out, second)


_UPLOAD_CHILD = r"""
import json, sys, time
path, url, key, method, chunk, state_dir = sys.argv[1:5] + [int(sys.argv[5]), sys.argv[6]]
challenge = sys.argv[7] if len(sys.argv) > 7 else "sim_agents"
started = time.perf_counter()
try:
    from wosac_eval.client import submit
except ImportError:
    submit = None
if submit is not None:
    import inspect
    known = inspect.signature(submit).parameters  # the client's own defaults otherwise (chunk size...)
    extra = {k: v for k, v in {"state_dir": state_dir, "new": True}.items() if k in known}
    got = submit(path, server=url, key=key, method=method, challenge=challenge, publish=True, wait=False, **extra)
    sid = None
    for name in ("id", "submission_id"):
        sid = sid or (got.get(name) if isinstance(got, dict) else getattr(got, name, None))
    print(json.dumps({"client": "wosac_eval.client.submit", "id": sid, "upload_s": time.perf_counter() - started}))
    sys.exit(0)
import os, httpx
size = os.path.getsize(path)
headers = {"Authorization": f"Bearer {key}"}
with httpx.Client(base_url=url, headers=headers, timeout=httpx.Timeout(60.0, read=3600.0)) as http:
    made = http.post("/v1/uploads", params={"challenge": challenge, "method": method, "publish": "true"},
                     headers={"Upload-Length": str(size)})
    made.raise_for_status()
    up = made.json()["upload_id"]
    offset = 0
    with open(path, "rb") as f:
        while offset < size:
            data = f.read(chunk)
            answer = http.patch(f"/v1/uploads/{up}", content=data, headers={
                "Upload-Offset": str(offset), "Content-Type": "application/offset+octet-stream"})
            answer.raise_for_status()
            offset = int(answer.headers["Upload-Offset"])
    done = http.post(f"/v1/uploads/{up}/complete")
    done.raise_for_status()
print(json.dumps({"client": "httpx resumable upload (wosac_eval.client absent)", "id": done.json()["id"],
                  "upload_s": time.perf_counter() - started}))
"""


def path_service(ctx) -> dict:
    try:
        import httpx
        from support.server_harness import Server
    except ImportError as error:
        return ctx.skipped("service", f"the service is not installed ({error}): pip install ./server")
    scenarios, submission = _paths(ctx.build)
    upload = submission.stat().st_size
    free = disk_free(ctx.runs)
    if free - upload < ctx.disk_margin_gb * GiB:
        return ctx.skipped(
            "service",
            f"its data dir would hold another {upload / GiB:.1f} GiB copy of the "
            f"submission and only {free / GiB:.1f} GiB are free (--disk-margin-gb {ctx.disk_margin_gb})",
        )
    folder = ctx.runs / "service"
    shutil.rmtree(folder, ignore_errors=True)
    data_dir = folder / "data"
    raw = ctx.manifest["submission_tar_bytes"]
    server = Server(
        data_dir,
        [scenarios],
        workers=1,
        score_threads=ctx.workers,
        poll_s=0.5,
        max_upload_bytes=max(16 * GiB, 2 * upload),
        max_decompressed_bytes=max(64 * GiB, 2 * raw),
        max_scenarios=max(100_000, 2 * ctx.layout.scenes),
    )
    row = None
    t_start = time.perf_counter()
    server.start(timeout=120)
    watch = TreeWatch(server.proc.pid, {"data": data_dir})
    try:
        key = server.key("full-scale-bench")
        method = METHOD
        child_dir = folder / "upload"
        child_dir.mkdir()
        t0 = time.perf_counter()
        up = run_watched(
            [
                PYTHON,
                "-c",
                _UPLOAD_CHILD,
                str(submission),
                server.url,
                key,
                method,
                str(64 * MiB),
                str(child_dir / "client-state"),
                ctx.challenge,
            ],
            child_dir,
            "upload",
            env=_env(),
        )
        upload_wall = time.perf_counter() - t0
        if up.rc != 0:
            raise RuntimeError(f"upload failed (exit {up.rc}): {up.stderr[-2000:]}")
        sent = json.loads(up.stdout.strip().splitlines()[-1])
        with server.client(key, timeout=600) as http:
            sid = sent["id"] or http.get("/v1/submissions").json()["submissions"][0]["id"]
            status = server.wait_state(http, sid, timeout=ctx.service_timeout)
            scored_wall = time.perf_counter() - t0 - upload_wall
            deadline = time.monotonic() + 10  # the job's peak RSS and CPU are written just after its state
            while status.get("peak_rss_bytes") is None and time.monotonic() < deadline:
                time.sleep(0.2)
                status = http.get(f"/v1/submissions/{sid}").json()
            result_path = folder / "result.json"
            if status["state"] == "done":
                with http.stream("GET", f"/v1/submissions/{sid}/results") as answer, open(result_path, "wb") as f:
                    answer.raise_for_status()
                    for part in answer.iter_bytes(MiB):
                        f.write(part)
            board = httpx.get(server.url + "/v1/leaderboard", params={"challenge": ctx.challenge}, timeout=60).json()
        watch.stop()
        data_peak, data_end = watch.disk_peak["data"], folder_bytes(data_dir)
        data_parts = {p.name: folder_bytes(p) for p in sorted(data_dir.iterdir())}
        published = any(entry.get("submission_id") == sid for entry in board.get("entries", []))
        # CPU: the upload client's and the job's (the status's cpu_s: its process and scoring pool)
        run = Run(
            0 if status["state"] == "done" else 1,
            upload_wall + scored_wall,
            "",
            "",
            watch,
            up.cpu_s + (status.get("cpu_s") or 0.0),
        )
        roles = run.watch.peaks(by_depth("api", "worker", "job", "job pool"))
        roles["upload client"] = up.watch.peaks(by_depth("client"))["client"]
        row = ctx.row(
            "service",
            f"upload + score (1 worker, {ctx.workers} processes per job"
            f"{', challenge=' + ctx.challenge if ctx.challenge_args else ''})",
            run,
            roles,
            disk=data_peak,
        )
        row["note"] = (
            f"{sent['client']}: upload {upload_wall:.1f} s ({upload / MiB / upload_wall:.0f} MiB/s), "
            f"then {scored_wall:.1f} s to {status['state']}"
            + (f" ({status.get('error')})" if status["state"] != "done" else "")
            + f"; data dir peak {data_peak / GiB:.2f} GiB, {data_end / GiB:.2f} GiB after, for a "
            f"{upload / GiB:.2f} GiB upload ({data_peak / upload:.2f}x; at the end: "
            + ", ".join(f"{k} {v / MiB:.1f} MiB" for k, v in data_parts.items() if v >= MiB // 10)
            + "); "
            f"job peak_rss {(status.get('peak_rss_bytes') or 0) / MiB:.0f} MiB, "
            f"cpu {status.get('cpu_s') or 0:.0f} s; "
            f"{'published' if published else 'NOT on the leaderboard'}"
        )
        row["service"] = {
            "client": sent["client"],
            "upload_s": round(upload_wall, 2),
            "scoring_s": round(scored_wall, 2),
            "server_start_s": round(t0 - t_start, 2),
            "state": status["state"],
            "data_dir_peak_bytes": data_peak,
            "data_dir_end_bytes": data_end,
            "upload_bytes": upload,
            "job_peak_rss_bytes": status.get("peak_rss_bytes"),
            "job_cpu_s": status.get("cpu_s"),
            "published": published,
            "data_dir_end_parts": data_parts,
            "status": status,
        }
        if status["state"] == "done":
            row = ctx.with_result(row, result_path, run)
        else:
            row["ok"] = False
    finally:
        if not watch._stop.is_set():
            watch.stop()
        server.stop()
        if row is not None:
            row.setdefault("service", {})["log_tail"] = (
                server.log.read_text(errors="replace")[-2000:] if server.log.exists() else ""
            )
        shutil.rmtree(data_dir, ignore_errors=True)  # the upload's copy: never left behind
    return row


_RAY_CHILD = r"""
import json, os, sys, threading, time
scenarios, submission, out = sys.argv[1:4]
nodes_n, kill_at = int(sys.argv[4]), float(sys.argv[5])
challenge = sys.argv[6] if len(sys.argv) > 6 else "sim_agents"
started = time.perf_counter()
import ray
from ray.cluster_utils import Cluster
store = 256 * 1024 * 1024
c = Cluster(initialize_head=True, head_node_args={"num_cpus": 0, "object_store_memory": store})
nodes = [c.add_node(num_cpus=1, object_store_memory=store) for _ in range(nodes_n)]
c.wait_for_nodes()
ray.init(address=c.address, log_to_driver=False)
startup = time.perf_counter() - started
from wosac_eval.scoring.submission import score_submission
reached = threading.Event()
state = {}
def progress(done, total):
    if total and done >= kill_at * total and not reached.is_set():
        state["at"] = done
        reached.set()
def score():
    try:
        state["result"] = score_submission([scenarios], submission, engine="ray", ray_address=c.address,
                                           progress=progress, challenge=challenge)
    except BaseException as error:
        state["error"] = repr(error)
    reached.set()
t = time.perf_counter()
worker = threading.Thread(target=score)
worker.start()
reached.wait()
killed_at_s = None
if "result" not in state and "error" not in state:
    c.remove_node(nodes[-1], allow_graceful=False)
    killed_at_s = time.perf_counter() - t
worker.join()
seconds = time.perf_counter() - t
if "result" in state:
    with open(out, "w") as f:
        json.dump(state["result"], f)
print("FULL-SCALE-RAY " + json.dumps({"startup_s": startup, "scoring_s": seconds,
                                     "killed_at": state.get("at") if killed_at_s else None,
                                     "killed_at_s": killed_at_s, "error": state.get("error")}), flush=True)
ray.shutdown()
c.shutdown()
"""


def ray_unavailable() -> str | None:
    try:
        import ray  # noqa: F401
    except ImportError:
        return "Ray is not installed (pip install 'wosac-eval[ray]')"
    if os.geteuid() != 0:
        return "needs root, to run the cluster in a loopback-only network namespace (unshare -n)"
    if not (shutil.which("unshare") and shutil.which("ip")):
        return "needs unshare and ip (util-linux, iproute2) for a loopback-only network namespace"
    return None


def _ray_role(entry: dict) -> str | None:
    cmd = entry["cmd"]
    if cmd.startswith(("unshare", "bash")) or entry["depth"] < 2:
        return None  # the namespace's wrappers
    if "ray_child.py" in cmd:
        return "driver"
    if "raylet" in cmd.split(" ")[0]:
        return "raylets"
    if "gcs_server" in cmd:
        return "gcs"
    if cmd.startswith("ray::") or "default_worker.py" in cmd:
        return "ray workers"
    return "ray other"


def path_ray(ctx) -> dict:
    why = ray_unavailable()
    if why:
        return ctx.skipped("ray", why)
    scenarios, submission = _paths(ctx.build)
    folder = ctx.runs / "ray"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    script = folder / "ray_child.py"
    script.write_text(_RAY_CHILD)
    out = folder / "result.json"
    ray_tmp = Path(tempfile.mkdtemp(prefix="wrfs", dir="/tmp"))  # short: Ray's socket paths live under it
    nodes = ctx.workers + 1
    inner = (
        f"ip link set lo up && {PYTHON} {script} {scenarios} {submission} {out} {nodes} "
        f"{ctx.ray_kill_at}{' ' + ctx.challenge if ctx.challenge_args else ''}; exit $?"
    )
    env = {**_env(), "RAY_TMPDIR": str(ray_tmp), "RAY_DISABLE_USAGE_STATS": "1"}
    env.pop("RAY_ADDRESS", None)
    try:
        run = run_watched(
            ["unshare", "-n", "-p", "--kill-child", "--mount-proc", "bash", "-c", inner],
            ctx.runs,
            "ray",
            env=env,
            dirs={"ray": ray_tmp, "out": folder},
            timeout=ctx.ray_timeout,
        )
    finally:
        shutil.rmtree(ray_tmp, ignore_errors=True)
    disk = run.watch.disk_peak["ray"] + run.watch.disk_peak["out"]
    row = ctx.row(
        "ray",
        f"Cluster: head + {nodes} nodes x 1 CPU, one killed{ctx.challenge_flag}",
        run,
        run.watch.peaks(_ray_role),
        disk=disk,
    )
    row["processes"] = run.watch.listing(_ray_role)
    try:
        info = json.loads(
            next(line for line in run.stdout.splitlines() if line.startswith("FULL-SCALE-RAY ")).partition(" ")[2]
        )
    except (ValueError, StopIteration):
        row["note"], row["ok"] = f"exit {run.rc}: {run.stderr.strip()[-500:]}", False
        return row
    row["ray"] = info
    kill = (
        f"node killed at {info['killed_at']}/{ctx.layout.scenes} scenarios ({info['killed_at_s']:.1f} s in)"
        if info["killed_at"] is not None
        else "NO node was killed (scoring ended first)"
    )
    row["note"] = (
        f"cluster start {info['startup_s']:.1f} s, scoring {info['scoring_s']:.1f} s "
        f"({ctx.layout.scenes / info['scoring_s']:.1f} scenes/s); {kill}; Ray's temp dir peak "
        f"{run.watch.disk_peak['ray'] / MiB:.1f} MiB" + (f"; error: {info['error']}" if info.get("error") else "")
    )
    return ctx.with_result(row, out, run)


PATH_RUNNERS = {
    "validate": path_validate,
    "cli": path_cli,
    "cli-again": lambda ctx: path_cli(ctx, "cli-again"),
    "core": path_core,
    "cli-objects": path_cli_objects,
    "service": path_service,
    "ray": path_ray,
    "interrupt": path_interrupt,
}


class Context:
    def __init__(self, args, manifest: dict):
        self.build = args.workdir / "build"
        self.runs = args.workdir / "runs"
        self.runs.mkdir(parents=True, exist_ok=True)
        self.manifest = manifest
        self.challenge = args.challenge
        # the commands' flag: none for Sim Agents (each command's default), so its commands stay as they were
        self.challenge_args = [] if args.challenge == "sim_agents" else ["--challenge", args.challenge]
        self.challenge_flag = "".join(" " + a for a in self.challenge_args)
        self.layout = Layout(manifest["scenes"], manifest["shards"], manifest["seed"])
        self.pool_size = len(manifest["bases"])
        self.workers = args.workers
        self.disk_margin_gb = args.disk_margin_gb
        self.interrupt_at = args.interrupt_at
        self.core_repeat = args.core_repeat
        self.ray_kill_at = args.ray_kill_at
        self.ray_timeout = args.ray_timeout
        self.service_timeout = args.service_timeout
        self.cli_wall: float | None = None
        self.cli_cpu: float | None = None
        self.cli_again_cpu: float | None = None
        self.load_before = 0.0
        # The first result on this build is the reference of every later one, in this run or a later run
        # on the same cached build (so that paths measured one at a time are compared too).
        self.reference_file = self.runs / "reference.json"
        self.reference: dict | None = None
        self.reference_from = ""
        if self.reference_file.exists() and not args.new_reference:
            stored = json.loads(self.reference_file.read_text())
            if stored.get("build") == manifest["key"]:
                self.reference, self.reference_from = stored["digest"], stored["from"]

    def row(self, path: str, what: str, run: Run, peaks: dict, disk: int) -> dict:
        return {
            "path": path,
            "what": what,
            "rc": run.rc,
            "wall_s": round(run.wall_s, 2),
            "cpu_s": round(run.cpu_s, 1),
            "load_before": self.load_before,
            "load_after": os.getloadavg()[0],
            "scenes_per_s": round(self.layout.scenes / run.wall_s, 2) if run.wall_s else None,
            "peak_rss": peaks,
            "disk_bytes": disk,
            "same": "-",
            "ok": run.rc == 0,
            "note": "",
        }

    def skipped(self, path: str, why: str) -> dict:
        print(f"[{path}] skipped: {why}", flush=True)
        return {"path": path, "skipped": why}

    def with_result(self, row: dict, result: Path, run: Run) -> dict:
        if run.rc != 0 or not result.exists():
            row["ok"] = False
            if not row["note"]:
                row["note"] = f"exit {run.rc}: {run.stderr.strip()[-500:]}"
            return row
        digest = digest_result(result, self.layout, self.pool_size)
        row["digest"] = digest
        row["disk_bytes"] = max(row["disk_bytes"], result.stat().st_blocks * 512)
        if self.reference is None:
            self.reference = digest
            self.reference_from = f"the {row['path']} path's result of {time.strftime('%Y-%m-%d %H:%M')}"
            self.reference_file.write_text(
                json.dumps({"build": self.manifest["key"], "from": self.reference_from, "digest": digest})
            )
            row["same"] = "reference"
        else:
            row["same"] = same_as(self.reference, digest)
        row["ok"] = row["ok"] and digest["num_scenarios"] == self.layout.scenes and row["same"] in ("yes", "reference")
        if not digest["copies_alike"]:
            row["note"] += "; copies of one base scene scored differently"
        result.unlink()  # a full-size result is large: its digest is what the comparison needs
        return row


def _fmt_peaks(peaks: dict) -> str:
    parts = []
    for role, r in peaks.items():
        if r["count"] == 1:
            parts.append(f"{role} {r['max_mib']:.0f}")
        else:
            many = f"{r['count']}" if r["at_once"] == r["count"] else f"{r['at_once']} at a time ({r['count']} in all)"
            parts.append(f"{role} {many} <= {r['max_mib']:.0f}")
    return ", ".join(parts) + " MiB"


def golden_metametrics(manifest: dict) -> dict[int, float]:
    """{base index: the official implementation's 2025 meta-metric} of the real bases (../shared/golden); for
    Scenario Generation, its `scenario_gen_2025` meta-metric of the golden bases (../shared/golden/scenario_gen)."""
    out = {}
    if manifest["key"].get("challenge") == "scenario_gen":
        for b, base in enumerate(manifest["bases"]):
            path = SHARED / "golden" / "scenario_gen" / f"{base.get('golden')}.json"
            if base.get("golden") and path.exists():
                out[b] = json.loads(path.read_text())["metrics"][SG_CONFIG]["metametric"]
        return out
    for b, base in enumerate(manifest["bases"]):
        for sid, _, golden in REAL_BASES:
            if base["name"].startswith(sid):
                path = SHARED / "golden" / f"{golden}.json"
                if path.exists():
                    out[b] = json.loads(path.read_text())["metrics"]["2025"]["metametric"]
    return out


def print_table(rows: list[dict], manifest: dict) -> None:
    n = manifest["scenes"]
    print(
        f"\n{n} scenarios, {os.cpu_count()} cores; peak RSS from each process's VmHWM (sampled every 0.2 s); "
        f"CPU: user + system seconds of the path's processes (service: the upload client and the job); "
        f"disk: allocated bytes the path wrote (peak); load: the 1-minute load average before-after"
    )
    print(
        f"{'path':11s} {'wall s':>8s} {'scenes/s':>8s} {'CPU s':>7s} {'disk MiB':>9s} {'same result':>11s} "
        f"{'load':>9s}  peak RSS per process"
    )
    for r in rows:
        if "skipped" in r or "failed" in r:
            print(f"{r['path']:11s} {'skipped: ' + r['skipped'] if 'skipped' in r else 'FAILED: ' + r['failed'][:300]}")
            continue
        load = f"{r['load_before']:.1f}-{r['load_after']:.1f}"
        print(
            f"{r['path']:11s} {r['wall_s']:8.1f} {r['scenes_per_s']:8.1f} {r['cpu_s']:7.0f} "
            f"{r['disk_bytes'] / MiB:9.1f} {r['same']:>11s} {load:>9s}  {_fmt_peaks(r['peak_rss'])}"
        )
    print()
    for r in rows:
        if "skipped" not in r and "failed" not in r:
            print(f"{r['path']:11s} {r['what']}: {r['note'].lstrip('; ')}")
    digests = [r["digest"] for r in rows if "digest" in r]
    if digests:
        d = digests[0]
        print(
            f"\nresult: meta-metric {d['metametric']:.4f} over {d['num_scenarios']} scenarios; copies of each base "
            f"scene scored alike: {'yes' if all(x['copies_alike'] for x in digests) else 'NO'}; per base: "
            + ", ".join(f"{m:.4f}" for m in d["base_metametric"].values() if m is not None)
        )
        for b, official in golden_metametrics(manifest).items():
            ours = d["base_metametric"].get(b)
            if ours is not None:
                print(
                    f"  {manifest['bases'][b]['name']}: {ours:.6f}, the official implementation's (golden): "
                    f"{official:.6f} (diff {abs(ours - official):.1e})"
                )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument(
        "--challenge",
        choices=CHALLENGES,
        default="sim_agents",
        help="the submission's challenge, and every path's --challenge (default %(default)s)",
    )
    p.add_argument("--scenes", type=int, default=VALIDATION_SET, help="scenarios (default %(default)s)")
    p.add_argument(
        "--paths",
        default=",".join(ALL_PATHS),
        help=f"comma-separated, run in this order (default {','.join(ALL_PATHS)}); 'none': build only",
    )
    cache = user_cache_dir()
    p.add_argument(
        "--workdir",
        type=Path,
        default=None,
        help=f"where the workload is cached and the paths write (default {cache / 'full-scale'}; "
        f"with --challenge scenario_gen, {cache / 'full-scale-scenario_gen'})",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=os.cpu_count() or 1,
        help="processes per path: validate and score --workers, the service's processes per job, "
        "the Ray cluster's nodes (plus one, the node killed) (default: the cores, %(default)s)",
    )
    p.add_argument("--synthetic", type=int, default=10, help="synthetic base scenes, one per recipe (default 10)")
    p.add_argument(
        "--shards",
        type=int,
        default=None,
        help=f"shards of the scenario set and the submission (default: {PER_SHARD} scenarios per shard, "
        f"{OFFICIAL_SHARDS} at {VALIDATION_SET})",
    )
    p.add_argument("--seed", type=int, default=11, help="synthetic scenes and scenario ids")
    p.add_argument(
        "--interrupt-at",
        type=float,
        default=0.8,
        help="share of the scenarios journaled when the interrupt path kills the run (default 0.8)",
    )
    p.add_argument(
        "--ray-kill-at",
        type=float,
        default=0.5,
        help="share of the scenarios scored when the ray path kills a node (default 0.5)",
    )
    p.add_argument("--core-repeat", type=int, default=5, help="runs of each base scene in the core path (default 5)")
    p.add_argument("--ray-timeout", type=float, default=7200.0)
    p.add_argument("--service-timeout", type=float, default=7 * 3600.0)
    p.add_argument(
        "--disk-margin-gb",
        type=float,
        default=20.0,
        help="free space the build and the service path must leave (default 20)",
    )
    p.add_argument(
        "--new-reference",
        action="store_true",
        help="compare with this run's first result only, not with the first result an earlier run "
        "got on the same cached workload (kept in WORKDIR/runs/reference.json)",
    )
    p.add_argument("--json", type=Path, help="also write the build's sizes and every row here")
    args = p.parse_args(argv)
    if not ((SHARED / "womd").is_dir() and (SHARED / "golden").is_dir()):
        sys.exit(f"needs the reference data in {SHARED} (womd/ and golden/): the real base scenes")
    if args.challenge == "scenario_gen" and not (SHARED / "golden" / "scenario_gen" / "scenes").is_dir():
        sys.exit(
            f"needs the reference data in {SHARED / 'golden' / 'scenario_gen'} (its scenes/ and golden "
            f"submissions): the golden base scenes of --challenge scenario_gen"
        )
    if args.workdir is None:
        args.workdir = cache / ("full-scale" if args.challenge == "sim_agents" else f"full-scale-{args.challenge}")
    if args.scenes < 1 or args.workers < 1 or args.synthetic < 0:
        sys.exit("--scenes and --workers must be >= 1, --synthetic >= 0")
    paths = [] if args.paths == "none" else [s.strip() for s in args.paths.split(",") if s.strip()]
    unknown = sorted(set(paths) - set(ALL_PATHS))
    if unknown:
        sys.exit(f"unknown path(s) {', '.join(unknown)}; choose from {', '.join(ALL_PATHS)}")
    args.shards = args.shards or max(1, min(args.scenes, round(args.scenes / PER_SHARD)))
    args.workdir = args.workdir.resolve()

    manifest = build(args)
    print_build(manifest, args.workdir)
    ctx = Context(args, manifest)
    global CACHE_FILE
    CACHE_FILE = ctx.runs / CRITICALITY_CACHE
    rows = []
    for path in paths:
        print(f"[{path}] running...", flush=True)
        ctx.load_before = os.getloadavg()[0]
        if path != "cli-again":
            empty_criticality_cache()
        try:
            row = PATH_RUNNERS[path](ctx)
        except Exception as error:  # noqa: BLE001 - one path's failure is a row; the others still run
            row = {"path": path, "failed": f"{type(error).__name__}: {error}"[-2000:], "ok": False}
            print(f"[{path}] FAILED: {row['failed']}", flush=True)
            rows.append(row)
            continue
        if "skipped" not in row:
            print(
                f"[{path}] {row['wall_s']:.1f} s, {row['scenes_per_s']:.1f} scenes/s, same result: {row['same']}",
                flush=True,
            )
        rows.append(row)
    if rows:
        print_table(rows, manifest)
        if ctx.reference_from:
            print(f"(same result: compared with {ctx.reference_from})")
    if args.json:
        args.json.write_text(
            json.dumps(
                {"build": manifest, "workers": args.workers, "rows": rows, "reference": ctx.reference_from}, indent=1
            )
        )
    failed = [r["path"] for r in rows if "skipped" not in r and not r["ok"]]
    if failed:
        print(f"\nFAILED: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
