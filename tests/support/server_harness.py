"""Run the real service for tests and benchmarks: `wosac-server serve` as a child
process on 127.0.0.1 with its own data dir (a real SQLite file) and a free port."""

from __future__ import annotations

import gzip
import io
import json
import os
import random
import signal
import socket
import ssl
import subprocess
import sys
import tarfile
import time
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import httpx

from support.paths import SHARED
from wosac_server import auth
from wosac_server.db import Store

GOLDEN = SHARED / "golden"
SCENARIO_FILES = [
    SHARED / "womd" / "motion_data_one_scenario.tfrecord",
    SHARED / "womd" / "womd_scenario_input.tfrecord",
]
# One golden submission per shared scenario: together they cover both.
GOLDEN_PAIR = [GOLDEN / "637f20cafde22ff8__logreplay.binproto", GOLDEN / "ee519cf571686d19__constvel_noise.binproto"]


@dataclass(frozen=True)
class ScoringData:
    """What the end-to-end tests and the load benchmark score."""

    source: str  # "shared golden" or "demo"
    scenarios: list[Path]  # the scenario shards the server scores against
    full: Path  # a valid submission covering every scenario
    single: Path  # a submission covering one scenario (score with allow_partial)


def golden_data(workdir: Path) -> ScoringData | None:
    """The golden submissions of ../shared: one binproto per shared scenario, and a
    two-shard .tar.gz of both (the second shard's metadata set equal to the first's,
    since shards of one submission must agree). None when ../shared is absent."""
    if not all(p.exists() for p in [*SCENARIO_FILES, *GOLDEN_PAIR]):
        return None
    from wosac_eval.protos import sim_agents_submission_pb2 as pb

    first, second = (pb.SimAgentsChallengeSubmission.FromString(p.read_bytes()) for p in GOLDEN_PAIR)
    merged = pb.SimAgentsChallengeSubmission()
    merged.CopyFrom(first)
    del merged.scenario_rollouts[:]
    merged.scenario_rollouts.extend(second.scenario_rollouts)
    full = workdir / "golden-pair.tar.gz"
    full.write_bytes(
        tar_bytes(
            {
                "shard-00000-of-00002.binproto": first.SerializeToString(),
                "shard-00001-of-00002.binproto": merged.SerializeToString(),
            }
        )
    )
    return ScoringData("shared golden", list(SCENARIO_FILES), full, GOLDEN_PAIR[0])


def demo_data(workdir: Path) -> ScoringData:
    """Two synthetic scenes from `wosac_eval.sim` and constant-velocity submissions."""
    from wosac_eval.sim import scenes
    from wosac_eval.sim.baselines import make_submission

    shards = scenes.write_scenario_shards(scenes.generate_scenes(2, seed=0), workdir / "scenarios", num_shards=2)
    full = make_submission(shards, "constant_velocity", workdir / "demo-full.tar.gz", num_shards=2)
    single = make_submission(shards[:1], "constant_velocity", workdir / "demo-single.tar.gz", num_shards=1)
    return ScoringData("demo", shards, full, single)


def scoring_data(workdir: Path) -> ScoringData:
    workdir.mkdir(parents=True, exist_ok=True)
    return golden_data(workdir) or demo_data(workdir)


def _below_ephemeral_ports() -> tuple[int, int]:
    """Ports the kernel never hands out by itself: below its ephemeral range (where the local ports of
    outgoing connections and port-0 binds come from; a test run makes thousands of connections, and one
    once took a port between this probe and a server's bind). From 10000, so as to stay clear of services'
    usual ports."""
    try:
        low, high = (int(p) for p in Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split())
    except (OSError, ValueError):
        low, high = 32768, 60999  # Linux's default
    if low > 11000:
        return 10000, low
    return (high + 1, 65536) if high < 64000 else (1024, 65536)  # above it, else anywhere (a wide range)


def free_port() -> int:
    """A free 127.0.0.1 port outside the kernel's ephemeral range. Under pytest-xdist, one whose remainder
    by the number of workers is this worker's number: two workers never pick the same port between this
    probe and their server's bind."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0) % workers
    # Explicit candidates from a random start (the kernel's own choice of port 0 may never fall in this
    # worker's class: on some machines it hands out odd ports only).
    low, high = _below_ephemeral_ports()
    start = random.randrange(low, high)
    start -= start % workers
    candidates = [*range(start + worker, high, workers), *range(low + (worker - low) % workers, start, workers)]
    for port in candidates:
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        return port
    raise RuntimeError("no free 127.0.0.1 port in this worker's class")


@cache
def tls_context() -> ssl.SSLContext:
    """One TLS context for every client of this process: an httpx client otherwise builds its own (the CA
    bundle read and parsed, ~40 ms of CPU each), unused on these plain-HTTP loopback URLs; at ten polls a
    second that was a sixth of the service tests' work."""
    return ssl.create_default_context()


def wait_healthy(url: str, process: subprocess.Popen, timeout: float) -> None:
    """Returns once `url`/healthz answers 200; RuntimeError when `process` exits first or time runs out."""
    deadline = time.monotonic() + timeout
    with httpx.Client(timeout=1.0, verify=tls_context()) as client:
        while time.monotonic() < deadline:
            if process.poll() is not None:
                raise RuntimeError(f"exited with {process.returncode}")
            try:
                if client.get(url + "/healthz").status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
    raise RuntimeError(f"did not come up in {timeout} s")


def canonical(result: dict) -> str:
    """JSON text with sorted keys: NaN-safe equality of two results."""
    return json.dumps(result, sort_keys=True, allow_nan=True)


class Server:
    """`wosac-server serve` as a child process, with its own data dir and port."""

    def __init__(self, data_dir: Path, scenarios: list[Path], nofile: int | None = None, **env: object):
        self.data_dir = data_dir
        self.nofile = nofile  # the server's open-file limit (soft and hard), when given
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        inherited = {k: v for k, v in os.environ.items() if not k.startswith("WOSAC_")}
        self.env = {
            **inherited,
            "WOSAC_DATA_DIR": str(data_dir),
            "WOSAC_SCENARIOS": ",".join(str(p) for p in scenarios),
            "WOSAC_POLL_S": "0.1",
            "WOSAC_HEARTBEAT_S": "0.2",
            "WOSAC_LEASE_S": "1.5",
            "WOSAC_WORKERS": "1",
            "WOSAC_SHUTDOWN_GRACE_S": "2",
            # No pictures of the worst scenes (drawn after scoring: ~1.5 s of a job here) unless a test
            # looks at them and asks (`scene_pictures=3`, the service's default).
            "WOSAC_SCENE_PICTURES": "0",
            "PYTHONUNBUFFERED": "1",
            # Tests must not depend on how full the machine's disk is, nor leave 64 MiB reserve files:
            # the disk tests (server_disk_test.py) set these on a filesystem of their own.
            "WOSAC_MIN_FREE_FRACTION": "0",
            "WOSAC_DISK_RESERVE_BYTES": str(2**20),
            # The run's own cache of scenes' criticality (tests/conftest.py), not the user's.
            "WOSAC_CRITICALITY_CACHE": os.environ.get("WOSAC_CRITICALITY_CACHE", "off"),
        }
        self.env.update({f"WOSAC_{k.upper()}": str(v) for k, v in env.items()})
        self.proc: subprocess.Popen | None = None
        self.log = data_dir.parent / f"server-{self.port}.log"

    @property
    def store(self) -> Store:
        url = self.env.get("WOSAC_DB_URL") or f"sqlite:///{self.data_dir / 'wosac.sqlite3'}"
        return Store(url)

    def start(self, timeout: float = 30.0) -> "Server":
        self.data_dir.mkdir(parents=True, exist_ok=True)
        log = open(self.log, "ab")
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "wosac_server",
                "serve",
                "--host",
                "127.0.0.1",
                "--port",
                str(self.port),
                "--log-level",
                "warning",
            ],
            env=self.env,
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=self.data_dir.parent,
            preexec_fn=self._limit_open_files if self.nofile else None,
        )
        try:
            wait_healthy(self.url, self.proc, timeout)
        except RuntimeError as error:
            raise RuntimeError(f"server {error}:\n{self.log.read_text()}") from None
        return self

    def _limit_open_files(self) -> None:
        import resource

        resource.setrlimit(resource.RLIMIT_NOFILE, (self.nofile, self.nofile))

    def open_files(self) -> int:
        """File descriptors the server process holds now."""
        return len(os.listdir(f"/proc/{self.proc.pid}/fd"))

    def stop(self) -> None:
        if self.proc and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def key(self, name: str, **limits: int) -> str:
        defaults = dict(max_concurrent=100, max_daily=1000, max_daily_bytes=10**12)
        return auth.create_key(self.store, name, **{**defaults, **limits})

    def client(self, key: str | None = None, timeout: float = 60.0, source: str | None = None) -> httpx.Client:
        """An HTTP client; `source`: the loopback address it connects from (127.0.0.2 is another client)."""
        headers = {"Authorization": f"Bearer {key}"} if key else {}
        transport = httpx.HTTPTransport(local_address=source, verify=tls_context()) if source else None
        return httpx.Client(
            base_url=self.url, headers=headers, timeout=timeout, transport=transport, verify=tls_context()
        )

    def wait_state(
        self, client: httpx.Client, submission_id: str, states=("done", "failed"), timeout: float = 90.0
    ) -> dict:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            body = client.get(f"/v1/submissions/{submission_id}").json()
            if body["state"] in states:
                return body
            time.sleep(0.1)
        raise AssertionError(f"{submission_id} still {body['state']} after {timeout} s:\n{self.log.read_text()}")


def as_submission(payload: bytes) -> bytes:
    """`payload`, the same length, turned into a real SimAgentsChallengeSubmission: its first bytes become
    the header of a `description` field holding the rest. The service checks that uploads are
    submissions at upload time; tests that never score use such bodies as stand-ins."""
    from wosac_eval.parse.wire import varint

    for header_len in range(2, 8):
        header = b"\x3a" + varint(len(payload) - header_len)
        if len(header) == header_len:
            return header + payload[header_len:]
    raise ValueError("payload too short to hold a field header")


def tar_bytes(members: dict[str, bytes], gz: bool = True) -> bytes:
    """A .tar(.gz) holding `members` (name -> content), names taken verbatim. The same bytes in every
    process (gzip's time stamp 0): test ids made of them agree across pytest-xdist workers."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            info.mtime = 0
            tar.addfile(info, io.BytesIO(data))
    return gzip.compress(buf.getvalue(), mtime=0) if gz else buf.getvalue()


def files_under(root: Path) -> set[Path]:
    return {p for p in root.rglob("*") if p.is_file()}


def wait_logged(log_path: Path, text: str, timeout: float = 30.0, process: subprocess.Popen | None = None) -> str:
    """The log once it holds `text` (or as it is after `timeout`, or once `process`, the writer, has
    exited): a worker logs some lines after it records a job's end, so a client can see the job ended
    before they are written."""
    deadline = time.monotonic() + timeout
    while text not in (log := log_path.read_text(errors="replace")) and time.monotonic() < deadline:
        if process is not None and process.poll() is not None:
            return log_path.read_text(errors="replace")
        time.sleep(0.1)
    return log


def resumed_and_scored(log_path: Path, submission_id: str, timeout: float = 30.0) -> tuple[int, int]:
    """(scenarios a job's last attempt took from its journal, scenarios it scored), from the worker's log
    (waiting for its "done" line, `wait_logged`)."""
    log = wait_logged(log_path, f"{submission_id} done (", timeout)
    resumed = int(log.split(f"job {submission_id} resumes from its journal: ")[1].split()[0])
    scored = int(log.split(f"{submission_id} done (")[1].split()[0])
    return resumed, scored


def wait_gone(path: Path, timeout: float = 10.0) -> bool:
    """Whether `path` is gone within `timeout` (a job's journal goes once its end is recorded)."""
    deadline = time.monotonic() + timeout
    while path.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    return not path.exists()
