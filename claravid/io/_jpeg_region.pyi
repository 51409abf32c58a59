# The libjpeg window decoder of _jpeg_region.c, for type checkers (optional, built at install).
# numpy arrays are buffers too (numpy's own stubs say so from Python 3.12 on).
import numpy as np
from typing_extensions import Buffer

LIBJPEG_TURBO_VERSION: int

class UnsupportedError(ValueError):
    """CMYK, 12-bit, lossless and similar files, which the caller decodes another way."""

def decode_window(
    data: Buffer | np.ndarray, x: int, y: int, w: int, h: int, out: Buffer | np.ndarray,
    margin_x: int = 1, margin_y: int = 1,
) -> None:  # fmt: skip
    """Decode the ``w``×``h`` window at (x, y) of the JPEG bytes ``data`` into ``out`` (uint8,
    C-contiguous, shape (h, w, 3), RGB)."""
