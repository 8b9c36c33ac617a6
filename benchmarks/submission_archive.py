"""Writing a submission archive: `SubmissionWriter` (ISA-L's deflate, level 3) against the same members
gzipped by zlib at level 9 (Python's `gzip`/`tarfile` default, what the writer used before), side by side.

The rollouts are the IDM baseline's on `--scenes` synthetic scenes (32 rollouts each), serialized once;
each timed write starts from the same bytes. Prints seconds (median of `--repeat`), MB/s of uncompressed
tar, archive sizes, and checks that both archives hold the same members byte for byte.

Usage: python benchmarks/submission_archive.py [--scenes 10] [--repeat 3]
"""

from __future__ import annotations

import argparse
import gzip
import io
import statistics
import tarfile
import tempfile
import time
from pathlib import Path

from wosac_eval.arrays.messages import rollouts_bytes
from wosac_eval.arrays.submission_writer import ARCHIVE_LEVEL, SubmissionMetadata, SubmissionWriter
from wosac_eval.sim import scenes
from wosac_eval.sim.baselines import policy_rollouts


def members(path: Path) -> dict[str, bytes]:
    with tarfile.open(path, "r:gz") as tar:
        return {m.name: tar.extractfile(m).read() for m in tar.getmembers()}


def zlib9_copy(source: Path, target: Path) -> float:
    """Seconds to gzip the same tar at zlib's level 9 (mtime 0, as the writer)."""
    raw = io.BytesIO()
    with tarfile.open(fileobj=raw, mode="w") as tar:
        for name, data in members(source).items():
            info = tarfile.TarInfo(name)
            info.size, info.mode, info.mtime = len(data), 0o644, 0
            tar.addfile(info, io.BytesIO(data))
    start = time.perf_counter()
    with open(target, "wb") as out, gzip.GzipFile(fileobj=out, mode="wb", mtime=0, compresslevel=9) as gz:
        gz.write(raw.getvalue())
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rollouts = [rollouts_bytes(policy_rollouts(s, "idm")) for s in scenes.generate_scenes(args.scenes, seed=0)]
    metadata = SubmissionMetadata(
        unique_method_name="bench", account_name="a@b.c", authors=["A"], affiliation="B", description="bench"
    )
    with tempfile.TemporaryDirectory() as scratch:
        ours, theirs = Path(scratch) / "isal.tar.gz", Path(scratch) / "zlib9.tar.gz"
        ours_s, theirs_s = [], []
        for _ in range(args.repeat):
            start = time.perf_counter()
            with SubmissionWriter(metadata, ours, num_shards=2) as writer:
                for data in rollouts:
                    writer.add(data)
            ours_s.append(time.perf_counter() - start)
            theirs_s.append(zlib9_copy(ours, theirs))
        same = members(ours) == members(theirs)
        tar_mb = sum(len(d) for d in members(ours).values()) / 1e6
        print(f"{args.scenes} scenes, {tar_mb:.1f} MB of shards, median of {args.repeat}")
        print(
            f"SubmissionWriter (ISA-L level {ARCHIVE_LEVEL}): {statistics.median(ours_s):.3f} s (the whole write),"
            f" {ours.stat().st_size / 1e6:.2f} MB"
        )
        print(
            f"zlib level 9 (gzip alone):              {statistics.median(theirs_s):.3f} s,"
            f" {theirs.stat().st_size / 1e6:.2f} MB"
        )
        print(
            f"speed-up {statistics.median(theirs_s) / statistics.median(ours_s):.1f}x, size"
            f" {ours.stat().st_size / theirs.stat().st_size - 1:+.1%}, same members: {same}"
        )


if __name__ == "__main__":
    main()
