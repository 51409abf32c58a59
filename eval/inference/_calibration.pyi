# The C pass of _calibration.c, for type checkers (the module is optional, built at install).
# numpy arrays are buffers too (numpy's own stubs say so from Python 3.12 on).
import numpy as np
from typing_extensions import Buffer

def sums(
    conf: Buffer | np.ndarray, pred: Buffer | np.ndarray, truth: Buffer | np.ndarray,
    edges: Buffer | np.ndarray, lut: Buffer | np.ndarray, count: Buffer | np.ndarray,
    conf_sum: Buffer | np.ndarray, correct: Buffer | np.ndarray, /,
) -> None:  # fmt: skip
    """Add one image's pixels to the per-bin ``count``, ``conf_sum`` and ``correct`` (in place);
    ValueError for a confidence outside [0, 1]."""
