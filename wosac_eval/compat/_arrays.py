"""Arrays for the compat modules: numpy arrays that also answer `.numpy()`, as the official tensors do.

Client programs of the official modules often end a computation with
`tensor.numpy()` (e.g. `getattr(features, name).numpy()`); the compat modules
hand out `CompatArray`s, plain numpy arrays in every other respect, so that
such code runs unchanged. (A single element, `array[i]`, is a numpy scalar,
which has no `.numpy()`.)
"""

from __future__ import annotations

import numpy as np


class CompatArray(np.ndarray):
    """A numpy array with the `.numpy()` of a TensorFlow eager tensor."""

    def numpy(self) -> np.ndarray:
        """A copy as a plain `numpy.ndarray`."""
        return np.array(self.view(np.ndarray), copy=True)


def compat_array(value, dtype=None) -> CompatArray:
    """`value` (array-like) as a `CompatArray`, of `dtype` when given."""
    return np.asarray(value, dtype=dtype).view(CompatArray)
