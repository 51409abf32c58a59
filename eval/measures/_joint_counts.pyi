# The C pass of _joint_counts.c, for type checkers (the module is optional, built at install).
# numpy arrays are buffers too (numpy's own stubs say so from Python 3.12 on).
import numpy as np
from typing_extensions import Buffer

def count(
    first: Buffer | np.ndarray, second: Buffer | np.ndarray, out: Buffer | np.ndarray,
    channels: int = 1, channel: int = 0, /,
) -> None:  # fmt: skip
    """Add the joint counts of two byte images to ``out`` (int64 [65536], index
    ``first << 8 | second``, in place); ``second`` may interleave two channels, of which
    ``channel`` counts. ValueError for sizes that do not match."""
