"""RGB photos, whole or a window of them, with the same pixels whichever path decodes them.

A 630×630 training crop is about 3 % of a 4032×3024 ClaraVid frame. With the optional C module
``claravid.io._jpeg_region`` (built at install when a C compiler and the libjpeg headers are there),
a window of a sequential (baseline) JPEG is decoded by libjpeg-turbo alone: the compressed data
is still read in order up to the window's last row, but the inverse DCT, chroma upsampling and
colour conversion run only for the blocks around the window, and nothing below it is touched.
About 8× as fast as a full OpenCV decode plus crop for a 630×630 window of a 4032×3024 frame
(``benchmarks/bench_jpeg_region.py``).

The promise: a window's pixels are those of ``cv2.imread`` (EXIF orientation ignored: pixels as
stored) over the window, for every file the readers accept. Which path gives them:

- sequential JPEG (SOF0/SOF1, 8-bit, grey/YCbCr/RGB): the C module, windows and whole frames
  alike; it also refuses data that ends early (libjpeg alone paints the missing rows grey);
- progressive JPEG: a full decode by OpenCV, sliced. Block smoothing of an incomplete
  progressive file (legal: its last scans missing) reads two blocks around each block, and
  OpenCV's libjpeg-turbo 3 smooths differently from the system's 2.1; a window could not equal
  it. The C module first reads every scan (no pixels), so that data that ends inside a scan is
  refused as for a sequential file;
- lossless JPEG, CMYK/YCCK JPEG, PNG, TIFF, WebP: a full decode by OpenCV, sliced.

Without the C module everything is decoded whole by OpenCV (same pixels, no speed-up; a JPEG
whose header promises rows its data lacks then comes back with grey rows, as OpenCV gives them).
Tell the user once which path runs with :func:`decoder`.

A photo is read from disk once (:func:`open_photo`) and its header parsed once: its size
(``photo.size``, for drawing a crop) and then its window (``photo.window(x, y, w, h)``)::

    photo = open_photo(path)
    x, y = rng.integers(photo.width - 630 + 1), rng.integers(photo.height - 630 + 1)
    rgb = photo.window(x, y, 630, 630)
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from claravid.infra.errors import CorruptFileError
from claravid.io.headers import BufferStream, ImageHeader, file_header, parse_jpeg
from claravid.io.imagefile import decode_bytes, load

try:  # the optional libjpeg window decoder (built at install when a compiler is there)
    from claravid.io import _jpeg_region as _native
except ImportError:  # pragma: no cover - depends on the build
    _native = None  # type: ignore[assignment]  # mypy types a module name as never None

#: How many times as fast a 630×630 window of a 4032×3024 4:2:0 JPEG comes from the C module as
#: from OpenCV's full decode plus crop (``benchmarks/bench_jpeg_region.py``, docs/data.md).
WINDOW_SPEEDUP = 8
REGION_DECODE = "libjpeg region decode"
FULL_DECODE = (
    f"full decode (C extension not built): a 630×630 crop of a 4032×3024 JPEG takes about "
    f"{WINDOW_SPEEDUP}× as long; install a C compiler and libjpeg-dev, then reinstall"
)

# OpenCV >= 4.10 decodes straight to RGB order, saving a full-frame channel swap.
_IMREAD_RGB = getattr(cv2, "IMREAD_COLOR_RGB", None)


def decoder() -> str:
    """Which path :func:`read_rgb_window` takes for JPEG files, to be said once per run (on the
    slow path with how much slower a training crop is, and what to install)."""
    return REGION_DECODE if _native is not None else FULL_DECODE


def _opencv_rgb(data: np.ndarray, path: Path, header: ImageHeader | None) -> np.ndarray:
    """uint8 H×W×3 in RGB order from OpenCV, like PIL's ``Image.open(p).convert('RGB')``."""
    if header is not None and header.lossless and header.components == 1:
        # libjpeg converts no colours in lossless mode: OpenCV reads such a file as grey only.
        grey = decode_bytes(data, path, cv2.IMREAD_GRAYSCALE, checked=True)
        return cv2.cvtColor(grey, cv2.COLOR_GRAY2RGB)  # as libjpeg expands a baseline grey one
    if _IMREAD_RGB is not None:
        return decode_bytes(data, path, _IMREAD_RGB, checked=True)
    return cv2.cvtColor(decode_bytes(data, path, cv2.IMREAD_COLOR, checked=True), cv2.COLOR_BGR2RGB)


def _outside(path: Path, x: int, y: int, width: int, height: int, frame: tuple[int, int]) -> str:
    return (
        f"window {width}×{height} at ({x}, {y}) does not fit in the {frame[0]}×{frame[1]} frame "
        f"of {path}; pad frames smaller than the crop before cropping"
    )


def _check_window(x: int, y: int, width: int, height: int) -> tuple[int, int, int, int]:
    for name, value in (("x", x), ("y", y), ("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise TypeError(f"{name} must be an integer, got {value!r}")
    if x < 0 or y < 0 or width < 1 or height < 1:
        raise ValueError(f"window {width}×{height} at ({x}, {y}): need x, y >= 0, sizes >= 1")
    return int(x), int(y), int(width), int(height)


class Photo:
    """An RGB photo's bytes, read once, and its header, parsed once: its size, then any window
    of it or the whole frame. Made by :func:`open_photo`.

    Attributes:
        path: the file.
        header: its PNG or JPEG header; None for other formats (decoded whole to learn the size).
    """

    def __init__(self, path: Path, data: np.ndarray, header: ImageHeader | None) -> None:
        self.path = path
        self.header = header
        self._data = data
        self._full: np.ndarray | None = None

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)``, from the header (other formats: from a full decode, kept)."""
        if self.header is not None:
            return self.header.size
        full = self.full()
        return full.shape[1], full.shape[0]

    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    def _by_window(self) -> bool:
        """Whether the C module decodes this file by window (see the module's docstring)."""
        header = self.header
        return (
            _native is not None
            and header is not None
            and header.format == "jpeg"
            and header.sequential
            and header.components in (1, 3)
        )

    def _native_window(self, x: int, y: int, width: int, height: int) -> np.ndarray | None:
        """The window from the C module; None when it does not handle the file (then OpenCV
        decodes it whole)."""
        assert _native is not None
        out = np.empty((height, width, 3), np.uint8)
        try:
            _native.decode_window(self._data, x, y, width, height, out)
        except _native.UnsupportedError:  # a colour space libjpeg does not convert to RGB
            return None
        except ValueError as error:
            raise CorruptFileError(self.path, f"libjpeg: {error}") from None
        return out

    def full(self) -> np.ndarray:
        """The whole frame: uint8 H×W×3, RGB order, pixels as stored (no EXIF rotation); decoded
        once and kept (the photo is short-lived: one sample)."""
        if self._full is not None:
            return self._full
        full = None
        if self._by_window():
            # _by_window() needs a header.
            full = self._native_window(0, 0, *self.header.size)  # type: ignore[union-attr]
        elif _native is not None and self.header is not None and self.header.progressive:
            # Decoding one pixel makes libjpeg read every scan first: refuses data that ends
            # inside a scan (an incomplete but legal file ends between scans).
            self._native_window(0, 0, 1, 1)
        if full is None:
            full = _opencv_rgb(self._data, self.path, self.header)
        self._full = full
        return full

    def window(self, x: int, y: int, width: int, height: int) -> np.ndarray:
        """``full()[y:y+height, x:x+width]``, decoded alone where the C module can.

        Raises:
            ValueError: the window does not lie inside the frame (it is never clipped).
            TypeError: a coordinate that is no integer.
        """
        x, y, width, height = _check_window(x, y, width, height)
        frame = self.size
        if x + width > frame[0] or y + height > frame[1]:
            raise ValueError(_outside(self.path, x, y, width, height, frame))
        if self._full is None and self._by_window():
            window = self._native_window(x, y, width, height)
            if window is not None:
                return window
        # A copy, so the caller does not keep the whole decoded frame alive through a view.
        return np.ascontiguousarray(self.full()[y : y + height, x : x + width])


def open_photo(path: str | Path) -> Photo:
    """Read a photo's bytes once and check them (see :func:`claravid.io.imagefile.check_bytes`).

    Raises:
        FileNotFoundError: naming the file, when it is missing.
        CorruptFileError: naming it, when it is empty, truncated, too short for its size or
            its header is corrupt.
        UnsupportedFileError: naming it, for images no reader decodes (12-bit or arithmetic
            JPEG, more than 2^30 pixels, no regular file).
    """
    path = Path(path)
    data, header = load(path)
    return Photo(path, data, header)


def read_rgb(path: str | Path) -> np.ndarray:
    """The RGB photo: uint8 H×W×3, RGB order, pixels as stored (see the module's docstring)."""
    return open_photo(path).full()


def read_rgb_window(path: str | Path, x: int, y: int, width: int, height: int) -> np.ndarray:
    """The window of an RGB photo: ``read_rgb(path)[y:y+height, x:x+width]``, decoded alone.

    Args:
        path: the photo (sequential JPEG: window decode; others: full decode and slice).
        x: the window's left column.
        y: the window's top row.
        width: the window's width in pixels (>= 1).
        height: the window's height in pixels (>= 1).

    Returns:
        uint8 ``height×width×3`` array in RGB order, pixels as stored (no EXIF rotation).

    Raises:
        ValueError: the window does not lie inside the frame (it is never clipped).
        CorruptFileError: naming the file, when it is empty, truncated, or its data is corrupt.
        FileNotFoundError: naming the file, when it is missing.
    """
    _check_window(x, y, width, height)
    return open_photo(path).window(x, y, width, height)


def jpeg_size(source: str | Path | bytes | np.ndarray) -> tuple[int, int]:
    """A JPEG's (width, height) from its header, without decoding it.

    Args:
        source: a file path, or the file's bytes (``bytes`` or a uint8 array).

    Raises:
        CorruptFileError: naming the file, when it is no JPEG or its header is truncated.
        FileNotFoundError: naming the file, when it is missing.
    """
    if isinstance(source, (bytes, bytearray, memoryview, np.ndarray)):
        return parse_jpeg(BufferStream(source), "<bytes>", to_scan=False).size
    path = Path(source)
    header, _ = file_header(path)
    if header is None or header.format != "jpeg":
        raise CorruptFileError(path, "not a JPEG file (no start-of-image marker)")
    return header.size


def image_size(path: str | Path) -> tuple[int, int]:
    """A photo's (width, height): from the header for a JPEG or PNG (the header bytes alone),
    else by decoding it.

    Raises:
        FileNotFoundError, CorruptFileError, UnsupportedFileError: as :func:`open_photo`.
    """
    header, _ = file_header(path)
    if header is not None:
        return header.size
    return open_photo(path).size


__all__ = [
    "FULL_DECODE",
    "REGION_DECODE",
    "Photo",
    "decoder",
    "image_size",
    "jpeg_size",
    "open_photo",
    "read_rgb",
    "read_rgb_window",
]
