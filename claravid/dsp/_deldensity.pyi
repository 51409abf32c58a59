# The C histogram of _deldensity.c, for type checkers (the module is optional, built at install).
# numpy arrays are buffers too (numpy's own stubs say so from Python 3.12 on).
import numpy as np
from typing_extensions import Buffer

def count(
    gx: Buffer | np.ndarray, gy: Buffer | np.ndarray, lut: Buffer | np.ndarray,
    out: Buffer | np.ndarray, /,
) -> None:  # fmt: skip
    """Add the bins (``lut``, uint16) of the (gx, gy) int16 gradient pairs into ``out`` (512×512
    uint32)."""
