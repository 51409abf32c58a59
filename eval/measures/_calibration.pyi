# The C pass of _calibration.c, for type checkers (the module is optional, built at install).
# numpy arrays are buffers too (numpy's own stubs say so from Python 3.12 on).
import numpy as np
from typing_extensions import Buffer

def exact_sums(
    conf: Buffer | np.ndarray, pred: Buffer | np.ndarray, truth: Buffer | np.ndarray,
    edges: Buffer | np.ndarray, lut: Buffer | np.ndarray, count: Buffer | np.ndarray,
    correct: Buffer | np.ndarray, fixed: Buffer | np.ndarray, small: Buffer | np.ndarray,
    vector: bool = True, /,
) -> None:  # fmt: skip
    """Add one image's pixels to the per-bin ``count``, ``correct``, ``fixed`` (sums of
    ``x · 2^30`` for x >= 2^-7) and ``small`` ([bins, 256]: significand sums of smaller x by
    binary exponent), in place; ``vector`` allows eight pixels at a time where the CPU has AVX2.
    ValueError for a confidence outside [0, 1]."""
