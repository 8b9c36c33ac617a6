"""The one-line opt-in: programs written for the official package run on wosac-eval with their imports unchanged.

    import wosac_eval.compat.official_names  # first, before the program imports waymo_open_dataset
    from waymo_open_dataset.wdl_limited.sim_agents_metrics import metrics  # is wosac_eval.compat.metrics
    from waymo_open_dataset.protos import scenario_pb2  # is wosac_eval.protos.scenario_pb2

or, with no line changed at all: `WOSAC_EVAL_OFFICIAL_NAMES=1 python program.py`.

Importing this module serves the official names in this process and in every process it starts
(`official_finder.install`: what is served, worker processes, and the rule when the official package is
installed too: it raises `OfficialPackageFound` rather than shadow it).
"""

from __future__ import annotations

from wosac_eval.compat.official_finder import (  # noqa: F401  (the names a program may want beside the opt-in)
    ENVIRONMENT,
    SERVED,
    OfficialPackageFound,
    install,
    installed,
    uninstall,
)

install()
