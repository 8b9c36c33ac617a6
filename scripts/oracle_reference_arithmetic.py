"""Run an oracle script of ../shared/oracle with the official box corners' reference arithmetic.

    ~/.wosac-oracle/bin/python scripts/oracle_reference_arithmetic.py SCRIPT [ARGS...]

Runs in the oracle venv (TensorFlow; never imported by the project or its CI).
The official box corners come from TensorFlow's batched product of rotation
matrices and corner offsets, whose rounding depends on the CPU: where oneDNN is
on (the machines that made the reference outputs in ../shared/golden), each
coordinate is one product plus one fused multiply-add, fma(a1, b1, a0 * b0), and
the third term adds an exact zero; where TensorFlow leaves oneDNN off (e.g. AMD
CPUs without AVX-512), every operation is rounded and about 1 corner in 5000
differs in the last bit. This wrapper evaluates that product the reference way
(the fused step in float64, then rounded: what `ops.fma32` does), so
golden cases made on any machine agree with the reference outputs. Checked:
the cases of ../shared/golden and ../shared/golden/scenario_gen are reproduced
bit for bit.
"""
import os
import runpy
import sys

os.environ["TF_ENABLE_ONEDNN_OPTS"] = "0"  # the rest of TensorFlow as on every machine

import tensorflow as tf  # noqa: E402

_einsum = tf.einsum
_BOX_CORNER_PRODUCT = "nij,nkj->nki"  # rotations (n, 3, 3) applied to corner offsets (n, 8, 3)


def _reference_product(rotation, offsets):
    a = tf.cast(rotation, tf.float64)[:, None, :, :]  # (n, 1, i, j)
    b = tf.cast(offsets, tf.float64)[:, :, None, :]   # (n, k, 1, j)
    acc = tf.cast(a[..., 0] * b[..., 0], tf.float32)
    for j in (1, 2):  # acc + a_j * b_j, rounded once
        acc = tf.cast(tf.cast(acc, tf.float64) + a[..., j] * b[..., j], tf.float32)
    return acc


def einsum(equation, *operands, **kwargs):
    if equation == _BOX_CORNER_PRODUCT and len(operands) == 2:
        return _reference_product(*operands)
    return _einsum(equation, *operands, **kwargs)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    tf.einsum = einsum
    sys.argv = sys.argv[1:]
    runpy.run_path(sys.argv[0], run_name="__main__")
