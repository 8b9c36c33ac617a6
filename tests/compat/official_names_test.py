"""The one-line opt-in (`import wosac_eval.compat.official_names`) and its environment variable: the official
package's names resolve to wosac-eval, other official modules are refused by name, and an installed official
package is never shadowed. Each check runs in a fresh interpreter (the installed package, outside the
repository), as a program does."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from wosac_eval.compat import official_finder

OPT_IN = "import wosac_eval.compat.official_names\n"


def run_python(code: str, cwd, env: dict | None = None) -> subprocess.CompletedProcess:
    environment = {k: v for k, v in os.environ.items() if k != official_finder.ENVIRONMENT}
    environment.update(env or {})
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=cwd,
        env=environment,
        capture_output=True,
        text=True,
        timeout=300,
    )


def result_of(done: subprocess.CompletedProcess):
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


SERVED_CHECK = """
import importlib, json, os, sys
import waymo_open_dataset
from waymo_open_dataset.wdl_limited.sim_agents_metrics import metrics
from waymo_open_dataset.protos import scenario_pb2, map_pb2, sim_agents_metrics_pb2, sim_agents_submission_pb2
from wosac_eval.compat.official_finder import SERVED
same = {name: importlib.import_module("waymo_open_dataset." + name) is importlib.import_module(target)
        for name, target in SERVED.items()}
root = waymo_open_dataset.__path__[0]
configs = ["wdl_limited/sim_agents_metrics/challenge_2025_sim_agents_config.textproto",
           "wdl_limited/sim_agents_metrics/challenge_2024_config.textproto",
           "wdl_limited/sim_agents_metrics/challenge_2025_scenario_gen_config.textproto",
           "wdl_limited/sim_agents_metrics/legacy_configs/challenge_2023_config.textproto",
           "utils/sim_agents/testdata/test_config.textproto"]
refused = {}
for statement in ("import waymo_open_dataset.v2", "from waymo_open_dataset.utils import box_utils",
                  "from waymo_open_dataset.protos import dataset_pb2", "import waymo_open_dataset.metrics.python"):
    try:
        exec(statement)
        refused[statement] = None
    except ModuleNotFoundError as error:
        refused[statement] = str(error)
print(json.dumps({
    "same": same,
    "metrics_module": metrics.__name__,
    "scenario": scenario_pb2.Scenario.DESCRIPTOR.full_name,
    "root": root,
    "file": waymo_open_dataset.__file__,
    "configs": [os.path.isfile(os.path.join(root, c)) for c in configs],
    "refused": refused,
    "environment": os.environ.get("WOSAC_EVAL_OFFICIAL_NAMES"),
}))
"""


@pytest.mark.parametrize("opt_in", ["import", "environment"])
def test_the_official_names_resolve_to_wosac_eval(opt_in, tmp_path):
    code = OPT_IN + SERVED_CHECK if opt_in == "import" else SERVED_CHECK
    env = {official_finder.ENVIRONMENT: "1"} if opt_in == "environment" else {}
    out = result_of(run_python(code, tmp_path, env))
    assert out["same"] and all(out["same"].values()), out["same"]
    assert len(out["same"]) == len(official_finder.SERVED) >= 16
    assert out["metrics_module"] == "wosac_eval.compat.metrics"
    assert out["scenario"].endswith("Scenario")
    assert out["configs"] == [True] * 5  # the official relative paths under the package root
    assert out["file"] is None  # as the official namespace package
    for statement, message in out["refused"].items():
        assert message is not None, statement
        name = message.split("'")[1]
        assert name.startswith("waymo_open_dataset.") and "does not serve it" in message, message
    assert out["environment"] == "1"  # processes started from here serve the names too


def test_the_opt_in_is_undone_by_uninstall(tmp_path):
    code = OPT_IN + textwrap.dedent(
        """
        import json, os, sys
        import waymo_open_dataset.wdl_limited.sim_agents_metrics.metrics
        from wosac_eval.compat import official_names
        official_names.uninstall()
        try:
            import waymo_open_dataset
            found = True
        except ModuleNotFoundError:
            found = False
        print(json.dumps({"found": found, "installed": official_names.installed(),
                          "environment": os.environ.get("WOSAC_EVAL_OFFICIAL_NAMES")}))
        """
    )
    assert result_of(run_python(code, tmp_path)) == {"found": False, "installed": False, "environment": None}


def test_without_the_opt_in_nothing_is_served(tmp_path):
    done = run_python("import waymo_open_dataset", tmp_path)
    assert done.returncode != 0 and "No module named 'waymo_open_dataset'" in done.stderr


def _official_package(folder) -> None:
    """A stand-in for an installed official package: a package named waymo_open_dataset holding modules."""
    package = folder / "waymo_open_dataset"
    (package / "protos").mkdir(parents=True)
    (package / "dataset_pb2.py").write_text("")
    (package / "protos" / "scenario_pb2.py").write_text("")


def test_an_installed_official_package_is_never_shadowed(tmp_path):
    _official_package(tmp_path / "site")
    env = {"PYTHONPATH": str(tmp_path / "site")}
    done = run_python(OPT_IN, tmp_path, env)
    assert done.returncode != 0
    assert "OfficialPackageFound" in done.stderr and str(tmp_path / "site" / "waymo_open_dataset") in done.stderr
    assert "does not shadow it" in done.stderr
    # Opted in by the environment (a worker's start cannot refuse): its first import of the package refuses.
    done = run_python(
        "import waymo_open_dataset.protos.scenario_pb2", tmp_path, {**env, official_finder.ENVIRONMENT: "1"}
    )
    assert done.returncode != 0 and "OfficialPackageFound" in done.stderr and "does not shadow it" in done.stderr
    # Without any opt-in, the official package is the official package.
    assert run_python("import waymo_open_dataset.dataset_pb2", tmp_path, env).returncode == 0


def test_a_folder_of_official_test_data_is_not_the_official_package(tmp_path):
    # The official test helpers read waymo_open_dataset/utils/sim_agents/testdata/ relative to the working folder.
    data = tmp_path / "waymo_open_dataset" / "utils" / "sim_agents" / "testdata"
    data.mkdir(parents=True)
    (data / "test_submission.binproto").write_bytes(b"")
    code = OPT_IN + "from waymo_open_dataset.utils.sim_agents import test_utils; print(test_utils.__name__)"
    done = run_python(code, tmp_path, {"PYTHONPATH": str(tmp_path)})
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "wosac_eval.compat.test_utils"
