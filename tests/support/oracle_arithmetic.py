"""The official arithmetic's answers on small inputs (tests/data/oracle_arithmetic/cases.npz).

Written by `scripts/oracle_arithmetic_cases.py` with TensorFlow 2.13 and waymo-open-dataset 1.6.7 (the
oracle venv): inputs and what the official kernels returned for them, so that the tests check the
float32 arithmetic after the features bit for bit without TensorFlow. In the repository: checked on
every test run, with or without ../shared.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from support.paths import TEST_DATA

CASES = TEST_DATA / "oracle_arithmetic" / "cases.npz"


@lru_cache(maxsize=1)
def cases() -> dict:
    with np.load(CASES) as data:
        return {name: data[name] for name in data.files}


def keys(kind: str) -> list[str]:
    """The case names of a kind (`log`, `sum`, `histogram`, ...): the middle part of `kind/<name>/<field>`."""
    return sorted({name.split("/")[1] for name in cases() if name.startswith(kind + "/")})


def case(kind: str, key: str) -> dict:
    """One case's arrays by field."""
    prefix = f"{kind}/{key}/"
    return {name[len(prefix) :]: value for name, value in cases().items() if name.startswith(prefix)}


def assert_bits_equal(actual, expected, where: str) -> None:
    """Equal float32 bit patterns (NaN for NaN, -0 for -0)."""
    actual = np.asarray(actual, np.float32)
    expected = np.asarray(expected, np.float32)
    assert actual.shape == expected.shape, (where, actual.shape, expected.shape)
    np.testing.assert_array_equal(actual.view(np.int32), expected.view(np.int32), err_msg=where)
