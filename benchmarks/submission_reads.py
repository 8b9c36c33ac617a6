"""How often one job reads its submission archive: the service's path against the path-based calls.

The service checks an upload (`check_container`), then scores it and draws its worst scenes through one
`SubmissionSource` with a spool; before, each stage opened the archive itself. This prints, for a
synthetic .tar.gz, how many times each way opens the archive, counted with an audit hook on `open`
(nothing is patched), and so how many times it is read through: each read opens it three times (the
sniff's raw and decompressed first bytes, then the stream), and the wall time of each.

    python benchmarks/submission_reads.py [--scenes 6] [--shards 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from wosac_eval.parse.archive import check_container
from wosac_eval.parse.scenarios import ScenarioIndex
from wosac_eval.parse.submission_source import SubmissionSource
from wosac_eval.results.scene_plot import scene_pictures
from wosac_eval.scoring.submission import score_submission
from wosac_eval.sim import baselines, scenes

OPENED: list[str] = []


def _count_opens(event: str, args: tuple) -> None:
    if event == "open" and args and isinstance(args[0], (str, Path)):
        OPENED.append(str(args[0]))


def _opens_of(path: Path, run) -> tuple[int, float]:
    """(times `path` was opened while `run()` ran, seconds)."""
    OPENED.clear()
    start = time.perf_counter()
    run()
    seconds = time.perf_counter() - start
    return sum(1 for p in OPENED if Path(p).resolve() == path.resolve()), seconds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--shards", type=int, default=3)
    args = parser.parse_args()
    sys.addaudithook(_count_opens)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        paths = scenes.write_scenario_shards(scenes.generate_scenes(args.scenes, seed=0), root / "scenarios", 2)
        archive = Path(
            baselines.make_submission(paths, "constant_velocity", root / "upload.tar.gz", num_shards=args.shards)
        )

        def by_paths() -> None:  # each stage reads the archive itself
            check_container(archive)
            result = score_submission(paths, archive, analysis=False)
            scene_pictures(paths, archive, [row["scenario_id"] for row in result["scenarios"]][:2])

        def by_source() -> None:  # the service: the check, then one walk shared by scoring and pictures
            check_container(archive)
            index = ScenarioIndex(paths)
            with SubmissionSource(archive, spool_dir=root) as source:
                result = score_submission(index, source, analysis=False)
                scene_pictures(index, source, [row["scenario_id"] for row in result["scenarios"]][:2])

        by_paths()  # warm-up: imports and caches, the same for both
        print(f"{args.scenes} synthetic scenes, {args.shards} shards, {archive.stat().st_size} bytes of tar.gz")
        print(f"{'way':<40} {'archive opens':>14} {'reads':>6} {'seconds':>8}")
        for name, run in (
            ("paths: check, score, pictures", by_paths),
            ("one SubmissionSource with a spool", by_source),
        ):
            opens, seconds = _opens_of(archive, run)
            print(f"{name:<40} {opens:>14} {opens / 3:>6.0f} {seconds:>8.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
