"""The label cache's container: a frame's label codes as a tiled, deflate-compressed TIFF.

One uint8 page of ``TILE`` × ``TILE`` tiles, each compressed on its own (zlib level 1: the
standard library's codec, so reading and writing need no ``imagecodecs``), so a window is read
by fetching and inflating only the tiles that intersect it. The ImageDescription tag holds
JSON naming the format, its version, a digest of the code tables and the frame's shape: a
file that is not ours, of another version or another code table, or of another size is
refused by :func:`read_layout` (the cache then rebuilds it), and so is one whose tiles run
past its end (a truncated copy). A tile's own bytes are checked when it is inflated: zlib
streams carry an Adler-32 checksum and the inflated size must be the tile's.

Plain TIFF, so any viewer (or ``tifffile.imread``) opens an entry for debugging.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from hashlib import sha1
from typing import Any

import numpy as np
import tifffile

from claravid.io.labels import DYNAMIC_CODES, STATIC_CODES

FORMAT = "claravid-label-codes"
#: Bump when the container changes in a way older readers would misread.
VERSION = 1
#: Tile side in pixels, by measurement (benchmarks/bench_label_cache.py, 4032×3024 frames, one
#: core): a 630×630 window reads in 0.77 ms at 256 as at 128, while 128 reads a whole frame 40%
#: slower (4× the tiles) and 512 takes 1.0 ms per window and 15% more bytes.
TILE = 256
#: zlib level 1: level 6 halves the size (~160 -> ~100 kB a frame) but writes ~3.5× slower,
#: which would take ``prepare`` past 1.3× the PNG decode it replaces.
LEVEL = 1
_ADOBE_DEFLATE = 8  # the TIFF compression tag tifffile writes for "zlib"

#: Changes when the class table or the code rules change, so old entries are never served.
CODES_DIGEST = sha1(STATIC_CODES.tobytes() + DYNAMIC_CODES.tobytes()).hexdigest()[:12]


class InvalidEntry(Exception):
    """A cache entry that must not be served (truncated, corrupt, foreign, stale); rebuild it."""


@dataclass(frozen=True)
class TileLayout:
    """Where each tile of an entry lies in its file, and how to inflate one.

    Attributes:
        height, width: the frame's size in pixels.
        tile_height, tile_width: the tile size (edge tiles are stored full size, padded).
        offsets, bytecounts: file offset and length of each tile, row-major.
        decode: tifffile's segment decoder for this page: ``decode(data, index)``.
    """

    height: int
    width: int
    tile_height: int
    tile_width: int
    offsets: tuple[int, ...]
    bytecounts: tuple[int, ...]
    decode: Callable[..., Any]

    @property
    def columns(self) -> int:
        """Tiles per row."""
        return -(-self.width // self.tile_width)


def _description(shape: tuple[int, int]) -> str:
    return json.dumps(
        {"format": FORMAT, "version": VERSION, "codes": CODES_DIGEST, "shape": list(shape)}
    )


def encode_codes(codes: np.ndarray, tile: int = TILE) -> bytes:
    """A frame's codes (uint8 H×W) as the bytes of a cache entry."""
    if codes.dtype != np.uint8 or codes.ndim != 2:
        raise ValueError(f"label codes must be uint8 H×W, got {codes.dtype} {codes.shape}")
    buffer = io.BytesIO()
    tifffile.imwrite(
        buffer,
        codes,
        tile=(tile, tile),
        compression="zlib",
        compressionargs={"level": LEVEL},
        photometric="minisblack",
        description=_description(codes.shape),
        metadata=None,  # our JSON alone in ImageDescription, not tifffile's shape record
    )
    return buffer.getvalue()


def read_layout(fd: int, expected_shape: tuple[int, int] | None, name: str = "entry") -> TileLayout:
    """Parse an entry's header from an open file descriptor and check it can be served.

    Args:
        fd: the entry, opened for reading (its position is moved; reads use offsets).
        expected_shape: (height, width) of the source frame; None skips that check.
        name: the file's name, for tifffile's messages.

    Raises:
        InvalidEntry: not a TIFF, not ours, another version, code table or size, or tiles
            beyond the end of the file.
    """
    size = os.fstat(fd).st_size
    try:
        with open(fd, "rb", closefd=False) as fh, tifffile.TiffFile(fh, name=name) as tif:
            if len(tif.pages) != 1:
                raise InvalidEntry(f"{len(tif.pages)} pages, expected 1")
            page = tif.pages[0]
            meta = json.loads(page.description or "null")
            layout = TileLayout(
                height=int(page.imagelength),
                width=int(page.imagewidth),
                tile_height=int(page.tilelength),
                tile_width=int(page.tilewidth),
                offsets=tuple(int(v) for v in page.dataoffsets),
                bytecounts=tuple(int(v) for v in page.databytecounts),
                decode=page.decode,
            )
            kind = (page.is_tiled, page.dtype, page.samplesperpixel, page.compression)
    except InvalidEntry:
        raise
    except Exception as exc:  # tifffile raises many kinds on arbitrary bytes: not our entry
        raise InvalidEntry(f"unreadable TIFF ({type(exc).__name__}: {exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InvalidEntry("not a label-code entry")
    if meta.get("version") != VERSION or meta.get("codes") != CODES_DIGEST:
        raise InvalidEntry(f"written by another version ({meta.get('version')})")
    shape = (layout.height, layout.width)
    if kind != (True, np.uint8, 1, _ADOBE_DEFLATE) or meta.get("shape") != list(shape):
        raise InvalidEntry(f"unexpected layout {kind} {shape}")
    if expected_shape is not None and shape != tuple(expected_shape):
        raise InvalidEntry(f"{shape[1]}×{shape[0]}, but the frame is {expected_shape[1]}×"
                           f"{expected_shape[0]}")  # fmt: skip
    rows = -(-layout.height // layout.tile_height)
    if len(layout.offsets) != rows * layout.columns or len(layout.bytecounts) != len(
        layout.offsets
    ):
        raise InvalidEntry("tile table does not match the frame size")
    end = max(o + c for o, c in zip(layout.offsets, layout.bytecounts, strict=True))
    if end > size:
        raise InvalidEntry(f"truncated: tiles end at byte {end}, the file has {size}")
    return layout


def _pread(fd: int, length: int, offset: int) -> bytes:
    if hasattr(os, "pread"):
        data = os.pread(fd, length, offset)
    else:  # Windows: no pread; the descriptor is private to this call, so seeking is safe
        os.lseek(fd, offset, os.SEEK_SET)
        data = os.read(fd, length)
    if len(data) != length:
        raise InvalidEntry(f"short read at byte {offset}: the file was cut")
    return data


def read_window(fd: int, layout: TileLayout, x: int, y: int, width: int, height: int) -> np.ndarray:
    """The codes of ``[y:y+height, x:x+width]``, reading and inflating only the tiles it touches.

    The window must lie inside the frame. Each row of tiles is fetched with one read when its
    tiles are contiguous in the file (as tifffile writes them).

    Raises:
        InvalidEntry: a tile is cut, corrupt (checksum) or of the wrong size.
    """
    th, tw, cols = layout.tile_height, layout.tile_width, layout.columns
    out = np.empty((height, width), dtype=np.uint8)
    c0, c1 = x // tw, (x + width - 1) // tw
    for row in range(y // th, (y + height - 1) // th + 1):
        first, last = row * cols + c0, row * cols + c1
        start = layout.offsets[first]
        span = layout.offsets[last] + layout.bytecounts[last] - start
        needed = sum(layout.bytecounts[first : last + 1])
        chunk = _pread(fd, span, start) if span == needed else None
        top, bottom = max(y, row * th), min(y + height, (row + 1) * th)
        for index in range(first, last + 1):
            offset, count = layout.offsets[index], layout.bytecounts[index]
            data = chunk[offset - start : offset - start + count] if chunk else None
            if data is None:
                data = _pread(fd, count, offset)
            try:
                tile = layout.decode(data, index)[0]
            except Exception as exc:  # zlib.error, tifffile's reshape error: a corrupt tile
                raise InvalidEntry(f"tile {index} is corrupt ({exc})") from None
            tile = tile.reshape(th, tw)
            col = index - row * cols
            left, right = max(x, col * tw), min(x + width, (col + 1) * tw)
            out[top - y : bottom - y, left - x : right - x] = tile[
                top - row * th : bottom - row * th, left - col * tw : right - col * tw
            ]
    return out
