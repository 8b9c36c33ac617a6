"""What walking a submission archive costs beyond inflating it: the members read as validation copies them.

Validation walks a `.tar.gz` submission once, copying each member to a scratch file a piece at a time
(`SubmissionSource`); scoring walks it again for what the journal did not keep. This times, on one core,
alternated `--repeat` times: inflating the archive alone (ISA-L, `read1` pieces: the floor), the tar walk
reading every member's bytes in the pieces the inflater gives (`MemberReader.read1`) or gathered into
1 MiB reads (`MemberReader.read`), and the first with each piece written to a scratch file, as validation
does. Prints CPU seconds (the median) and MB/s of decompressed bytes.

    python benchmarks/archive_walk.py SUBMISSION.tar.gz [--repeat 3]

A validation-size archive: `python benchmarks/full_scale.py --scenes 1200 --paths none --workdir DIR` builds
DIR/build/submission.tar.gz.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from isal import igzip

from wosac_eval.parse.archive import iter_archive_members
from wosac_eval.parse.decompress import sniff_file
from wosac_eval.parse.limits import InputLimits

PIECE = 1 << 20  # what the walk asks for at a time (`submission_source._COPY_BYTES`)


def inflate(path: Path) -> int:
    with igzip.open(path, "rb") as f:
        return sum(len(piece) for piece in iter(lambda: f.read1(PIECE), b""))


def walk(path: Path, *, gathered: bool = False, scratch: str | None = None) -> int:
    """Decompressed bytes of every member, read as the walk reads them (written to `scratch` if given)."""
    compression = sniff_file(path)[0]
    total = 0
    for number, member in enumerate(iter_archive_members(path, compression, InputLimits())):
        read = member.read if gathered else member.read1
        out = open(os.path.join(scratch, str(number)), "wb") if scratch else None  # noqa: SIM115
        while piece := read(PIECE):
            total += len(piece)
            if out is not None:
                out.write(piece)
        if out is not None:
            out.close()
            os.unlink(out.name)
    return total


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("archive", type=Path)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        ways: dict[str, Callable[[], int]] = {
            "inflate alone (ISA-L)": lambda: inflate(args.archive),
            "walk, pieces as inflated (read1)": lambda: walk(args.archive),
            "walk, 1 MiB reads gathered (read)": lambda: walk(args.archive, gathered=True),
            "walk with read1, each member to a scratch file": lambda: walk(args.archive, scratch=scratch),
        }
        seconds: dict[str, list[float]] = {name: [] for name in ways}
        size = 0
        for _ in range(args.repeat):  # alternated: a machine whose speed drifts moves every way alike
            for name, way in ways.items():
                start = time.process_time()
                size = way()
                seconds[name].append(time.process_time() - start)
    print(f"{args.archive}: {size / 1e6:.0f} MB decompressed; CPU seconds, median of {args.repeat} alternated runs")
    for name, times in seconds.items():
        median = statistics.median(times)
        print(f"  {name:48s} {median:6.2f} s  {size / 1e6 / median:7.0f} MB/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
