"""The limits of a job's scoring process, and what a job's failure says when that process ends without
an outcome (killed for memory, past its CPU time, or by a signal)."""

from __future__ import annotations

import os
import resource
import signal

from wosac_eval.runtime.processes import exit_with_parent, set_parent_death_signal

from .settings import Settings


def limit_this_process(settings: Settings, parent_pid: int) -> None:
    """The limits of a job's scoring process: death with its worker, address space, CPU time and a
    lower CPU priority than the API's (so scoring never starves /healthz and uploads)."""
    # A worker killed between its fork and the signal's set-up sends no signal: the job's process
    # would score on unsupervised and race the retry of its job; `exit_with_parent` sees that case.
    # Off Linux (no signal) a thread watches the worker instead.
    armed = set_parent_death_signal(signal.SIGKILL)
    exit_with_parent(parent_pid, watch=not armed)
    if settings.job_nice:
        os.nice(settings.job_nice)
    if settings.job_memory_bytes:
        # The soft limit (what the kernel enforces); the hard one stays, so that a protobuf parse
        # refused for memory can be told from damaged bytes (wosac_eval.parse.decode).
        hard = resource.getrlimit(resource.RLIMIT_AS)[1]
        soft = settings.job_memory_bytes if hard == resource.RLIM_INFINITY else min(settings.job_memory_bytes, hard)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    if settings.job_cpu_budget_s:
        soft = max(1, int(settings.job_cpu_budget_s))
        resource.setrlimit(resource.RLIMIT_CPU, (soft, soft + 5))  # SIGXCPU at soft, SIGKILL at hard


def why_child_ended(status: int, settings: Settings, peak_rss: int) -> str:
    """A job's failure reason from how its scoring process ended without recording an outcome."""
    used = f"peak memory {peak_rss / 2**20:.0f} MiB"
    if os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGXCPU:
        return (
            f"scoring used its CPU-time budget of {settings.job_cpu_budget_s:g} s (WOSAC_JOB_CPU_BUDGET_S) "
            f"and was stopped ({used})"
        )
    limit = (
        f"its memory limit is {settings.job_memory_bytes} bytes (WOSAC_JOB_MEMORY_BYTES)"
        if settings.job_memory_bytes
        else "it has no memory limit"
    )
    if os.WIFSIGNALED(status):
        name = signal.Signals(os.WTERMSIG(status)).name
        return f"the scoring process was ended by {name} ({used}; {limit}): most likely out of memory"
    return f"the scoring process exited with status {os.WEXITSTATUS(status)} without a result ({used}; {limit})"
