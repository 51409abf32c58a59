"""What an image file is, from its header alone, and the limits every reader holds it to.

Before anything is decoded, the header says the format, the size and, for a JPEG, the coding
process (baseline, progressive, lossless, arithmetic), the bits per sample and the components.
:func:`check_header` refuses, naming the file, what no reader should start on:

- more than :data:`MAX_PIXELS` pixels (OpenCV's own limit: it raises ``cv2.error`` past it; a
  header that claims 65500×65500 is corrupt far more often than real);
- a JPEG or PNG whose file is too short for the size its header claims: a Huffman-coded JPEG
  codes every 8×8 block of a component with at least one bit, deflate cannot shrink data more
  than 1032 times. (A 3 kB file that claims 30000×30000 pixels would otherwise cost half a
  minute and 5 GB of memory to decode into grey.)
- JPEG processes the readers do not take: more than 8 bits per sample (OpenCV decodes none),
  arithmetic coding (a cut file decodes to invented pixels without any warning: arithmetic
  decoders feed zeros past the end of the data, which is also what a complete file's last bytes
  may legally leave out, so a cut cannot be told from an end) and hierarchical files.

Sizes come from the PNG ``IHDR`` chunk and the JPEG start-of-frame segment; other formats have
no header here (None), their reader decodes them whole.
"""

from __future__ import annotations

import io
import os
import stat
import struct
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from claravid.infra.errors import CorruptFileError, UnsupportedFileError

#: The most pixels any reader decodes: OpenCV's default ``OPENCV_IO_MAX_IMAGE_PIXELS`` (2^30).
MAX_PIXELS = 1 << 30
#: Deflate's largest compression ratio (a 258-byte match in two 1-bit codes).
_DEFLATE_MAX_RATIO = 1032

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}

JPEG_SOI = b"\xff\xd8"
# Start-of-frame markers carry the size; C4 (DHT), C8 (reserved) and CC (DAC) share the range.
_SOF_MARKERS = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
# Markers without a length field: TEM and the restart markers.
_STANDALONE = frozenset({0x01, *range(0xD0, 0xD8)})
_SOS, _EOI = 0xDA, 0xD9


@dataclass(frozen=True)
class ImageHeader:
    """A PNG's or JPEG's header.

    Attributes:
        format: ``"jpeg"`` or ``"png"``.
        width, height: the size in pixels.
        bits: bits per sample (JPEG precision, PNG bit depth).
        components: JPEG components, PNG channels.
        sof: the JPEG start-of-frame marker (0xC0 baseline ... 0xCF); 0 for a PNG.
        sampling: per JPEG component, its (horizontal, vertical) sampling factors.
        scan: offset of the JPEG's first start-of-scan marker; 0 when the header was read from a
            file without its data (:func:`file_header`), or for a PNG.
        color_type: the PNG colour type; -1 for a JPEG.
    """

    format: str
    width: int
    height: int
    bits: int
    components: int
    sof: int = 0
    sampling: tuple[tuple[int, int], ...] = ()
    scan: int = 0
    color_type: int = -1

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)``."""
        return self.width, self.height

    @property
    def progressive(self) -> bool:
        """A progressive JPEG (SOF2, SOF6, SOF10, SOF14)."""
        return self.sof in (0xC2, 0xC6, 0xCA, 0xCE)

    @property
    def lossless(self) -> bool:
        """A lossless JPEG (SOF3, SOF7, SOF11, SOF15)."""
        return self.sof in (0xC3, 0xC7, 0xCB, 0xCF)

    @property
    def arithmetic(self) -> bool:
        """An arithmetic-coded JPEG (SOF9 and above)."""
        return self.sof >= 0xC9

    @property
    def hierarchical(self) -> bool:
        """A hierarchical (differential) JPEG, which libjpeg decodes in no version."""
        return self.sof in (0xC5, 0xC6, 0xC7, 0xCD, 0xCE, 0xCF)

    @property
    def sequential(self) -> bool:
        """A baseline or extended sequential, Huffman-coded JPEG (SOF0, SOF1): one scan after
        another from the top, what the window decoder reads."""
        return self.sof in (0xC0, 0xC1)


class _Stream(Protocol):
    def read(self, count: int, /) -> bytes: ...
    def seek(self, offset: int, whence: int, /) -> int: ...
    def tell(self) -> int: ...


class BufferStream:
    """read/seek/tell over bytes already in memory, without copying them into a BytesIO."""

    def __init__(self, data: bytes | bytearray | memoryview | np.ndarray) -> None:
        # An ndarray is a buffer too (numpy's stubs say so from Python 3.12 on).
        self._view = memoryview(data).cast("B")  # type: ignore[arg-type]
        self._pos = 0

    def read(self, count: int, /) -> bytes:
        chunk = self._view[self._pos : self._pos + count].tobytes()
        self._pos += len(chunk)
        return chunk

    def seek(self, offset: int, whence: int, /) -> int:
        assert whence == io.SEEK_CUR
        self._pos = min(self._pos + offset, len(self._view))
        return self._pos

    def tell(self) -> int:
        return self._pos


def _read_exact(stream: _Stream, count: int, name: str | Path) -> bytes:
    chunk = stream.read(count)
    if len(chunk) != count:
        raise CorruptFileError(name, "truncated JPEG header (the file ends before its image data)")
    return chunk


def _next_marker(stream: _Stream, name: str | Path) -> int:
    if _read_exact(stream, 1, name) != b"\xff":
        raise CorruptFileError(name, "corrupt JPEG header (a segment does not start with FF)")
    marker = _read_exact(stream, 1, name)[0]
    while marker == 0xFF:  # fill bytes may pad a marker
        marker = _read_exact(stream, 1, name)[0]
    return marker


def parse_jpeg(stream: _Stream, name: str | Path, to_scan: bool = True) -> ImageHeader:
    """The header of the JPEG ``stream`` (positioned at its start), reading only the header.

    Args:
        stream: the file or its bytes (:class:`BufferStream`).
        name: the file, for errors.
        to_scan: read on to the first start-of-scan marker and record where it is (the data of a
            file in memory); False: stop at the start of frame (a size read from disk).

    Raises:
        CorruptFileError: no JPEG, or a truncated or corrupt header.
    """
    if stream.read(2) != JPEG_SOI:
        raise CorruptFileError(name, "not a JPEG file (no start-of-image marker)")
    frame: ImageHeader | None = None
    while True:
        marker = _next_marker(stream, name)
        if marker in _STANDALONE:
            continue
        if marker == _SOS and frame is not None:
            return replace(frame, scan=stream.tell() - 2)
        if marker in (_SOS, _EOI):
            raise CorruptFileError(name, "corrupt JPEG header (image data before any frame size)")
        (length,) = struct.unpack(">H", _read_exact(stream, 2, name))
        if length < 2:
            raise CorruptFileError(name, f"corrupt JPEG header (segment length {length})")
        if marker in _SOF_MARKERS and frame is None:
            if length < 8:
                raise CorruptFileError(name, f"corrupt JPEG header (frame segment of {length} B)")
            body = _read_exact(stream, length - 2, name)
            bits, height, width, components = struct.unpack(">BHHB", body[:6])
            if width == 0 or height == 0:  # height 0 defers it to a DNL marker: rare, unsupported
                raise CorruptFileError(name, f"JPEG frame of {width}×{height} pixels")
            factors = body[6 : 6 + 3 * components][1::3]
            if components == 0 or len(factors) != components:
                raise CorruptFileError(name, f"corrupt JPEG header ({components} components)")
            sampling = tuple((f >> 4, f & 15) for f in factors)
            frame = ImageHeader("jpeg", width, height, bits, components, marker, sampling)
            if not to_scan:
                return frame
            continue
        stream.seek(length - 2, io.SEEK_CUR)  # EXIF and ICC segments can be 64 KiB: skip them


def parse_png(head: bytes) -> ImageHeader | None:
    """The header of a PNG from its first 26 bytes (signature and ``IHDR``); None for no PNG."""
    if len(head) < 26 or not head.startswith(PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return None
    width, height, bits, color_type = struct.unpack(">IIBB", head[16:26])
    channels = _PNG_CHANNELS.get(color_type, 0)
    return ImageHeader("png", width, height, bits, channels, color_type=color_type)


def read_header(data: bytes | np.ndarray, name: str | Path) -> ImageHeader | None:
    """The header of a PNG or JPEG file's bytes (for a JPEG, up to its first scan); None for
    other formats.

    Raises:
        CorruptFileError: a JPEG whose header is truncated or corrupt.
    """
    # An ndarray is a buffer too (numpy's stubs say so from Python 3.12 on).
    head = memoryview(data).cast("B")[:26].tobytes()  # type: ignore[arg-type]
    if head.startswith(JPEG_SOI):
        return parse_jpeg(BufferStream(data), name)
    return parse_png(head)


def _min_bytes(header: ImageHeader) -> int:
    """The fewest bytes a file with this header can have (0: no bound known)."""
    if header.format == "png":
        return (
            header.width
            * header.height
            * header.components
            * header.bits
            // 8
            // (_DEFLATE_MAX_RATIO)
        )
    if header.arithmetic or not header.sampling:  # arithmetic codes can take < 1 bit per block
        return 0
    h_max = max(h for h, _ in header.sampling) or 1
    v_max = max(v for _, v in header.sampling) or 1
    units = []
    for h, v in header.sampling:  # one bit per sample (lossless) or per 8×8 block at least
        cols = -(-header.width * h // h_max)
        rows = -(-header.height * v // v_max)
        units.append(cols * rows if header.lossless else -(-cols // 8) * -(-rows // 8))
    return min(units) // 8


def check_header(header: ImageHeader | None, name: str | Path, file_size: int) -> None:
    """Refuse, naming the file, what no reader decodes (see the module's docstring).

    Args:
        header: from :func:`read_header` or :func:`file_header`; None (another format) passes.
        name: the file, for the message.
        file_size: the file's length in bytes.

    Raises:
        UnsupportedFileError: too many pixels, or a JPEG process the readers do not take.
        CorruptFileError: a file too short for the size its header claims.
    """
    if header is None:
        return
    pixels = header.width * header.height
    if pixels > MAX_PIXELS:
        raise UnsupportedFileError(
            name,
            f"its header claims {header.width}×{header.height} = {pixels:,} pixels, more than "
            f"the {MAX_PIXELS:,} (2^30) the readers decode; a corrupt header, or an image to "
            "cut into tiles first",
        )
    if header.format == "jpeg":
        _check_jpeg_process(header, name)
    least = _min_bytes(header)
    if file_size < least:
        raise CorruptFileError(
            name,
            f"its header claims {header.width}×{header.height} pixels, but the file holds "
            f"{file_size:,} bytes, fewer than the {least:,} any {header.format.upper()} of that "
            "size needs (a corrupt header or a truncated file)",
        )


def _check_jpeg_process(header: ImageHeader, name: str | Path) -> None:
    convert = "convert it to an 8-bit baseline JPEG or a PNG"
    if header.hierarchical:
        raise UnsupportedFileError(
            name,
            f"hierarchical JPEG (SOF{header.sof - 0xC0}), which libjpeg cannot decode; {convert}",
        )
    if header.arithmetic:
        raise UnsupportedFileError(
            name,
            "arithmetic-coded JPEG: a cut one decodes to invented pixels without any error, so "
            f"the readers refuse them all; {convert} (jpegtran re-codes it losslessly)",
        )
    if header.bits != 8:
        raise UnsupportedFileError(
            name, f"{header.bits}-bit JPEG: the readers decode 8-bit JPEGs only; {convert}"
        )
    if header.components not in (1, 3, 4):
        raise UnsupportedFileError(
            name, f"JPEG with {header.components} components (1, 3 or 4 are read); {convert}"
        )


def open_regular(path: str | Path) -> int:
    """A read-only descriptor on ``path``, refusing what is not a regular file.

    Opened without blocking, so a FIFO (or a device) named like an image is refused at once
    instead of waiting forever for a writer.

    Raises:
        FileNotFoundError: naming the file, when it is missing.
        UnsupportedFileError: naming it, when it is a folder, FIFO, socket or device.
    """
    path = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        raise FileNotFoundError(f"file not found: {path}") from None
    except IsADirectoryError:
        fd = -1
    if fd < 0 or not _is_regular(fd):
        if fd >= 0:
            os.close(fd)
        raise UnsupportedFileError(
            path, "not a regular file (a folder, FIFO, socket or device); name an image file"
        )
    return fd


def _is_regular(fd: int) -> bool:
    return stat.S_ISREG(os.fstat(fd).st_mode)


def file_header(path: str | Path) -> tuple[ImageHeader | None, int]:
    """A PNG's or JPEG's header read from disk (the header bytes only), checked by
    :func:`check_header`, and the file's size; ``(None, size)`` for other formats.

    Raises:
        FileNotFoundError, UnsupportedFileError, CorruptFileError: see :func:`open_regular`
            and :func:`check_header`.
    """
    fd = open_regular(path)
    with open(fd, "rb", closefd=True) as stream:
        size = os.fstat(stream.fileno()).st_size
        head = stream.read(26)
        header: ImageHeader | None
        if head.startswith(JPEG_SOI):
            stream.seek(0)
            header = parse_jpeg(stream, path, to_scan=False)
        else:
            header = parse_png(head)
    check_header(header, path, size)
    return header, size
