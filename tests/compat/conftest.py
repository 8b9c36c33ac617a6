"""What the official tests' cases need: the WOMD test scenario and the official test submission, found where the
official test helpers find them (the submission relative to the working folder)."""

from __future__ import annotations

import pytest

from support.paths import require_shared
from wosac_eval import read_scenarios


@pytest.fixture
def womd_test_scenario(shared):
    """The official tests' scenario (637f20cafde22ff8: 83 tracks), from the reference material."""
    require_shared("womd")
    return next(iter(read_scenarios(shared / "womd" / "motion_data_one_scenario.tfrecord")))


@pytest.fixture
def official_testdata(shared, tmp_path, monkeypatch):
    """A working folder holding the official test submission where the official `load_test_submission` opens it
    (`waymo_open_dataset/utils/sim_agents/testdata/`, relative to the working folder)."""
    require_shared("womd")
    folder = tmp_path / "waymo_open_dataset" / "utils" / "sim_agents" / "testdata"
    folder.mkdir(parents=True)
    (folder / "test_submission.binproto").symlink_to(shared / "womd" / "test_submission.binproto")
    monkeypatch.chdir(tmp_path)
    return tmp_path
