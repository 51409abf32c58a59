"""An image file's bytes, read once and checked, and their decode by OpenCV with errors that name
the file.

Every image reader of the toolkit goes through here: :func:`read_checked` reads regular files
only, refuses empty and truncated ones and, from the header (:mod:`claravid.io.headers`), images
no reader decodes (too many pixels, a file too short for its size, unsupported JPEG processes);
:func:`decode_bytes` holds bytes handed to it directly to the same header checks and turns
OpenCV's own errors into :class:`CorruptFileError`.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from claravid.infra.errors import CorruptFileError
from claravid.io.headers import (
    JPEG_SOI,
    PNG_SIGNATURE,
    ImageHeader,
    check_header,
    open_regular,
    parse_png,
    read_header,
)

_JPEG_EOI = b"\xff\xd9"
_PNG_IEND = b"IEND\xaeB`\x82"
_TAIL = 4096  # where a JPEG's end-of-image marker is first looked for


def read_bytes(path: str | Path) -> np.ndarray:
    """Read a whole regular file into a uint8 array (no copy on the way to ``cv2.imdecode``).

    Raises:
        FileNotFoundError: naming the file, when it is missing.
        UnsupportedFileError: naming it, when it is no regular file (a FIFO would block).
    """
    fd = open_regular(path)
    with open(fd, "rb", buffering=0, closefd=True) as stream:
        size = stream.seek(0, 2)
        stream.seek(0)
        data = np.empty(size, np.uint8)
        # An ndarray is a buffer too (numpy's stubs say so from Python 3.12 on).
        view, done = memoryview(data), 0  # type: ignore[arg-type]
        while done < size:
            count = stream.readinto(view[done:])
            if not count:  # the file shrank while being read
                return data[:done]
            done += count
    return data


def _check_jpeg_end(data: np.ndarray, header: ImageHeader, path: Path) -> None:
    """A JPEG must reach its end-of-image marker after its first scan's data.

    The marker cannot occur inside entropy-coded data (a coded 0xFF is followed by 0x00), so one
    after the first scan ends the image: what follows it (a motion photo's video, maker data)
    does not matter. An end marker before the first scan (that of an EXIF thumbnail) does not
    count.
    """
    tail_start = max(header.scan, data.size - _TAIL)
    if _JPEG_EOI in data[tail_start:].tobytes():
        return
    if data.size - header.scan > _TAIL and _JPEG_EOI in data[header.scan :].tobytes():
        return  # trailer data after the end marker
    raise CorruptFileError(path, "truncated JPEG (no end-of-image marker)")


def check_bytes(data: np.ndarray, path: str | Path) -> ImageHeader | None:
    """Check a file's bytes before decoding them; return their header (None: not PNG/JPEG).

    Raises:
        CorruptFileError: empty, truncated (a JPEG without its end-of-image marker, a PNG
            without its ``IEND`` chunk), corrupt header, or too short for its size.
        UnsupportedFileError: an image no reader decodes (see :func:`check_header`).
    """
    path = Path(path)
    if data.size == 0:
        raise CorruptFileError(path, "the file is empty (0 bytes)")
    header = read_header(data, path)
    check_header(header, path, int(data.size))
    if header is not None and header.format == "jpeg":
        _check_jpeg_end(data, header, path)
    elif data[:8].tobytes() == PNG_SIGNATURE and not _png_complete(data):
        raise CorruptFileError(path, "truncated PNG (no IEND chunk)")
    return header


def _png_complete(data: np.ndarray) -> bool:
    """Whether a PNG's chunks reach its ``IEND`` chunk.

    Usually the file ends with it (one look at the last 12 bytes). Bytes after it (a tool's
    trailer, padding) do not make the image incomplete, so otherwise the chunk headers are
    walked from the signature: a file cut short runs out of bytes before any ``IEND``.
    """
    if data[-12:].tobytes().endswith(_PNG_IEND):
        return True
    position, size = 8, int(data.size)
    while position + 12 <= size:
        length = int.from_bytes(data[position : position + 4].tobytes(), "big")
        if data[position + 4 : position + 12].tobytes() == _PNG_IEND:
            return True
        position += 12 + length
    return False


def load(path: str | Path) -> tuple[np.ndarray, ImageHeader | None]:
    """A file's bytes, read once, and their checked header (see :func:`check_bytes`)."""
    data = read_bytes(path)
    return data, check_bytes(data, path)


def read_checked(path: str | Path) -> np.ndarray:
    """A file's bytes, refusing what :func:`check_bytes` refuses (naming the file)."""
    return load(path)[0]


def decode_bytes(
    data: np.ndarray,
    path: str | Path,
    flags: int,
    exif_orientation: bool = False,
    *,
    checked: bool = False,
) -> np.ndarray:
    """Decode a file's bytes with OpenCV; ``path`` names the file in the error.

    Args:
        data: the file's bytes.
        path: the file, for errors.
        flags: ``cv2.IMREAD_*`` flags.
        exif_orientation: rotate by the EXIF orientation tag.
        checked: the bytes passed :func:`check_bytes` already (from :func:`load` or
            :func:`read_checked`); False: check them here.

    Raises:
        CorruptFileError: the checks of :func:`check_bytes`, or OpenCV cannot decode the bytes.
    """
    if not checked:
        check_bytes(data, path)
    if not exif_orientation and flags != cv2.IMREAD_UNCHANGED:
        flags |= cv2.IMREAD_IGNORE_ORIENTATION
    try:
        image = cv2.imdecode(data, flags)
    except cv2.error as error:  # e.g. a size beyond OpenCV's limits in a format we do not parse
        reason = str(error).strip().splitlines()[-1] if str(error).strip() else "cv2.error"
        raise CorruptFileError(path, f"OpenCV refused it ({reason})") from None
    if image is None:
        raise CorruptFileError(path, "OpenCV could not decode it (corrupt or not an image)")
    return image


def decode_image(
    path: str | Path, flags: int = cv2.IMREAD_COLOR, *, exif_orientation: bool = False
) -> np.ndarray:
    """Read, check and decode an image file with OpenCV, raising errors that name the file.

    Args:
        path: the image file.
        flags: ``cv2.IMREAD_*`` flags.
        exif_orientation: rotate by the EXIF orientation tag, as ``cv2.imread`` does. Off by
            default, as PIL (and so the official SDK) ignores the tag.
    """
    return decode_bytes(read_checked(path), path, flags, exif_orientation, checked=True)


PNG_COLOR_TYPES = {0: "grey", 2: "RGB", 3: "palette", 4: "grey+alpha", 6: "RGBA"}


def png_header(data: np.ndarray) -> tuple[int, int] | None:
    """(bit depth, colour type) from a PNG's IHDR chunk, or None when the bytes are no PNG."""
    header = parse_png(data[:26].tobytes())
    return None if header is None else (header.bits, header.color_type)


def describe_bytes(data: np.ndarray) -> str:
    """What a file's bytes are, for error messages: ``a 16-bit RGB PNG``, ``JPEG data``."""
    header = png_header(data)
    if header is not None:
        depth, color_type = header
        article = "an" if str(depth).startswith("8") else "a"
        return f"{article} {depth}-bit {PNG_COLOR_TYPES.get(color_type, f'type-{color_type}')} PNG"
    if data[:2].tobytes() == JPEG_SOI:
        return "JPEG data"
    return "no PNG data"
