"""Every compiled loop that scoring and validating run, compiled ahead of the first scenario.

numba compiles a loop on its first call, once per installation (about half a minute for all of them),
and caches it on disk; a process that should not pay that in its first scenario (a Docker image while
it is built, a service before it takes jobs, a pool before its workers start) calls `compile_loops`
first. The loops live in three rooms below this one: the protobuf wire walks (`parse.wire_walks`), the
feature searches (`features.search.compile_searches`) and the criticality's pair loop
(`analysis.criticality_features`, scoring's default analysis).
"""

from __future__ import annotations

import time

from wosac_eval.analysis import criticality_features
from wosac_eval.features.search import compile_searches
from wosac_eval.parse import wire_walks


def compile_loops() -> float:
    """Compiles the wire walks, the search loops and the criticality's loop now (or loads them from
    numba's cache); returns the seconds it took."""
    start = time.perf_counter()
    wire_walks.compile_walks()
    compile_searches()
    criticality_features.compile_loops()
    return time.perf_counter() - start
