"""A validation-size result (44,097 scenarios, ~150 MB of JSON) served by the real service: the API
process's peak RSS while it streams the JSON and the CSV, for a result stored as the worker stores it
(summary + rows, `wosac_server.results`) and for one stored by an earlier service (one `<id>.json`).

Starts `wosac-server serve` (no workers) in a temp dir, writes both results for two jobs marked done
(synthetic rows shaped like real ones: `tests/support/results.py`), then downloads each form once
with httpx and prints bytes, seconds and the API process's resident memory: before the request and
its peak during it (the kernel's VmHWM, reset before each request through /proc/PID/clear_refs).
For comparison, the peak RSS of the service's former CSV path (`json.load` of the file and the CSV
built in memory) in a process of its own.

    python benchmarks/result_streaming.py [--rows 44097]
"""

from __future__ import annotations

import argparse
import gc
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_env import REPO, VALIDATION_SET  # noqa: E402

import httpx  # noqa: E402

from support.results import synthetic_result  # noqa: E402
from support.server_harness import Server, as_submission  # noqa: E402
from wosac_server import jobs, results  # noqa: E402

MiB = 1 << 20


def rss(pid: int, field: str) -> int:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024
    return 0


def reset_peak(pid: int) -> bool:
    try:
        Path(f"/proc/{pid}/clear_refs").write_text("5")  # VmHWM := VmRSS
        return True
    except OSError:
        return False


def fetch(server: Server, key: str, path: str, params: dict | None = None) -> tuple[int, float, int, int]:
    """(bytes, seconds, RSS before, peak RSS during) of one streamed download."""
    pid = server.proc.pid
    reset_peak(pid)
    before = rss(pid, "VmRSS")
    size, started = 0, time.perf_counter()
    with httpx.Client(base_url=server.url, headers={"Authorization": f"Bearer {key}"}, timeout=600) as c:
        with c.stream("GET", path, params=params) as r:
            assert r.status_code == 200, r.read()[:500]
            for piece in r.iter_raw():
                size += len(piece)
    return size, time.perf_counter() - started, before, rss(pid, "VmHWM")


FORMER_CSV = """
import json, resource, sys
sys.path.insert(0, sys.argv[2])
from wosac_server.results import result_csv
with open(sys.argv[1]) as f:
    text = result_csv(json.load(f))
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, len(text))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rows", type=int, default=VALIDATION_SET)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="wosac-results-bench-") as tmp:
        root = Path(tmp)
        placeholder = root / "placeholder.tfrecord"
        placeholder.write_bytes(b"")
        server = Server(root / "data", [placeholder], workers=0).start()
        try:
            key = server.key("bench")
            ids = {}
            with server.client(key) as c:
                for form in ("split", "single file"):
                    ids[form] = c.post("/v1/submissions", content=as_submission(b"b" * 64)).json()["id"]
                    server.store.execute("UPDATE submissions SET state = 'done' WHERE id = ?", (ids[form],))
            doc = synthetic_result(args.rows)
            results_dir = server.data_dir / "results"
            started = time.perf_counter()
            results.write_result(results_dir, ids["split"], doc)
            split_write = time.perf_counter() - started
            legacy = results.legacy_path(results_dir, ids["single file"])
            started = time.perf_counter()
            jobs.write_json_atomically(legacy, doc)
            single_write = time.perf_counter() - started
            del doc
            gc.collect()
            print(
                f"{args.rows} rows; result JSON {legacy.stat().st_size / MiB:.1f} MiB; "
                f"written as summary + rows in {split_write:.2f} s (the single file: {single_write:.2f} s)"
            )
            print(
                f"API process at rest: {rss(server.proc.pid, 'VmRSS') / MiB:.0f} MiB RSS; peak per request: "
                + (
                    "VmHWM, reset before each"
                    if reset_peak(server.proc.pid)
                    else "VmHWM since the process started (clear_refs refused: an upper bound)"
                )
            )
            print(
                f"{'stored as':12s} {'request':34s} {'bytes':>11s} {'seconds':>8s} {'RSS before':>11s} {'peak RSS':>9s}"
            )
            for form, sid in ids.items():
                for label, path, params in [
                    ("results (JSON)", f"/v1/submissions/{sid}/results", None),
                    ("results?format=csv", f"/v1/submissions/{sid}/results", {"format": "csv"}),
                    ("results/summary", f"/v1/submissions/{sid}/results/summary", None),
                    (
                        "results/scenarios?offset=44000",
                        f"/v1/submissions/{sid}/results/scenarios",
                        {"offset": min(44_000, max(args.rows - 97, 0)), "limit": 1000},
                    ),
                ]:
                    size, seconds, before, peak = fetch(server, key, path, params)
                    print(
                        f"{form:12s} {label:34s} {size:>11,d} {seconds:>8.2f} {before / MiB:>7.0f} MiB "
                        f"{peak / MiB:>5.0f} MiB"
                    )
            former = subprocess.run(
                [sys.executable, "-c", FORMER_CSV, str(legacy), str(REPO / "server")],
                capture_output=True,
                text=True,
                check=True,
            )
            peak, length = map(int, former.stdout.split())
            print(
                f"former CSV path (json.load + CSV in memory, own process): peak RSS {peak / MiB:.0f} MiB "
                f"for {length:,d} characters of CSV"
            )
        finally:
            server.stop()


if __name__ == "__main__":
    main()
