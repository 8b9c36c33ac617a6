"""Upload speed of the service's tus uploads on loopback: `wosac-eval submit` and the web page in headless
Chromium (tus-js-client), each into a fresh `wosac-server serve` (no worker: the upload is measured, then
the submission stays queued).

For each size: MiB/s from the first request to the submission's id (the upload check of the whole file
included), the API process's CPU seconds per GiB and its peak RSS (VmHWM: flat with the size when
nothing is held in memory); and the cost of a resume: the CLI killed (SIGKILL) half-way, run again, the
extra seconds and bytes sent against the run without the kill.

The submission is a real one of any size: an uncompressed tar of shards, each the golden submission with
a description padded to 1 GiB (what the upload check reads as a submission; the job would fail validation
for scenarios repeated across shards, but nothing scores here). The files are deleted afterwards.

    python benchmarks/upload_speed.py --sizes-gib 2,20 [--no-browser] [--dir /big/disk]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import shutil
import signal
import subprocess
import tarfile
import tempfile
import time
from pathlib import Path

from bench_env import REPO  # noqa: F401  (tests/support on the path)

from support.browser import DevToolsBrowser, find_chromium
from support.runs import WOSAC_EVAL
from support.server_harness import Server, scoring_data

GiB = 2**30
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]


def padded_shard(data, pad: int) -> bytes:
    """The golden (or demo) submission's rollouts in one shard, its description `pad` bytes."""
    from wosac_eval.protos import sim_agents_submission_pb2 as pb

    with tarfile.open(data.full) as tar:
        shards = [tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()]
    merged = pb.SimAgentsChallengeSubmission.FromString(shards[0])
    for shard in shards[1:]:
        merged.scenario_rollouts.extend(pb.SimAgentsChallengeSubmission.FromString(shard).scenario_rollouts)
    merged.description = "x" * pad
    return merged.SerializeToString()


def make_submission(path: Path, size: int, data) -> Path:
    """An uncompressed tar of shards of about 1 GiB each, `size` bytes or a little more."""
    shard = padded_shard(data, min(GiB, size) - 4096)
    count = max(1, round(size / len(shard)))
    with tarfile.open(path, "w") as tar:
        for i in range(count):
            info = tarfile.TarInfo(f"shard-{i:05d}-of-{count:05d}.binproto")
            info.size = len(shard)
            tar.addfile(info, io.BytesIO(shard))
    return path


def process_figures(pid: int) -> tuple[float, int]:
    """(CPU seconds, peak RSS bytes) of a process so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    cpu = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    peak = next(int(line.split()[1]) * 1024 for line in open(f"/proc/{pid}/status") if line.startswith("VmHWM:"))
    return cpu, peak


def start_server(root: Path, data) -> Server:
    shutil.rmtree(root, ignore_errors=True)
    return Server(root, data.scenarios, workers=0, min_free_fraction=0, disk_reserve_bytes=0).start(timeout=60)


def cli(server: Server, key: str, path: Path, state: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [*WOSAC_EVAL, "submit", str(path), "--server", server.url, "--method", "bench"] + ["--state-dir", str(state)],
        env={**os.environ, "WOSAC_API_KEY": key},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def measure(server: Server, run) -> dict:
    """Runs `run()` (an upload to completion); the API process's figures over it."""
    cpu0, _ = process_figures(server.proc.pid)
    start = time.monotonic()
    detail = run()
    seconds = time.monotonic() - start
    cpu1, peak = process_figures(server.proc.pid)
    return {"seconds": seconds, "api_cpu_s": cpu1 - cpu0, "api_peak_rss_mib": peak / 2**20, **detail}


def cli_upload(server: Server, key: str, path: Path, state: Path) -> dict:
    done = cli(server, key, path, state)
    out, err = done.communicate()
    if done.returncode != 0:
        raise RuntimeError(err)
    return {"submission": out.split()[1].rstrip(":")}


def cli_resume(server: Server, key: str, path: Path, state: Path) -> dict:
    """The CLI killed (SIGKILL) once the server holds half the file, then run again to the end."""
    size, first = path.stat().st_size, cli(server, key, path, state)
    while (row := server.store.fetchone("SELECT received_bytes FROM uploads")) is None or row[
        "received_bytes"
    ] < size // 2:
        time.sleep(0.05)
    first.send_signal(signal.SIGKILL)
    first.wait()
    held = server.store.fetchone("SELECT received_bytes FROM uploads")["received_bytes"]
    start = time.monotonic()
    again = cli(server, key, path, state)
    _, err = again.communicate()
    sent = int(err.split("(sent ")[1].split()[0].replace(",", ""))
    return {
        "held_at_kill": held,
        "sent_after": sent,
        "resent_bytes": sent - (size - held),
        "second_run_s": time.monotonic() - start,
    }


def browser_upload(server: Server, key: str, path: Path, profile: Path) -> dict:
    browser = DevToolsBrowser(find_chromium(), profile, FLAGS)
    try:
        browser.open(server.url + "/")
        browser.choose_file("#upload-form input[type=file]", path)
        browser.js(
            f"""(() => {{ const f = document.getElementById("upload-form"); f.key.value = {json.dumps(key)};
            f.method.value = "bench"; f.requestSubmit(); }})()"""
        )
        deadline = time.monotonic() + 3600
        while not (sid := browser.js("document.getElementById('result-id').textContent")):
            if time.monotonic() > deadline:
                raise RuntimeError(browser.js("document.getElementById('upload-status').textContent"))
            time.sleep(0.5)
    finally:
        browser.close()
    return {"submission": sid}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes-gib", default="2,20", help="file sizes to upload, GiB (comma-separated; '': none)")
    parser.add_argument("--no-browser", action="store_true", help="the CLI only")
    parser.add_argument("--resume-gib", type=float, default=2.0, help="size of the resume's file (0: none)")
    parser.add_argument("--dir", default=None, help="where the files go (default: a temporary folder)")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="upload-speed-", dir=args.dir))
    data = scoring_data(work / "data")
    rows = []
    try:
        for gib in [float(g) for g in args.sizes_gib.split(",") if g]:
            path = make_submission(work / "submission.tar", int(gib * GiB), data)
            size = path.stat().st_size
            runs = [("cli", lambda s, k: cli_upload(s, k, path, work / "state"))]
            if not args.no_browser:
                runs.append(("browser", lambda s, k: browser_upload(s, k, path, work / "profile")))
            for name, run in runs:
                server = start_server(work / "server", data)
                try:
                    key = server.key("bench")
                    figures = measure(server, lambda run=run, server=server, key=key: run(server, key))
                finally:
                    server.stop()
                    shutil.rmtree(work / "server", ignore_errors=True)
                    shutil.rmtree(work / "state", ignore_errors=True)
                    shutil.rmtree(work / "profile", ignore_errors=True)
                row = {"client": name, "bytes": size, **figures}
                row["mib_per_s"] = size / 2**20 / figures["seconds"]
                row["api_cpu_s_per_gib"] = figures["api_cpu_s"] / (size / GiB)
                rows.append(row)
                print(json.dumps(row), flush=True)
            path.unlink()
        if args.resume_gib:
            path = make_submission(work / "submission.tar", int(args.resume_gib * GiB), data)
            server = start_server(work / "server", data)
            try:
                key = server.key("bench")
                for attempt in ("warm-up", "measured"):  # the first pays for the file's pages and the disk's writeback
                    whole = measure(server, lambda a=attempt: cli_upload(server, key, path, work / f"state-{a}"))
                    server.store.execute("DELETE FROM uploads")
                resumed = measure(server, lambda: cli_resume(server, key, path, work / "state-resume"))
            finally:
                server.stop()
            row = {
                "client": "cli resume",
                "bytes": path.stat().st_size,
                "uninterrupted_s": whole["seconds"],
                "killed_and_resumed_s": resumed["seconds"],
                **{k: resumed[k] for k in ("held_at_kill", "sent_after", "resent_bytes", "second_run_s")},
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print("\nclient   size       MiB/s   API CPU s/GiB   API peak RSS")
    for r in rows:
        if "mib_per_s" in r:
            print(
                f"{r['client']:8} {r['bytes'] / GiB:5.1f} GiB  {r['mib_per_s']:6.0f}   {r['api_cpu_s_per_gib']:8.2f}"
                f"        {r['api_peak_rss_mib']:6.0f} MiB"
            )
        else:
            rest = 1 - r["held_at_kill"] / r["bytes"]
            print(
                f"resume of {r['bytes'] / GiB:.1f} GiB killed at {r['held_at_kill'] / GiB:.2f} GiB: the run again "
                f"{r['second_run_s']:.1f} s for the rest ({rest:.0%} of {r['uninterrupted_s']:.1f} s uninterrupted: "
                f"{rest * r['uninterrupted_s']:.1f} s), {r['resent_bytes'] / 2**20:.1f} MiB sent twice; "
                f"both runs {r['killed_and_resumed_s']:.1f} s"
            )


if __name__ == "__main__":
    main()
