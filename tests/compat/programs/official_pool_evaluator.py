"""An evaluation pool written for the official waymo-open-dataset package, as training codebases run theirs: the
scenarios are scored in worker processes started by multiprocessing's spawn or forkserver method
(`official_pool_worker.score_files`, unchanged). The one line added, the opt-in, sits under the main guard,
which those workers do not run: they serve the official names from the environment the opt-in sets.

    python official_pool_evaluator.py spawn|forkserver SCENARIO.binproto:ROLLOUTS.binproto ...
    python official_pool_evaluator.py spawn|forkserver --where N

Prints a last line `RESULT <json>`: each scenario's metrics and the worker that scored it (with --where, what N
tasks' workers imported, without scoring).
"""

import json
import multiprocessing
import sys

if __name__ == "__main__":
    import wosac_eval.compat.official_names  # noqa: F401  (the one line added to the official program)

    from official_pool_worker import score_files, where_served

    method = sys.argv[1]
    if sys.argv[2] == "--where":
        task, items = where_served, list(range(int(sys.argv[3])))
    else:
        task, items = score_files, [tuple(arg.split(":")) for arg in sys.argv[2:]]
    with multiprocessing.get_context(method).Pool(2) as pool:
        scored = pool.map(task, items, chunksize=1)
    print("RESULT " + json.dumps(scored))
