"""Writing the workload of benchmarks/full_scale.py: the scenario set as TFRecord shards and the submission
as one .tar.gz, from the pool of base scenes (`full_scale_bases`), without holding more than the pool.

The TFRecord CRC32C of a copy is one pass of the hardware CRC over its id and the base's tail; the
submission's gzip stream is stitched from each base's rollouts deflated once (raw deflate, sync-flushed,
so that pieces concatenate) and stored blocks for what changes per copy (the `scenario_rollouts` field
header and id, tar headers, shard metadata), with the gzip CRC32 computed over the raw bytes. The build
is kept in WORKDIR/build and reused while its parameters (its manifest's key) are the same.
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import struct
import sys
import tarfile
import time
import zlib
from pathlib import Path

import google_crc32c

from bench_env import VALIDATION_SET
from full_scale_bases import Base, Layout, base_pool, scenario_id
from full_scale_watch import GiB, MiB, disk_free, folder_bytes
from wosac_eval.arrays.submission_writer import SubmissionMetadata
from wosac_eval.protos import sim_agents_submission_pb2 as sub_pb2
from wosac_eval.sim import scenes

OFFICIAL_SHARDS = 150  # validation.tfrecord-0000k-of-00150
PER_SHARD = math.ceil(VALIDATION_SET / OFFICIAL_SHARDS)  # 294 scenarios per official shard
LAYOUT_VERSION = 1  # bump when the bytes a build writes change
METHOD = "full-scale-benchmark"


def _mask(crc: int) -> int:
    """A CRC32C rotated and offset as the TFRecord format stores it."""
    return (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF


SG_DESCRIPTION = (
    "Validation-size Scenario Generation workload of benchmarks/full_scale.py: copies of the golden "
    "synthetic scenes with their golden submissions, of real WOMD scenes and of synthetic scenes with "
    "baseline rollouts (91 steps, box sizes and object types)."
)


def metadata_bytes(challenge: str = "sim_agents") -> bytes:
    """The submission's metadata fields (every one the challenge requires, and the recommended link)."""
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
