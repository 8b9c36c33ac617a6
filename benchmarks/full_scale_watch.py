"""What a path of benchmarks/full_scale.py costs: its processes' peak memory (VmHWM, sampled every 0.2 s
over the whole process tree) and CPU time, the disk its folders take (allocated blocks), and the result
document it writes, digested to be compared with the other paths' (timing fields aside).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

from bench_env import REPO
from full_scale_bases import Layout, scenario_id

MiB = 1 << 20
GiB = 1 << 30


def disk_free(path: Path) -> int:
    path.mkdir(parents=True, exist_ok=True)
    return shutil.disk_usage(path).free


def folder_bytes(path: Path) -> int:
    """Allocated bytes of a file or of everything under a folder (0 when gone)."""
    total = 0
    try:
        if path.is_file():
            return path.stat().st_blocks * 512
        for root, _, files in os.walk(path):
            for name in files:
                try:
                    total += os.lstat(os.path.join(root, name)).st_blocks * 512
                except OSError:
                    pass
    except OSError:
        pass
    return total


def _parents() -> dict[int, tuple[int, int]]:
    """{pid: (parent pid, start time)} of every process (from /proc/<pid>/stat): pid and start time
    name a process even where its pid is reused later."""
    out = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat", "rb") as f:
                    fields = f.read().rsplit(b")", 1)[1].split()
                out[int(entry)] = (int(fields[1]), int(fields[19]))
            except (OSError, IndexError, ValueError):
                pass
    return out


def _hwm_kib(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status", "rb") as f:
            for line in f:
                if line.startswith(b"VmHWM:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def _cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().rstrip(b"\0").replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


class TreeWatch:
    """Samples, every `interval` s until stopped, the peak RSS (VmHWM) of every process descending
    from `root` (the root included) and the allocated bytes of `dirs`."""

    def __init__(self, root: int, dirs: dict[str, Path] | None = None, interval: float = 0.2):
        self.root, self.dirs, self.interval = root, dirs or {}, interval
        self.procs: dict[tuple[int, int], dict] = {}  # (pid, start time) -> {"cmd", "depth", "hwm_kib"}
        self.disk_peak = {name: 0 for name in self.dirs}
        self.alive: list[tuple[tuple[int, int], ...]] = []  # the tree's processes at each sample
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        parents = _parents()
        children: dict[int, list[int]] = {}
        for pid, (ppid, _) in parents.items():
            children.setdefault(ppid, []).append(pid)
        frontier, depth, seen = [self.root], 0, []
        while frontier:
            nxt = []
            for pid in frontier:
                if pid not in parents:
                    continue
                key = (pid, parents[pid][1])
                seen.append(key)
                hwm = _hwm_kib(pid)
                entry = self.procs.get(key)
                if entry is None:
                    entry = self.procs[key] = {"cmd": _cmdline(pid), "depth": depth, "hwm_kib": 0}
                entry["hwm_kib"] = max(entry["hwm_kib"], hwm)
                nxt += children.get(pid, [])
            frontier, depth = nxt, depth + 1
        self.alive.append(tuple(seen))
        for name, path in self.dirs.items():
            self.disk_peak[name] = max(self.disk_peak[name], folder_bytes(path))

    def _run(self) -> None:
        while not self._stop.is_set():
            self._sample()
            self._stop.wait(self.interval)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
        for name, path in self.dirs.items():
            self.disk_peak[name] = max(self.disk_peak[name], folder_bytes(path))

    def listing(self, role: Callable[[dict], str | None], limit: int = 200) -> list[list]:
        """[role, peak MiB, command line (cut)] of each process seen, largest first."""
        rows = [[role(e), round(e["hwm_kib"] / 1024, 1), e["cmd"][:160]] for e in self.procs.values()]
        return sorted(rows, key=lambda r: -r[1])[:limit]

    def peaks(self, role: Callable[[dict], str | None]) -> dict[str, dict]:
        """{role: {"count", "at_once", "max_mib", "each_mib"}} of the processes `role` names (None: not
        shown); `at_once`: the most of them seen alive in one sample."""
        out: dict[str, dict] = {}
        roles = {key: role(entry) for key, entry in self.procs.items()}
        for key, entry in self.procs.items():
            name = roles[key]
            if name is None or not entry["hwm_kib"]:
                continue
            r = out.setdefault(name, {"count": 0, "at_once": 0, "max_mib": 0.0, "each_mib": []})
            r["count"] += 1
            r["each_mib"].append(round(entry["hwm_kib"] / 1024, 1))
            r["max_mib"] = max(r["max_mib"], entry["hwm_kib"] / 1024)
        for pids in self.alive:
            counts: dict[str, int] = {}
            for key in pids:
                if roles.get(key) in out:
                    counts[roles[key]] = counts.get(roles[key], 0) + 1
            for name, count in counts.items():
                out[name]["at_once"] = max(out[name]["at_once"], count)
        for r in out.values():
            r["max_mib"] = round(r["max_mib"], 1)
            r["each_mib"].sort(reverse=True)
        return out


def by_depth(*names: str) -> Callable[[dict], str | None]:
    """Role by depth in the tree: names[0] the root, names[1] its children, ...; deeper: the last name."""
    return lambda entry: names[min(entry["depth"], len(names) - 1)]


@dataclasses.dataclass
class Run:
    rc: int
    wall_s: float
    stdout: str
    stderr: str
    watch: TreeWatch
    cpu_s: float = 0.0  # CPU seconds of the process and the descendants it waited for


def run_watched(
    cmd: list[str],
    run_dir: Path,
    name: str,
    *,
    dirs: dict[str, Path] | None = None,
    env: dict | None = None,
    timeout: float | None = None,
    poll: Callable[[subprocess.Popen], None] | None = None,
) -> Run:
    """Runs `cmd` in its own session, watched; `poll(process)` is called every 0.05 s while it runs.
    Its CPU time is the rusage of the process and of every descendant it waited for (os.wait4)."""
    out, err = run_dir / f"{name}.stdout", run_dir / f"{name}.stderr"
    usage = None
    with open(out, "wb") as o, open(err, "wb") as e:
        started = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=o, stderr=e, env=env, cwd=REPO, start_new_session=True)
        watch = TreeWatch(proc.pid, dirs)
        try:
            while True:
                pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
                if pid:
                    proc.returncode = os.waitstatus_to_exitcode(status)
                    break
                if poll is not None:
                    poll(proc)
                if timeout is not None and time.perf_counter() - started > timeout:
                    os.killpg(proc.pid, signal.SIGKILL)
                time.sleep(0.05)
        except BaseException:
            if proc.returncode is None:
                os.killpg(proc.pid, signal.SIGKILL)
            raise
        finally:
            if proc.returncode is None:
                _, status, usage = os.wait4(proc.pid, 0)
                proc.returncode = os.waitstatus_to_exitcode(status)
            wall = time.perf_counter() - started
            watch.stop()
    cpu = usage.ru_utime + usage.ru_stime if usage is not None else 0.0
    return Run(proc.returncode, wall, out.read_text(errors="replace"), err.read_text(errors="replace"), watch, cpu)


_TIMING = re.compile(r"(^|_)(elapsed|seconds|wall|timing|timings|duration|started|finished)(_|$)|(_s|_at)$")


def _strip_timing(value):
    if isinstance(value, dict):
        return {k: _strip_timing(v) for k, v in value.items() if not _TIMING.search(k)}
    if isinstance(value, list):
        return [_strip_timing(v) for v in value]
    return value


def _sha(value) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, allow_nan=True).encode()).hexdigest()[:16]


def digest_result(path: Path, layout: Layout, pool_size: int) -> dict:
    """Digests of a result document's parts (timing fields aside), and whether the copies of each base
    scene scored alike."""
    doc = _strip_timing(json.loads(path.read_text()))
    rows = doc.get("scenarios", [])
    index = {scenario_id(i, layout.seed): i for i in range(layout.scenes)}
    per_base: dict[int, set] = {}
    first_of_base: dict[int, dict] = {}
    for row in rows:
        i = index.get(row.get("scenario_id"))
        if i is None:
            continue
        body = {k: v for k, v in row.items() if k != "scenario_id"}
        per_base.setdefault(i % pool_size, set()).add(_sha(body))
        first_of_base.setdefault(i % pool_size, row)
    # "per_object" names a side file (score --per-object): not a score, so the paths compare without it
    rest = {k: v for k, v in doc.items() if k not in ("scenarios", "buckets", "aggregate", "per_object")}
    return {
        "rows": _sha(rows),
        "buckets": _sha(doc.get("buckets")),
        "aggregate": _sha(doc.get("aggregate")),
        "rest": _sha(rest),
        "num_scenarios": len(rows),
        "metametric": (doc.get("aggregate") or {}).get("metametric"),
        "copies_alike": all(len(s) == 1 for s in per_base.values()) and len(per_base) == pool_size,
        "base_metametric": {b: first_of_base[b].get("metametric") for b in sorted(first_of_base)},
    }


def same_as(reference: dict | None, digest: dict | None) -> str:
    if reference is None or digest is None:
        return "-"
    parts = [p for p in ("rows", "buckets", "aggregate", "rest") if reference[p] != digest[p]]
    return "yes" if not parts else "NO: " + ",".join(parts)
