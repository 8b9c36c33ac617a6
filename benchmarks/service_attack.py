"""The scoring service under attack on loopback: what each bomb costs, and /healthz while it is attacked.

Starts `wosac-server serve` (real uvicorn, SQLite, one scoring worker, default limits) in a temp dir
and prints:

1. every bomb of `tests/support/bombs.py` (1 GiB of zeros in tar.bz2/xz/gz, 8 million empty
   scenario_rollouts or trajectories in 16 kB of tar.gz, 100k archive members): where it was
   stopped (at upload, or by its scoring job), the reason, the upload's answer time, the scoring
   process's peak RSS (`peak_rss_bytes` of the job) and the API process's peak RSS;
2. /healthz latency (p50/p99/max of a probe every 20 ms from 127.0.0.1, in a process of its own)
   while 40 bomb uploads run
   at once (10 waves; one key allowed 2 jobs, from four other loopback addresses), and while 1,100
   connections that never finish their headers are held open (from 40 addresses, then from one),
   while 100 slow bodies dribble one byte every 0.5 s of a declared megabyte (half without a key,
   half with keys), and while 1,100 connections from 40 addresses are held against the service's
   open-file limit (`--server-nofile`, default 1024, the limit the red team used);
3. the upload check's cost against plain decompression of the same .tar.gz (same repetitions).

    python benchmarks/service_attack.py [--connections 1100] [--uploads 40] [--sections bombs,uploads,...]
"""

from __future__ import annotations

import argparse
import gzip
import multiprocessing
import os
import resource
import socket
import statistics
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from bench_env import median_seconds  # noqa: E402

from support.bombs import all_bombs, empty_rollouts_bomb, zeros_bomb  # noqa: E402
from support.server_harness import Server, scoring_data, tar_bytes  # noqa: E402

MiB = 1 << 20


def peak_rss(pid: int) -> int:
    for line in open(f"/proc/{pid}/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return 0


def _probe_loop(port: int, period_s: float, stop, out) -> None:
    """GET /healthz every `period_s` on fresh connections; sends (latencies, failures) when told to stop."""
    latencies, failures = [], 0
    while not stop.is_set():
        started = time.perf_counter()
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
                s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
                answer = b""
                while chunk := s.recv(4096):
                    answer += chunk
            ok = answer.startswith(b"HTTP/1.1 200")
        except OSError:
            ok = False
        latencies.append(time.perf_counter() - started)
        failures += not ok
        stop.wait(period_s)
    out.send((latencies, failures))


class HealthProbe:
    """/healthz latencies from a process of its own (the attackers' threads must not slow the probe)."""

    def __init__(self, server: Server, period_s: float = 0.02):
        ctx = multiprocessing.get_context("fork")
        self.stop, (self._receive, send) = ctx.Event(), ctx.Pipe(duplex=False)
        self.process = ctx.Process(target=_probe_loop, args=(server.port, period_s, self.stop, send), daemon=True)
        self.latencies: list[float] = []
        self.failures = 0

    def start(self) -> None:
        self.process.start()

    def join(self) -> None:
        self.stop.set()
        self.latencies, self.failures = self._receive.recv()
        self.process.join()

    def summary(self) -> str:
        xs = sorted(self.latencies)
        p99 = xs[min(len(xs) - 1, int(0.99 * len(xs)))]
        return (
            f"/healthz n={len(xs)} p50 {statistics.median(xs) * 1e3:.1f} ms, p99 {p99 * 1e3:.1f} ms, "
            f"max {xs[-1] * 1e3:.1f} ms, failed {self.failures}"
        )


def probed(server: Server, work) -> tuple[object, HealthProbe]:
    probe = HealthProbe(server)
    probe.start()
    time.sleep(0.3)  # a baseline before the attack starts
    try:
        result = work()
    finally:
        probe.join()
    return result, probe


def bombs_one_by_one(server: Server, key: str) -> None:
    print("\n1. bombs, one at a time (worker: one process per job; limits: the service defaults)")
    print(
        f"{'bomb':40s} {'size':>9s}  {'stopped':10s} {'answer':>8s} {'job peak RSS':>13s} {'API peak RSS':>13s}  reason"
    )
    with server.client(key, timeout=600) as c:
        for name, bomb in all_bombs().items():
            started = time.perf_counter()
            r = c.post("/v1/submissions", content=bomb, params={"allow_partial": "true"})
            answer = time.perf_counter() - started
            job_rss = "-"
            if r.status_code == 202:
                status = server.wait_state(c, r.json()["id"], timeout=600)
                while status["peak_rss_bytes"] is None:
                    time.sleep(0.05)
                    status = c.get(f"/v1/submissions/{status['id']}").json()
                where = f"job {status['state']}"
                job_rss = f"{status['peak_rss_bytes'] / MiB:.0f} MiB"
                report = status.get("validation_report") or {}
                reason = next(
                    (
                        line.strip(" -")
                        for line in report.get("text", "").splitlines()
                        if "refused before parsing" in line
                    ),
                    status["error"],
                )
            else:
                where, reason = f"upload {r.status_code}", r.json()["detail"]
            print(
                f"{name:40s} {len(bomb):>9d}  {where:10s} {answer:>7.2f}s {job_rss:>13s} "
                f"{peak_rss(server.proc.pid) / MiB:>9.0f} MiB  {reason[:110]}"
            )


ATTACKER_NICE = 0  # --attacker-nice: the attack's threads share this machine's cores with the server


def _attacker_priority() -> None:
    if ATTACKER_NICE:
        os.setpriority(os.PRIO_PROCESS, 0, ATTACKER_NICE)  # on Linux: this thread only


def concurrent_bomb_uploads(server: Server, uploads: int, waves: int) -> None:
    key = server.key("attacker", max_concurrent=2)
    bombs = [zeros_bomb("gz", 256 * MiB), empty_rollouts_bomb(4_000_000)]

    def upload(i: int) -> int:
        source = f"127.0.0.{2 + i % 4}"
        with server.client(key, timeout=120, source=source) as c:
            return c.post("/v1/submissions", content=bombs[i % 2]).status_code

    def attack():
        codes = []
        with ThreadPoolExecutor(uploads, initializer=_attacker_priority) as pool:
            for _ in range(waves):
                codes += pool.map(upload, range(uploads))
        return codes

    started = time.perf_counter()
    codes, probe = probed(server, attack)
    took = time.perf_counter() - started
    counts = {code: codes.count(code) for code in sorted(set(codes))}
    print(
        f"\n2a. {waves} waves of {uploads} concurrent bomb uploads (a key allowed 2 jobs; attackers at nice "
        f"{ATTACKER_NICE}): answers {counts} in {took:.1f} s; {probe.summary()}"
    )


def half_open(server: Server, connections: int, sources: int, hold_s: float) -> None:
    def attack():
        socks = []
        for i in range(connections):
            s = socket.socket()
            s.bind((f"127.0.1.{1 + i % sources}", 0))
            s.setblocking(True)
            try:
                s.connect(("127.0.0.1", server.port))
                s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")  # never finished
            except OSError:
                pass
            socks.append(s)
        opened = time.perf_counter()
        time.sleep(hold_s)
        closed = 0
        for s in socks:
            s.setblocking(False)
            try:
                closed += s.recv(1) == b"H"  # an answer (408/503) came: the server closed it
            except OSError:
                pass
            s.close()
        return closed, time.perf_counter() - opened

    ((closed, held), peak), probe = probed(server, lambda: fd_watch(server, attack))
    exhausted = sum(
        "Too many open files" in line or "out of system resource" in line
        for line in server.log.read_text().splitlines()
    )
    print(
        f"2b. {connections} half-open connections from {sources} address(es), held {held:.0f} s: "
        f"{closed} answered and closed by the server; server descriptors at most {peak[0]} (limit "
        f"{server.nofile or resource.getrlimit(resource.RLIMIT_NOFILE)[1]}), {exhausted} log line(s) of "
        f"descriptor exhaustion; {probe.summary()}"
    )


def slow_bodies(server: Server, count: int, period_s: float, hold_s: float) -> None:
    """`count` POSTs declaring 1,000,000 bytes, then one byte every `period_s`: half without a key, half
    with one of 25 keys (each allowed 2 jobs): how soon the server closes them and what it answered."""
    keys = [server.key(f"slow-{i}", max_concurrent=2) for i in range(25)]
    uploads = server.data_dir / "uploads"

    def attack():
        socks = []
        for i in range(count):
            s = socket.socket()
            s.bind((f"127.0.3.{1 + i % 4}", 0))
            s.connect(("127.0.0.1", server.port))
            auth = f"Authorization: Bearer {keys[i % len(keys)]}\r\n" if i % 2 else ""
            s.sendall(f"POST /v1/submissions HTTP/1.1\r\nHost: x\r\n{auth}Content-Length: 1000000\r\n\r\n".encode())
            s.setblocking(False)
            socks.append([s, time.perf_counter(), None, b""])
        most_files = peak_fds = 0
        started = time.perf_counter()
        last_sent = 0.0
        while time.perf_counter() - started < hold_s and any(entry[2] is None for entry in socks):
            send = time.perf_counter() - last_sent >= period_s
            last_sent = time.perf_counter() if send else last_sent
            for entry in socks:
                s = entry[0]
                if entry[2] is not None:
                    continue
                if send:
                    try:
                        s.send(b"x")
                    except OSError:
                        pass
                try:
                    data = s.recv(65536)
                    entry[3] += data
                    if not data:
                        entry[2] = time.perf_counter() - entry[1]
                except BlockingIOError:
                    pass
                except OSError:
                    entry[2] = time.perf_counter() - entry[1]
            most_files = max(most_files, len(list(uploads.glob("*.body"))))
            peak_fds = max(peak_fds, len(os.listdir(f"/proc/{server.proc.pid}/fd")))
            time.sleep(0.05)  # a close is seen within 50 ms
        for entry in socks:
            entry[0].close()
        return socks, most_files, peak_fds

    (socks, most_files, peak_fds), probe = probed(server, attack)
    time.sleep(0.5)
    left = len(list(uploads.glob("*.body")))
    for with_key, label in ((False, "without a key"), (True, "with a key")):
        group = [e for i, e in enumerate(socks) if bool(i % 2) == with_key]
        closed = sorted(e[2] for e in group if e[2] is not None)
        answers: dict[str, int] = {}
        for e in group:
            status = e[3][9:12].decode() if e[3].startswith(b"HTTP/1.1 ") else "none"
            answers[status] = answers.get(status, 0) + 1
        when = (
            f"closed after p50 {statistics.median(closed):.1f} s, max {closed[-1]:.1f} s" if closed else "none closed"
        )
        print(f"    {len(group)} slow bodies {label}: {len(closed)} closed by the server ({when}); answers {answers}")
    print(
        f"2c. {count} slow bodies (1 byte per {period_s:g} s of a declared 1,000,000): at most {most_files} "
        f"temporary body file(s) at once, {left} left after; server descriptors at most {peak_fds}; "
        f"{probe.summary()}"
    )


def fd_watch(server: Server, work):
    """Runs `work`; (its result, the most descriptors the server held meanwhile)."""
    import threading

    peak, stop = [0], threading.Event()

    def watch():
        while not stop.is_set():
            try:
                peak[0] = max(peak[0], len(os.listdir(f"/proc/{server.proc.pid}/fd")))
            except OSError:
                pass
            stop.wait(0.05)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        return work(), peak
    finally:
        stop.set()
        watcher.join()


def check_cost(tmp: Path, shard: bytes) -> None:
    from wosac_eval.parse.archive import check_container

    members = {f"shard-{i:05d}.binproto": shard for i in range(max(1, (64 * MiB) // len(shard)))}
    path = tmp / "legit.tar.gz"
    path.write_bytes(tar_bytes(members))

    def plain():
        with gzip.open(path, "rb") as f:
            while f.read(MiB):
                pass

    ours = median_seconds(lambda: check_container(path), repeat=3, warmup=1)
    base = median_seconds(plain, repeat=3, warmup=1)
    size = sum(map(len, members.values()))
    print(
        f"\n3. upload check of a {path.stat().st_size / MiB:.0f} MiB .tar.gz ({len(members)} shards, "
        f"{size / MiB:.0f} MiB inside): check_container {ours:.3f} s, plain gzip decompression {base:.3f} s "
        f"({ours / base:.2f}x)"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connections", type=int, default=1100)
    parser.add_argument("--uploads", type=int, default=40)
    parser.add_argument("--waves", type=int, default=10, help="rounds of --uploads concurrent uploads")
    parser.add_argument("--hold", type=float, default=12.0, help="seconds the half-open connections are held")
    parser.add_argument("--slow-bodies", type=int, default=100)
    parser.add_argument(
        "--server-nofile",
        type=int,
        default=1024,
        help="the service's open-file limit (soft and hard; 0: this process's)",
    )
    parser.add_argument(
        "--sections",
        default="bombs,uploads,half-open,slow-bodies,check",
        help="which of: bombs, uploads, half-open, slow-bodies, check",
    )
    parser.add_argument(
        "--attacker-nice",
        type=int,
        default=10,
        help="niceness of the uploading threads (default 10: on a small machine the attack "
        "would otherwise take the server's cores, as a remote attacker cannot; 0 to compare)",
    )
    args = parser.parse_args()
    global ATTACKER_NICE
    ATTACKER_NICE = args.attacker_nice
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    with tempfile.TemporaryDirectory(prefix="wosac-attack-") as tmp:
        tmp = Path(tmp)
        data = scoring_data(tmp / "data")
        sections = set(args.sections.split(","))
        server = Server(tmp / "service", data.scenarios, nofile=args.server_nofile or None, workers=1).start()
        try:
            print(
                f"service on 127.0.0.1:{server.port}, scenarios: {data.source}, open-file limit "
                f"{args.server_nofile or hard}"
            )
            if "bombs" in sections:
                bombs_one_by_one(server, server.key("bomber"))
            if "uploads" in sections:
                concurrent_bomb_uploads(server, args.uploads, args.waves)
            if "half-open" in sections:
                half_open(server, args.connections, 40, args.hold)
                half_open(server, args.connections, 1, args.hold)
            if "slow-bodies" in sections:
                slow_bodies(server, args.slow_bodies, 0.5, hold_s=40)
            shard = data.single.read_bytes() if data.single.suffix == ".binproto" else None
            if shard is not None and "check" in sections:
                check_cost(tmp, shard)
        finally:
            server.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
