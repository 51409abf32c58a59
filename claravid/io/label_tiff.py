"""The label cache's container: a frame's label codes as a tiled, deflate-compressed TIFF.

One uint8 page of ``TILE`` × ``TILE`` tiles, each compressed on its own (zlib level 1, the
standard library's codec, so reading and writing need no ``imagecodecs``), so a window is read
by fetching and inflating only the tiles that intersect it. The ImageDescription tag holds
JSON naming the format and its version, a digest of the code tables, the frame's shape, the
*sources* the entry was built from (:func:`claravid.io.labels.source_identity`: each label
file's path, size and modification time) and a CRC-32 of each compressed tile.

:func:`read_layout` refuses (:class:`InvalidEntry`, the cache then rebuilds) a file that is not
ours, of another version, of another class/code table, of another size, built from other
source files (another frame's entry copied over this one's), or whose tiles run past its end (a
truncated copy). A tile's bytes are checked against their CRC before they are inflated, so a
corrupt or foreign tile is never served, and :func:`verify_tiles` checks every tile of an entry
without inflating any (what ``claravid-cache`` does before it calls an entry valid).

The layout of an entry is fixed, so :class:`TileLayout` keeps plain arrays (offsets, byte
counts, CRCs), nothing of tifffile: layouts are cheap to keep, and to pickle. Plain TIFF, so any
viewer (or ``tifffile.imread``) opens an entry for debugging.
"""

from __future__ import annotations

import io
import json
import os
import zlib
from dataclasses import dataclass
from hashlib import sha1
from typing import Any

import numpy as np
import tifffile

from claravid.io.labels import DYNAMIC_CODES, STATIC_CODES

FORMAT = "claravid-label-codes"
#: Bump when the container changes in a way older readers would misread. 2: the sources and
#: the tiles' CRCs are recorded.
VERSION = 2
#: Tile side in pixels, by measurement (benchmarks/bench_label_cache.py, 4032×3024 frames, one
#: core): a 630×630 window reads in 0.77 ms at 256 as at 128, while 128 reads a whole frame 40%
#: slower (4× the tiles) and 512 takes 1.0 ms per window and 15% more bytes.
TILE = 256
#: zlib level 1: level 6 halves the size (~160 -> ~100 kB a frame) but writes ~3.5× slower,
#: which would take ``prepare`` past 1.3× the PNG decode it replaces.
LEVEL = 1
_ADOBE_DEFLATE = 8  # the TIFF compression tag of zlib/deflate
_NO_PREDICTOR = 1

#: Changes when the class table or the code rules change, so old entries are never served.
CODES_DIGEST = sha1(STATIC_CODES.tobytes() + DYNAMIC_CODES.tobytes()).hexdigest()[:12]

#: The sources of an entry: ``{"pan_seg": "<path>:<size>:<mtime ns>", "dynamic_mask": ... or
#: None}`` (:func:`claravid.io.labels.source_identity`).
SourceIdentity = dict[str, Any]
_NAMES = {"pan_seg": "panoptic file", "dynamic_mask": "dynamic mask"}


class InvalidEntry(Exception):
    """A cache entry that must not be served (truncated, corrupt, foreign, stale); rebuild it."""


class OtherVersion(InvalidEntry):
    """An entry written by another version of the cache format (every entry of an older cache
    is one: readers say so once, not once per entry)."""


@dataclass(frozen=True)
class TileLayout:
    """Where each tile of an entry lies in its file, and what it must hold.

    Attributes:
        height, width: the frame's size in pixels.
        tile_height, tile_width: the tile size (edge tiles are stored full size, padded).
        offsets, bytecounts: int64 [T], file offset and length of each tile, row-major.
        crcs: uint32 [T], the CRC-32 of each tile's compressed bytes.
        sources: the source files the entry was built from, as recorded in it.
    """

    height: int
    width: int
    tile_height: int
    tile_width: int
    offsets: np.ndarray
    bytecounts: np.ndarray
    crcs: np.ndarray
    sources: SourceIdentity

    @property
    def columns(self) -> int:
        """Tiles per row."""
        return -(-self.width // self.tile_width)

    @property
    def rows(self) -> int:
        """Tiles per column."""
        return -(-self.height // self.tile_height)


def _description(shape: tuple[int, int], sources: SourceIdentity, crcs: list[int]) -> str:
    return json.dumps(
        {"format": FORMAT, "version": VERSION, "codes": CODES_DIGEST, "shape": list(shape),
         "sources": sources, "tiles": crcs},
        separators=(",", ":"),
    )  # fmt: skip


def _tiles(codes: np.ndarray, tile: int) -> list[bytes]:
    """The compressed tiles of ``codes``, row-major, edge tiles padded with zeros (as TIFF
    stores them)."""
    height, width = codes.shape
    out = []
    for top in range(0, height, tile):
        for left in range(0, width, tile):
            block = np.zeros((tile, tile), np.uint8)
            part = codes[top : top + tile, left : left + tile]
            block[: part.shape[0], : part.shape[1]] = part
            out.append(zlib.compress(block.tobytes(), LEVEL))
    return out


def encode_codes(
    codes: np.ndarray, tile: int = TILE, sources: SourceIdentity | None = None
) -> bytes:
    """A frame's codes (uint8 H×W) as the bytes of a cache entry.

    Args:
        codes: the label codes.
        tile: the tile side.
        sources: what they were built from (:func:`claravid.io.labels.source_identity`),
            recorded so that the entry is refused for any other sources.
    """
    if codes.dtype != np.uint8 or codes.ndim != 2:
        raise ValueError(f"label codes must be uint8 H×W, got {codes.dtype} {codes.shape}")
    tiles = _tiles(codes, tile)
    buffer = io.BytesIO()
    with tifffile.TiffWriter(buffer) as tif:
        tif.write(
            iter(tiles),  # already compressed: tifffile writes the bytes as they are
            shape=codes.shape,
            dtype=np.uint8,
            tile=(tile, tile),
            compression="zlib",
            photometric="minisblack",
            description=_description(codes.shape, sources or {}, [zlib.crc32(t) for t in tiles]),
            metadata=None,  # our JSON alone in ImageDescription, not tifffile's shape record
        )
    return buffer.getvalue()


def _differences(recorded: Any, expected: SourceIdentity) -> str:
    """What differs between the sources an entry records and the frame's, in words."""
    if not recorded:
        return "it records no sources"
    parts = []
    for name in sorted(set(recorded) | set(expected)):
        was, now = recorded.get(name), expected.get(name)
        if was == now:
            continue
        what = _NAMES.get(name, name)
        if now is None:
            parts.append(f"it was built with a {what} ({was}) this frame is read without")
        elif was is None:
            parts.append(f"it was built without the frame's {what} ({now})")
        else:
            parts.append(f"its {what} was {was}, the frame's is {now}")
    return "; ".join(parts)


def check_sources(layout: TileLayout, expected: SourceIdentity) -> None:
    """Refuse an entry built from other source files than the frame's.

    Raises:
        InvalidEntry: naming what differs (another frame's entry copied over this one's, an
            entry built without the frame's dynamic mask, an edited file).
    """
    if layout.sources != expected:
        raise InvalidEntry(
            f"built from other source files: {_differences(layout.sources, expected)}"
        )


def read_layout(
    fd: int,
    expected_shape: tuple[int, int] | None,
    name: str = "entry",
    expected_sources: SourceIdentity | None = None,
) -> TileLayout:
    """Parse an entry's header from a descriptor opened at its start and check it can be served.

    Args:
        fd: the entry, opened for reading at offset 0 (its position is moved).
        expected_shape: (height, width) of the source frame; None skips that check.
        name: the file's name, for tifffile's messages.
        expected_sources: the frame's sources; None skips that check.

    Raises:
        InvalidEntry: not a TIFF, not ours, another version, class/code table or size, other
            source files, or tiles beyond the end of the file.
    """
    size = os.fstat(fd).st_size
    try:
        with open(fd, "rb", closefd=False) as fh, tifffile.TiffFile(fh, name=name) as tif:
            if len(tif.pages) != 1:
                raise InvalidEntry(f"{len(tif.pages)} pages, expected 1")
            page = tif.pages[0]
            meta = json.loads(page.description or "null")
            kind = (page.is_tiled, page.dtype, page.samplesperpixel, page.compression,
                    page.predictor)  # fmt: skip
            dims = (int(page.imagelength), int(page.imagewidth))
            tiles = (int(page.tilelength), int(page.tilewidth))
            offsets = np.asarray(page.dataoffsets, dtype=np.int64)
            bytecounts = np.asarray(page.databytecounts, dtype=np.int64)
    except InvalidEntry:
        raise
    except Exception as exc:  # tifffile raises many kinds on arbitrary bytes: not our entry
        raise InvalidEntry(f"unreadable TIFF ({type(exc).__name__}: {exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InvalidEntry("not a label-code entry")
    if meta.get("version") != VERSION:
        raise OtherVersion(f"written by another version of the cache ({meta.get('version')})")
    if meta.get("codes") != CODES_DIGEST:
        raise InvalidEntry(
            f"written under another class/code table (digest {meta.get('codes')}, this "
            f"toolkit's is {CODES_DIGEST})"
        )
    if kind != (True, np.uint8, 1, _ADOBE_DEFLATE, _NO_PREDICTOR) or meta.get("shape") != list(
        dims
    ):
        raise InvalidEntry(f"unexpected layout {kind} {dims}")
    if expected_shape is not None and dims != tuple(expected_shape):
        raise InvalidEntry(f"{dims[1]}×{dims[0]}, but the frame is {expected_shape[1]}×"
                           f"{expected_shape[0]}")  # fmt: skip
    sources = meta.get("sources")
    crcs = meta.get("tiles")
    layout = TileLayout(
        height=dims[0], width=dims[1], tile_height=tiles[0], tile_width=tiles[1],
        offsets=offsets, bytecounts=bytecounts,
        crcs=np.asarray(crcs if isinstance(crcs, list) else [], dtype=np.uint32),
        sources=sources if isinstance(sources, dict) else {},
    )  # fmt: skip
    if expected_sources is not None:
        check_sources(layout, expected_sources)
    count = layout.rows * layout.columns
    if not (len(offsets) == len(bytecounts) == len(layout.crcs) == count):
        raise InvalidEntry("tile table does not match the frame size")
    end = int((offsets + bytecounts).max())
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


def _check_crc(layout: TileLayout, index: int, data: bytes | memoryview) -> None:
    if zlib.crc32(data) != int(layout.crcs[index]):
        raise InvalidEntry(f"tile {index} is corrupt (its bytes do not match their CRC)")


def verify_tiles(fd: int, layout: TileLayout) -> None:
    """Check every tile's bytes against its CRC (nothing is inflated).

    Raises:
        InvalidEntry: a tile is cut or its bytes differ from what was written.
    """
    tiles = zip(layout.offsets.tolist(), layout.bytecounts.tolist(), strict=True)
    for index, (offset, count) in enumerate(tiles):
        _check_crc(layout, index, _pread(fd, count, offset))


def read_window(fd: int, layout: TileLayout, x: int, y: int, width: int, height: int) -> np.ndarray:
    """The codes of ``[y:y+height, x:x+width]``, reading and inflating only the tiles it touches.

    The window must lie inside the frame. Each row of tiles is fetched with one read when its
    tiles are contiguous in the file (as tifffile writes them).

    Raises:
        InvalidEntry: a tile is cut, corrupt (CRC, inflation) or of the wrong size.
    """
    th, tw, cols = layout.tile_height, layout.tile_width, layout.columns
    out = np.empty((height, width), dtype=np.uint8)
    c0, c1 = x // tw, (x + width - 1) // tw
    for row in range(y // th, (y + height - 1) // th + 1):
        first, last = row * cols + c0, row * cols + c1
        # Python ints of this row's tiles (indexing numpy arrays one by one is slower).
        offsets = layout.offsets[first : last + 1].tolist()
        counts = layout.bytecounts[first : last + 1].tolist()
        start = offsets[0]
        span = offsets[-1] + counts[-1] - start
        chunk = memoryview(_pread(fd, span, start)) if span == sum(counts) else None
        top, bottom = max(y, row * th), min(y + height, (row + 1) * th)
        for index, offset, count in zip(range(first, last + 1), offsets, counts, strict=True):
            data = (
                chunk[offset - start : offset - start + count]
                if chunk
                else _pread(fd, count, offset)
            )
            _check_crc(layout, index, data)
            try:
                raw = zlib.decompress(data)
            except zlib.error as exc:
                raise InvalidEntry(f"tile {index} is corrupt ({exc})") from None
            if len(raw) != th * tw:
                raise InvalidEntry(f"tile {index} holds {len(raw)} bytes, not {th}×{tw}")
            tile = np.frombuffer(raw, np.uint8).reshape(th, tw)
            col = index - row * cols
            left, right = max(x, col * tw), min(x + width, (col + 1) * tw)
            out[top - y : bottom - y, left - x : right - x] = tile[
                top - row * th : bottom - row * th, left - col * tw : right - col * tw
            ]
    return out
