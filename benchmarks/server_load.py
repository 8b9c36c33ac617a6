"""Bounded load test of the scoring service on loopback.

Starts `wosac-server serve` (real uvicorn, real SQLite file, real worker processes)
in a temp dir, uploads N submissions concurrently (default 20), waits until every
one is scored and prints the figures: upload wall time, uploads/s, MB/s, time until
all were scored, scenarios/s, and whether every result equals the first one (the
same submission must score the same every time).

    .venv/bin/python benchmarks/server_load.py [--uploads 20] [--workers 2] [--submission PATH]

Uploads the one-scenario golden submission of ../shared (scored with allow_partial
against both shared scenarios); when ../shared is absent, demo data from
`wosac_eval.sim` instead. --submission/--scenarios override both.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from bench_env import REPO  # noqa: E402

from support.server_harness import Server, scoring_data  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--uploads", type=int, default=20, help="concurrent uploads (default 20)")
    parser.add_argument("--workers", type=int, default=2, help="scoring worker processes (default 2)")
    parser.add_argument("--submission", type=Path, help="default: a one-scenario golden (or demo) submission")
    parser.add_argument("--scenarios", type=Path, nargs="+", help="default: the matching scenario shards")
    parser.add_argument("--timeout", type=float, default=900.0, help="give up after this many seconds")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="wosac-load-") as tmp:
        if args.submission is None or args.scenarios is None:
            data = scoring_data(Path(tmp) / "inputs")
            args.submission = args.submission or data.single
            args.scenarios = args.scenarios or data.scenarios
            print(f"inputs: {data.source} data")
        for path in [args.submission, *args.scenarios]:
            if not path.exists():
                print(f"missing {path}", file=sys.stderr)
                return 2
        body = args.submission.read_bytes()
        server = Server(
            Path(tmp) / "data", args.scenarios, workers=args.workers, poll_s=0.2, heartbeat_s=2, lease_s=30
        ).start()
        try:
            key = server.key("load", max_concurrent=10**6, max_daily=10**6)
            with server.client(key, timeout=300) as client:

                def upload(_):
                    t = time.perf_counter()
                    r = client.post("/v1/submissions", content=body, params={"allow_partial": "true"})
                    assert r.status_code == 202, r.text
                    return r.json()["id"], time.perf_counter() - t

                t0 = time.perf_counter()
                with ThreadPoolExecutor(args.uploads) as pool:
                    uploaded = list(pool.map(upload, range(args.uploads)))
                upload_s = time.perf_counter() - t0
                ids = [sid for sid, _ in uploaded]
                pending, states = set(ids), {}
                while pending and time.perf_counter() - t0 < args.timeout:
                    for s in client.get("/v1/submissions", params={"limit": 1000}).json()["submissions"]:
                        if s["id"] in pending and s["state"] in ("done", "failed"):
                            states[s["id"]] = s
                            pending.discard(s["id"])
                    time.sleep(0.2)
                all_s = time.perf_counter() - t0
                done = [sid for sid in ids if states.get(sid, {}).get("state") == "done"]
                results = {
                    sid: json.dumps(client.get(f"/v1/submissions/{sid}/results").json(), sort_keys=True) for sid in done
                }
        finally:
            server.stop()

    n = args.uploads
    latencies = sorted(lat for _, lat in uploaded)
    scenarios = sum(states[sid]["progress"]["scenarios_total"] or 0 for sid in done)
    print(f"uploads: {n} concurrent x {len(body) / 1e6:.2f} MB, {args.workers} worker process(es)")
    print(
        f"upload phase: {upload_s:.2f} s, {n / upload_s:.1f} uploads/s, {n * len(body) / 1e6 / upload_s:.1f} MB/s; "
        f"latency median {statistics.median(latencies):.2f} s, max {latencies[-1]:.2f} s"
    )
    print(
        f"all scored after {all_s:.2f} s: {len(done)}/{n} done, {n - len(done) - len(pending)} failed, "
        f"{len(pending)} unfinished; {scenarios / all_s:.2f} scenarios/s"
    )
    same = len(set(results.values())) == 1
    print(f"every result identical: {same}")
    return 0 if len(done) == n and same else 1


if __name__ == "__main__":
    sys.exit(main())
