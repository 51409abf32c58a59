"""Read a window of an RGB photo without decoding the whole frame, same pixels as a full decode.

A 630×630 training crop is about 3 % of a 4032×3024 ClaraVid frame. With the optional C module
``claravid.io._jpeg_region`` (built at install when a C compiler and the libjpeg headers are there),
a JPEG window is decoded by libjpeg-turbo alone: the compressed data is still read in order up
to the window's last row, but the inverse DCT, chroma upsampling and colour conversion run only
for the blocks around the window, and nothing below it is touched. About 4× faster than a full
``cv2.imread`` of the frame (``benchmarks/bench_jpeg_region.py``).

The pixels are exactly those of :func:`claravid.io.modalities.read_rgb` (OpenCV, EXIF orientation
ignored: pixels as stored) over the window. Smooth chroma upsampling makes a pixel depend on its
neighbours' chroma, so the C module decodes one MCU more on every side and cuts it away; the
tests compare every sampling and encoder variant against full decodes.

Without the C module, and for files it does not handle (PNG, CMYK or 12-bit JPEG), the window is
cut from a full decode by :func:`claravid.io.modalities.read_rgb`: same values, no speed-up.
Tell the user once which path runs with :func:`decoder`.

Integration sketch for a dataset that crops::

    width, height = image_size(path)      # header only
    x, y = rng.integers(width - 630 + 1), rng.integers(height - 630 + 1)
    rgb = read_rgb_window(path, x, y, 630, 630)
"""

from __future__ import annotations

import io
import struct
from pathlib import Path
from typing import Protocol

import numpy as np

from claravid.infra.errors import CorruptFileError
from claravid.io.modalities import read_checked, read_rgb

try:  # the optional libjpeg window decoder (built at install when a compiler is there)
    from claravid.io import _jpeg_region as _native
except ImportError:  # pragma: no cover - depends on the build
    _native = None

REGION_DECODE = "libjpeg region decode"
FULL_DECODE = "full decode (C extension not built)"

_SOI = b"\xff\xd8"
# Start-of-frame markers carry the size; C4 (DHT), C8 (reserved) and CC (DAC) share the range.
_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# Markers without a length field: TEM and the restart markers.
_STANDALONE = frozenset({0x01, *range(0xD0, 0xD8)})
_SOS, _EOI = 0xDA, 0xD9


class _Stream(Protocol):
    def read(self, count: int, /) -> bytes: ...
    def seek(self, offset: int, whence: int, /) -> int: ...


class _BufferStream:
    """read/seek over bytes already in memory, without copying them into a BytesIO."""

    def __init__(self, data: bytes | np.ndarray) -> None:
        self._view = memoryview(data).cast("B")
        self._pos = 0

    def read(self, count: int, /) -> bytes:
        chunk = self._view[self._pos : self._pos + count].tobytes()
        self._pos += len(chunk)
        return chunk

    def seek(self, offset: int, whence: int, /) -> int:
        assert whence == io.SEEK_CUR
        self._pos = min(self._pos + offset, len(self._view))
        return self._pos


def decoder() -> str:
    """Which path :func:`read_rgb_window` takes for JPEG files, to be said once per run."""
    return REGION_DECODE if _native is not None else FULL_DECODE


def _read_exact(stream: _Stream, count: int, name: str) -> bytes:
    chunk = stream.read(count)
    if len(chunk) != count:
        raise CorruptFileError(name, "truncated JPEG header (the file ends before the frame size)")
    return chunk


def _sof_size(stream: _Stream, name: str) -> tuple[int, int]:
    """(width, height) from the first start-of-frame segment, reading only the header."""
    if stream.read(2) != _SOI:
        raise CorruptFileError(name, "not a JPEG file (no start-of-image marker)")
    while True:
        if _read_exact(stream, 1, name) != b"\xff":
            raise CorruptFileError(name, "corrupt JPEG header (a segment does not start with FF)")
        marker = _read_exact(stream, 1, name)[0]
        while marker == 0xFF:  # fill bytes may pad a marker
            marker = _read_exact(stream, 1, name)[0]
        if marker in _STANDALONE:
            continue
        if marker in (_SOS, _EOI):
            raise CorruptFileError(name, "corrupt JPEG header (image data before any frame size)")
        (length,) = struct.unpack(">H", _read_exact(stream, 2, name))
        if length < 2:
            raise CorruptFileError(name, f"corrupt JPEG header (segment length {length})")
        if marker in _SOF_MARKERS:
            _, height, width = struct.unpack(">BHH", _read_exact(stream, 5, name))
            if width == 0 or height == 0:  # height 0 defers it to a DNL marker: rare, unsupported
                raise CorruptFileError(name, f"JPEG frame of {width}×{height} pixels")
            return width, height
        stream.seek(length - 2, io.SEEK_CUR)  # EXIF and ICC segments can be 64 KiB: skip them


def jpeg_size(source: str | Path | bytes | np.ndarray) -> tuple[int, int]:
    """A JPEG's (width, height) from its header, without decoding it.

    Args:
        source: a file path, or the file's bytes (``bytes`` or a uint8 array).

    Raises:
        CorruptFileError: naming the file, when it is no JPEG or its header is truncated.
        FileNotFoundError: naming the file, when it is missing.
    """
    if isinstance(source, (bytes, bytearray, memoryview, np.ndarray)):
        return _sof_size(_BufferStream(source), "<bytes>")
    path = Path(source)
    if not path.is_file():
        raise FileNotFoundError(f"file not found: {path}")
    with path.open("rb") as stream:
        return _sof_size(stream, str(path))


def image_size(path: str | Path) -> tuple[int, int]:
    """An RGB photo's (width, height): from the header for a JPEG, else by decoding it."""
    with Path(path).open("rb") as stream:
        is_jpeg = stream.read(2) == _SOI
    if is_jpeg:
        return jpeg_size(path)
    height, width = read_rgb(path).shape[:2]
    return width, height


def _check_window(x: int, y: int, width: int, height: int) -> None:
    for name, value in (("x", x), ("y", y), ("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise TypeError(f"{name} must be an integer, got {value!r}")
    if x < 0 or y < 0 or width < 1 or height < 1:
        raise ValueError(f"window {width}×{height} at ({x}, {y}): need x, y >= 0, sizes >= 1")


def _outside(path: Path, x: int, y: int, width: int, height: int, frame: tuple[int, int]) -> str:
    return (
        f"window {width}×{height} at ({x}, {y}) does not fit in the {frame[0]}×{frame[1]} frame "
        f"of {path}; pad frames smaller than the crop before cropping"
    )


def _slice(image: np.ndarray, path: Path, x: int, y: int, width: int, height: int) -> np.ndarray:
    frame = (image.shape[1], image.shape[0])
    if x + width > frame[0] or y + height > frame[1]:
        raise ValueError(_outside(path, x, y, width, height, frame))
    # A copy, so the caller does not keep the whole decoded frame alive through a view.
    return np.ascontiguousarray(image[y : y + height, x : x + width])


def read_rgb_window(path: str | Path, x: int, y: int, width: int, height: int) -> np.ndarray:
    """The window of an RGB photo: ``read_rgb(path)[y:y+height, x:x+width]``, decoded alone.

    Args:
        path: the photo (JPEG: window decode; PNG, TIFF, WebP: full decode and slice).
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
    x, y, width, height = int(x), int(y), int(width), int(height)
    path = Path(path)
    if _native is None:
        return _slice(read_rgb(path), path, x, y, width, height)
    data = read_checked(path)  # refuses empty files and JPEGs without an end-of-image marker
    if data[:2].tobytes() != _SOI:
        return _slice(read_rgb(path), path, x, y, width, height)
    frame = _sof_size(_BufferStream(data), str(path))
    if x + width > frame[0] or y + height > frame[1]:
        raise ValueError(_outside(path, x, y, width, height, frame))
    out = np.empty((height, width, 3), np.uint8)
    try:
        _native.decode_window(data, x, y, width, height, out)
    except _native.UnsupportedError:  # CMYK, 12-bit: OpenCV decodes those whole
        return _slice(read_rgb(path), path, x, y, width, height)
    except ValueError as error:
        raise CorruptFileError(path, f"libjpeg: {error}") from None
    return out


__all__ = [
    "FULL_DECODE",
    "REGION_DECODE",
    "decoder",
    "image_size",
    "jpeg_size",
    "read_rgb_window",
]
