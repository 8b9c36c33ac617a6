"""The wheel (`pip wheel .`, as CI builds it) carries the official layout and the official names' startup hook:
every config once at its official relative path under the compat root, the .pth into site-packages. Installed
from that wheel alone, an evaluation pool's spawn workers serve the official names (the tests' own installation,
editable here and a wheel in CI, runs the same pools in `official_program_test.py`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import zipfile

import pytest

from support.paths import REPO
from wosac_eval.compat import official_finder

PTH = "wosac_eval_official_names.pth"


def build_wheel(out) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(REPO)],
        cwd=out,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return str(next(out.glob("wosac_eval-*.whl")))


def fresh_environment(folder, wheel: str):
    """A fresh environment with the wheel installed, its dependencies read from this one's site-packages."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(folder)], check=True)
    python = folder / "bin" / "python"
    site = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], capture_output=True, text=True
    ).stdout.strip()
    install = [sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", site, wheel]
    assert subprocess.run(install, capture_output=True, timeout=600).returncode == 0
    with open(os.path.join(site, "dependencies.pth"), "w") as f:
        f.write(sysconfig.get_path("purelib") + "\n")
    return python, site


@pytest.mark.ci  # builds the wheel (10-30 s) and starts a pool from a fresh installation: the CI tier's
def test_the_wheel_carries_the_layout_and_its_installation_serves_spawn_workers(tmp_path):
    wheel = build_wheel(tmp_path)
    names = zipfile.ZipFile(wheel).namelist()
    textprotos = sorted(n for n in names if n.endswith(".textproto"))
    assert textprotos == [
        "wosac_eval/compat/utils/sim_agents/testdata/test_config.textproto",
        "wosac_eval/compat/utils/sim_agents/testdata/test_config_dependent_timesteps.textproto",
        "wosac_eval/compat/wdl_limited/sim_agents_metrics/challenge_2024_config.textproto",
        "wosac_eval/compat/wdl_limited/sim_agents_metrics/challenge_2025_scenario_gen_config.textproto",
        "wosac_eval/compat/wdl_limited/sim_agents_metrics/challenge_2025_sim_agents_config.textproto",
        "wosac_eval/compat/wdl_limited/sim_agents_metrics/legacy_configs/challenge_2023_config.textproto",
    ]
    hooks = [n for n in names if n.endswith(".pth")]
    assert len(hooks) == 1 and hooks[0].endswith(f".data/purelib/{PTH}")  # installed into site-packages

    python, site = fresh_environment(tmp_path / "env", wheel)
    assert os.path.isfile(os.path.join(site, PTH))
    program = REPO / "tests" / "compat" / "programs" / "official_pool_evaluator.py"
    env = {k: v for k, v in os.environ.items() if k not in (official_finder.ENVIRONMENT, "PYTHONPATH")}
    done = subprocess.run(
        [str(python), str(program), "spawn", "--where", "4"],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    seen = json.loads(done.stdout.strip().splitlines()[-1][len("RESULT ") :])
    assert [(s["config"], s["metrics_module"]) for s in seen] == [(True, "wosac_eval.compat.metrics")] * 4
    where = subprocess.run(
        [str(python), "-c", "import wosac_eval; print(wosac_eval.__file__)"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    ).stdout.strip()
    assert where.startswith(site)  # the wheel's copy, not this tree
