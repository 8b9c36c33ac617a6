"""The paths of benchmarks/full_scale.py that run a service or a cluster: the scoring service
(`wosac-server serve` on 127.0.0.1, the submission uploaded with `wosac_eval.client.submit`, scored and
published) and Ray (`score_submission(engine="ray")` on a local cluster, one node killed midway, inside a
loopback-only network namespace).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

from full_scale_build import METHOD
from full_scale_paths import PYTHON, Context, workload_paths
from full_scale_watch import GiB, MiB, Run, TreeWatch, by_depth, disk_free, folder_bytes, run_watched

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


def path_service(ctx: Context) -> dict:
    """The service path: a `wosac-server` on 127.0.0.1 with 1 worker, the submission uploaded, scored and
    published; its data dir removed after (the upload's copy is never left behind)."""
    try:  # here, not at the top: the service is installed apart (pip install ./server)
        import httpx
        from support.server_harness import Server
    except ImportError as error:
        return ctx.skipped("service", f"the service is not installed ({error}): pip install ./server")
    scenarios, submission = workload_paths(ctx.build)
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
        t0 = time.perf_counter()
        up, sent = _upload(ctx, server.url, key, submission, folder / "upload")
        upload_wall = time.perf_counter() - t0
        result_path = folder / "result.json"
        with server.client(key, timeout=600) as http:
            sid = sent["id"] or http.get("/v1/submissions").json()["submissions"][0]["id"]
            status = server.wait_state(http, sid, timeout=ctx.service_timeout)
            scored_wall = time.perf_counter() - t0 - upload_wall
            status = _with_job_figures(http, sid, status)
            if status["state"] == "done":
                _download_result(http, sid, result_path)
            board = httpx.get(server.url + "/v1/leaderboard", params={"challenge": ctx.challenge}, timeout=60).json()
        watch.stop()
        measured = _ServiceRun(
            sent,
            status,
            up,
            upload,
            (upload_wall, scored_wall, t0 - t_start),
            any(entry.get("submission_id") == sid for entry in board.get("entries", [])),
        )
        row = _service_row(ctx, measured, watch, data_dir)
        if status["state"] == "done":
            row = ctx.with_result(row, result_path, measured.run(watch))
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


def _upload(ctx: Context, url: str, key: str, submission: Path, child_dir: Path) -> tuple[Run, dict]:
    """The submission uploaded by a client process of its own (watched); its run and the line it printed."""
    child_dir.mkdir()
    up = run_watched(
        [
            PYTHON,
            "-c",
            _UPLOAD_CHILD,
            str(submission),
            url,
            key,
            METHOD,
            str(64 * MiB),
            str(child_dir / "client-state"),
            ctx.challenge,
        ],
        child_dir,
        "upload",
        env=ctx.env(),
    )
    if up.rc != 0:
        raise RuntimeError(f"upload failed (exit {up.rc}): {up.stderr[-2000:]}")
    return up, json.loads(up.stdout.strip().splitlines()[-1])


def _with_job_figures(http, sid: str, status: dict) -> dict:
    """The submission's status once it carries the job's peak RSS and CPU (written just after its state),
    or after 10 s."""
    deadline = time.monotonic() + 10
    while status.get("peak_rss_bytes") is None and time.monotonic() < deadline:
        time.sleep(0.2)
        status = http.get(f"/v1/submissions/{sid}").json()
    return status


def _download_result(http, sid: str, path: Path) -> None:
    with http.stream("GET", f"/v1/submissions/{sid}/results") as answer, open(path, "wb") as f:
        answer.raise_for_status()
        for part in answer.iter_bytes(MiB):
            f.write(part)


@dataclasses.dataclass
class _ServiceRun:
    """What the service path measured: the upload client's line and run, the submission's last status,
    the upload's size, (upload, scoring, server start) seconds, and whether it is on the leaderboard."""

    sent: dict
    status: dict
    upload: Run
    upload_bytes: int
    seconds: tuple[float, float, float]
    published: bool

    def run(self, watch: TreeWatch) -> Run:
        """The path as one run: the upload and the scoring's wall time; the CPU of the upload client and of
        the job (the status's cpu_s: its process and scoring pool)."""
        upload_s, scoring_s, _ = self.seconds
        cpu = self.upload.cpu_s + (self.status.get("cpu_s") or 0.0)
        return Run(0 if self.status["state"] == "done" else 1, upload_s + scoring_s, "", "", watch, cpu)


def _service_row(ctx: Context, measured: _ServiceRun, watch: TreeWatch, data_dir: Path) -> dict:
    """The service path's row: peaks by role, the data dir's peak and final size, the note, and the
    figures under "service"."""
    status, upload = measured.status, measured.upload_bytes
    upload_wall, scored_wall, server_start = measured.seconds
    data_peak, data_end = watch.disk_peak["data"], folder_bytes(data_dir)
    data_parts = {p.name: folder_bytes(p) for p in sorted(data_dir.iterdir())}
    run = measured.run(watch)
    roles = run.watch.peaks(by_depth("api", "worker", "job", "job pool"))
    roles["upload client"] = measured.upload.watch.peaks(by_depth("client"))["client"]
    row = ctx.row(
        "service",
        f"upload + score (1 worker, {ctx.workers} processes per job"
        f"{', challenge=' + ctx.challenge if ctx.challenge_args else ''})",
        run,
        roles,
        disk=data_peak,
    )
    row["note"] = (
        f"{measured.sent['client']}: upload {upload_wall:.1f} s ({upload / MiB / upload_wall:.0f} MiB/s), "
        f"then {scored_wall:.1f} s to {status['state']}"
        + (f" ({status.get('error')})" if status["state"] != "done" else "")
        + f"; data dir peak {data_peak / GiB:.2f} GiB, {data_end / GiB:.2f} GiB after, for a "
        f"{upload / GiB:.2f} GiB upload ({data_peak / upload:.2f}x; at the end: "
        + ", ".join(f"{k} {v / MiB:.1f} MiB" for k, v in data_parts.items() if v >= MiB // 10)
        + "); "
        f"job peak_rss {(status.get('peak_rss_bytes') or 0) / MiB:.0f} MiB, "
        f"cpu {status.get('cpu_s') or 0:.0f} s; "
        f"{'published' if measured.published else 'NOT on the leaderboard'}"
    )
    row["service"] = {
        "client": measured.sent["client"],
        "upload_s": round(upload_wall, 2),
        "scoring_s": round(scored_wall, 2),
        "server_start_s": round(server_start, 2),
        "state": status["state"],
        "data_dir_peak_bytes": data_peak,
        "data_dir_end_bytes": data_end,
        "upload_bytes": upload,
        "job_peak_rss_bytes": status.get("peak_rss_bytes"),
        "job_cpu_s": status.get("cpu_s"),
        "published": measured.published,
        "data_dir_end_parts": data_parts,
        "status": status,
    }
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
    try:  # here, not at the top: Ray is an optional extra
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


def path_ray(ctx: Context) -> dict:
    why = ray_unavailable()
    if why:
        return ctx.skipped("ray", why)
    scenarios, submission = workload_paths(ctx.build)
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
    env = {**ctx.env(), "RAY_TMPDIR": str(ray_tmp), "RAY_DISABLE_USAGE_STATS": "1"}
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
