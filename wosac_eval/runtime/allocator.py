"""Allocator setting for scoring processes: keep freed memory for reuse.

The feature kernels create and drop numpy temporaries of a few hundred KiB to
a few MiB thousands of times per scenario. glibc serves blocks above its
mmap threshold (128 KiB at first) with fresh pages and hands freed memory at
the top of the heap back to the system, so each reuse pays page faults: about
a quarter of the scoring time. Raising both thresholds keeps that memory in
the process (the peak RSS is unchanged; it is simply not returned between
scenarios). Scoring entry points (`score_submission`, the CLI, the service
workers) apply it; set WOSAC_EVAL_SYSTEM_MALLOC=1 to leave malloc untouched.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20  # glibc's largest allowed value on 64-bit systems
TRIM_THRESHOLD = 256 << 20
_applied = False


def keep_freed_memory() -> bool:
    """Raises glibc's mmap and trim thresholds for this process (and the processes it forks).

    Returns True when the setting is in effect, False on other C libraries or
    when opted out with WOSAC_EVAL_SYSTEM_MALLOC=1.
    """
    global _applied
    if _applied:
        return True
    if os.environ.get("WOSAC_EVAL_SYSTEM_MALLOC") == "1" or not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    _applied = bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))
    return _applied
