"""`features.float32_explog`: the official CPU kernels' `log` and `exp`, bit for bit.

Against the official arithmetic's answers (`tests/data/oracle_arithmetic`): tensors of 1 to 333 values
(Eigen's packets, then the C library on the trailing values) and lone scalars with special values.
Against this machine's C library itself: glibc's `logf` and `expf` on 200,000 random values each
(glibc 2.28 and later compute them with the algorithms reproduced; skips elsewhere).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import platform

import numpy as np
import pytest

from support import oracle_arithmetic as oracle
from wosac_eval.features.float32_explog import libm_expf, libm_logf, row_exp32, tensor_exp32, tensor_log32
from wosac_eval.features.float32_sums import PACKET

F = np.float32


@pytest.mark.parametrize("key", oracle.keys("log"))
def test_log_of_a_tensor_is_the_official(key):
    c = oracle.case("log", key)
    oracle.assert_bits_equal(tensor_log32(c["in"]), c["out"], f"log of {key} values")


@pytest.mark.parametrize("key", oracle.keys("exp"))
def test_exp_of_a_tensor_is_the_official(key):
    c = oracle.case("exp", key)
    oracle.assert_bits_equal(tensor_exp32(c["in"]), c["out"], f"exp of {key} values")


def test_lone_scalars_are_the_c_librarys():
    for kind, function in (("logf", libm_logf), ("expf", libm_expf)):
        c = oracle.case(kind, "scalars")
        oracle.assert_bits_equal(function(c["in"]), c["out"], kind)
        # A 0-d tensor is all trailing values: the library too.
        for value, want in zip(c["in"][:50], c["out"][:50]):
            oracle.assert_bits_equal(
                (tensor_log32 if kind == "logf" else tensor_exp32)(value), want, f"{kind}({value})"
            )


def test_padding_past_the_official_tensor_changes_no_value():
    c = oracle.case("log", "41")
    padded = np.concatenate([c["in"], np.full(23, 7.5, F)])
    oracle.assert_bits_equal(tensor_log32(padded, 41)[:41], c["out"], "log of 41 values padded to 64")


def test_a_rows_packets_and_tail_are_its_own():
    """`row_exp32`: each row of 13 values has one packet and 5 trailing values, wherever it lies."""
    rng = np.random.default_rng(3)
    rows = rng.uniform(-20, 0, (6, 13)).astype(F)
    got = row_exp32(rows)
    for row, values in zip(rows, got):
        oracle.assert_bits_equal(values[:PACKET], tensor_exp32(row[:PACKET]), "packet")
        oracle.assert_bits_equal(values[PACKET:], libm_expf(row[PACKET:]), "trailing values")


def _glibc():
    name, version = platform.libc_ver()
    if name != "glibc" or tuple(int(p) for p in version.split(".")[:2]) < (2, 28):
        pytest.skip(
            f"the C library is {name or 'unknown'} {version}: the algorithms reproduced are glibc 2.28's and later"
        )
    library = ctypes.CDLL(ctypes.util.find_library("m"))
    for name in ("logf", "expf"):
        getattr(library, name).restype = ctypes.c_float
        getattr(library, name).argtypes = [ctypes.c_float]
    return library


def test_log_and_exp_are_this_machines_glibc_bit_for_bit():
    library = _glibc()
    rng = np.random.default_rng(7)
    # Normal operands and results (TensorFlow's flush-to-zero of the others: the oracle cases check it).
    logs = np.concatenate([rng.uniform(0, 3000, 100_000), np.exp2(rng.uniform(-126, 127, 100_000)), [1.0, 2.0]])
    logs = logs[logs >= np.finfo(F).tiny].astype(F)
    exps = np.concatenate([rng.uniform(-87.3, 88.7, 150_000), rng.uniform(-1, 1, 50_000)]).astype(F)
    for values, ours, theirs in ((logs, libm_logf, library.logf), (exps, libm_expf, library.expf)):
        want = np.array([theirs(float(v)) for v in values], F)
        oracle.assert_bits_equal(ours(values), want, theirs.__name__)
    # What a correctly rounded logf would give instead: about 1% differ between 0.5 and 2 (where the
    # official sums of exponentials lie), so the library's own is needed.
    near_one = rng.uniform(0.5, 2, 100_000).astype(F)
    assert np.mean(np.log(near_one.astype(np.float64)).astype(F) != libm_logf(near_one)) > 0.005
