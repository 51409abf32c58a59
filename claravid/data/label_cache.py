"""``LabelCache``: frames' label codes prepared once, then read whole or by window.

An entry is a tiled TIFF (:mod:`claravid.io.label_tiff`) named after the identity (path, size,
mtime) of its source files, the panoptic PNG and the dynamic mask when the frame is read with
one, and recording that identity: an edited source misses instead of serving stale labels, and
an entry built from other sources (without the dynamic mask, another frame's entry copied over
this one's) is refused. A 630×630 training crop reads the ~16 tiles it touches instead of
decoding a 12 MP PNG. An entry that fails its checks (cut, corrupt tile, foreign, another
version, class table, size or sources) is rebuilt from the sources, never served.

Write failures (:mod:`claravid.data.cache_entries`). Only what proves that the cache folder
cannot take any entry (a read-only file system, a full disk or quota, the folder itself not
writable) turns writing off for that folder in this process, with one warning; reads then
decode the sources. Any other failure (a folder where one entry should be, one sub-folder
without permission, a transient I/O error) concerns that entry alone: one warning names it,
its frame is decoded in this process, the other entries are cached as usual.
:meth:`LabelCache.prepare` (:mod:`claravid.data.cache_prepare`) stops with an error for the
first kind and lists the frames of the second.

A ``LabelCache`` pickles (for DataLoader workers started by spawn or forkserver): what it keeps
of parsed entries (plain offsets, byte counts and CRCs, at most :data:`LAYOUTS` of them) stays
behind.
"""

from __future__ import annotations

import os
import threading
import warnings
from collections import OrderedDict
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from claravid.data.cache_entries import (
    CacheWriteError,
    LabelCacheWarning,
    NotAnEntry,
    entry_error,
    entry_path,
    entry_path_of,
    folder_refuses,
    open_entry,
    png_shape,
    write_atomic,
    write_error,
)
from claravid.data.cache_prepare import PrepareSummary, Sources, prepare_entries
from claravid.infra.cachedir import cache_dir
from claravid.io import label_tiff
from claravid.io.label_tiff import InvalidEntry, OtherVersion, SourceIdentity, TileLayout
from claravid.io.labels import read_label_codes, source_identity

__all__ = [
    "LAYOUTS",
    "CacheWriteError",
    "LabelCache",
    "LabelCacheWarning",
    "PrepareSummary",
    "entry_path",
    "png_shape",
    "write_atomic",
]

#: Parsed entry headers kept per ``LabelCache`` (least recently used dropped first): ~4 kB each
#: for a 4032×3024 frame; a header parsed again costs ~0.25 ms.
LAYOUTS = 1024
# Per process, for every LabelCache: folders that cannot take an entry (warned once, not
# written again), entries whose write failed (warned once, not retried), invalid entries that
# could not be rebuilt (warned once), folders holding entries of another version (warned once).
_unwritable_folders: set[str] = set()
_unwritable_entries: set[str] = set()
_unrepaired_entries: set[str] = set()
_other_versions: set[str] = set()  # folders whose entries of another version were warned about


class LabelCache:
    """Label codes of frames, stored once as tiled TIFFs under ``directory/label_codes``.

    Args:
        directory: the cache root; None: ``$CLARAVID_CACHE`` or ``~/.cache/claravid``.
        tile_size: tile side of the entries this cache writes (reading takes any): a positive
            multiple of 16, as TIFF tiles are.
        layouts: how many parsed entry headers to keep (least recently used dropped first);
            0 keeps none.

    Raises:
        ValueError: a tile size or a number of layouts it cannot use, said when it is made
            rather than at the first read.
    """

    def __init__(
        self,
        directory: str | Path | None = None,
        tile_size: int = label_tiff.TILE,
        layouts: int = LAYOUTS,
    ):
        if not _is_int(tile_size) or tile_size < 16 or tile_size % 16:
            raise ValueError(
                f"tile_size={tile_size!r}: TIFF tiles are a positive multiple of 16 pixels, "
                f"e.g. {label_tiff.TILE} (the default)"
            )
        if not _is_int(layouts) or layouts < 0:
            raise ValueError(
                f"layouts={layouts!r}: how many parsed entry headers to keep, an integer >= 0 "
                f"(default {LAYOUTS})"
            )
        #: Whether the folder came from $CLARAVID_CACHE (what a message advises to change).
        self.from_environment = directory is None
        self.directory = Path(directory) if directory is not None else cache_dir()
        self.directory = self.directory / "label_codes"
        self.tile_size = tile_size
        self.max_layouts = layouts
        self._init_layouts()

    def _init_layouts(self) -> None:
        # Parsed headers of entries read before, keyed by path and checked against the file's
        # identity (inode, size, mtime): a warm window read is one open and a few reads. Plain
        # arrays only (no tifffile object of a closed file), bounded, behind a lock: DataLoader
        # threads and the prefetching of several readers share one cache.
        self._layouts: OrderedDict[str, tuple[tuple[int, int, int], TileLayout]] = OrderedDict()
        self._lock = threading.Lock()

    def __getstate__(self) -> dict:
        # A worker process starts with no parsed header (and its own lock).
        state = self.__dict__.copy()
        del state["_layouts"], state["_lock"]
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._init_layouts()

    def path_for(self, pan_seg: Path, dynamic_mask: Path | None = None) -> Path:
        """The entry of a frame's sources (whether present or not)."""
        return entry_path(self.directory, pan_seg, dynamic_mask)

    def read(self, pan_seg: Path, dynamic_mask: Path | None = None) -> np.ndarray:
        """The frame's codes (uint8 H×W): from the cache when valid, else decoded and stored."""
        return self._read(Path(pan_seg), dynamic_mask, None)

    def read_window(
        self,
        pan_seg: Path,
        dynamic_mask: Path | None,
        x: int,
        y: int,
        width: int,
        height: int,
    ) -> np.ndarray:
        """The codes of a window, ``read_label_codes(...)[y:y+height, x:x+width]``.

        From a valid entry only the tiles the window touches are read and inflated; a missing
        or invalid entry is built from the sources first (one whole decode).

        Raises:
            ValueError: the window is empty or not inside the frame.
        """
        if min(width, height) < 1 or min(x, y) < 0:
            raise ValueError(f"window {width}×{height} at ({x}, {y}) is empty or negative")
        return self._read(Path(pan_seg), dynamic_mask, (x, y, width, height))

    def prepare(
        self,
        frames: Iterable[Sources],
        *,
        workers: int = 0,
        progress: bool = False,
        shard: tuple[int, int] = (0, 1),
    ) -> PrepareSummary:
        """Build every missing or invalid entry of ``frames``, in worker processes.

        Idempotent: entries present and valid (every tile checked against its CRC) are counted
        as skipped, not rewritten.

        Args:
            frames: ``(panoptic PNG, dynamic mask or None)`` of each frame.
            workers: worker processes; 0 or 1 builds in this process.
            progress: show a progress bar on stderr.
            shard: ``(k, n)``: only every n-th frame from the k-th (a job array's part).

        Raises:
            CacheWriteError: the cache folder cannot take any entry (full disk, read-only); the
                message says which and where. Entries written before stay; none is
                half-written. A location that refuses one entry only is listed in
                ``unwritten`` instead.
        """
        return prepare_entries(self, frames, workers=workers, progress=progress, shard=shard)

    def advice(self) -> str:
        """What a message advises to make this cache writable."""
        if self.from_environment:
            return "set CLARAVID_CACHE to a writable folder"
        return "choose a writable cache folder"

    def open_valid(
        self, path: Path, pan_seg: Path, identity: SourceIdentity, verify: bool = False
    ) -> tuple[int, TileLayout]:
        """An open descriptor on the valid entry ``path`` of these sources, and its layout.

        Args:
            path: the entry.
            pan_seg: the frame's panoptic PNG (its size, from the header, must be the entry's).
            identity: the frame's sources (:func:`claravid.io.labels.source_identity`).
            verify: check every tile's CRC too (nothing inflated).

        Raises:
            OSError: no entry there (or a folder in its place).
            NotAnEntry: a FIFO, socket or device in its place (never read: a FIFO would block).
            InvalidEntry: an entry that must not be served.
        """
        fd = open_entry(path)
        try:
            st = os.fstat(fd)
            file_id = (st.st_ino, st.st_size, st.st_mtime_ns)
            key = str(path)
            with self._lock:
                known = self._layouts.get(key)
                if known is not None and known[0] == file_id:
                    self._layouts.move_to_end(key)
            if known is not None and known[0] == file_id:
                layout = known[1]
                label_tiff.check_sources(layout, identity)
            else:
                layout = label_tiff.read_layout(fd, png_shape(pan_seg), path.name, identity)
                with self._lock:
                    self._layouts[key] = (file_id, layout)
                    self._layouts.move_to_end(key)
                    while len(self._layouts) > self.max_layouts:
                        self._layouts.popitem(last=False)
            if verify:
                label_tiff.verify_tiles(fd, layout)
            return fd, layout
        except BaseException:
            os.close(fd)
            raise

    def _forget(self, path: Path) -> None:
        with self._lock:
            self._layouts.pop(str(path), None)

    def _read(
        self, pan_seg: Path, dynamic_mask: Path | None, window: tuple[int, int, int, int] | None
    ) -> np.ndarray:
        dyn = None if dynamic_mask is None else Path(dynamic_mask)
        identity = source_identity(pan_seg, dyn)
        path = entry_path_of(self.directory, identity)
        problem = None
        try:
            fd, layout = self.open_valid(path, pan_seg, identity)
        except NotAnEntry as exc:  # left alone: decoded, never written over
            self._warn_not_an_entry(path, exc)
            return _window_of(read_label_codes(pan_seg, dyn), window)
        except OSError:  # missing, or a cache folder we cannot even read: decode instead
            pass
        except InvalidEntry as exc:
            problem = exc
        else:
            try:
                x, y, w, h = window or (0, 0, layout.width, layout.height)
                _check_window(x, y, w, h, layout.width, layout.height)
                return label_tiff.read_window(fd, layout, x, y, w, h)
            except InvalidEntry as exc:
                problem = exc
            finally:
                os.close(fd)
        if problem is not None:
            self._forget(path)
        codes = read_label_codes(pan_seg, dyn)
        stored = self._store(path, codes, identity)
        if problem is not None:
            self._warn_invalid(path, problem, stored)
        return _window_of(codes, window)

    def _store(self, path: Path, codes: np.ndarray, identity: SourceIdentity) -> bool:
        """Write the entry unless its folder or itself refused a write before; True if written."""
        if str(self.directory) in _unwritable_folders or str(path) in _unwritable_entries:
            return False  # once refused, not encoded and tried again in this process
        try:
            write_atomic(path, label_tiff.encode_codes(codes, self.tile_size, identity))
        except OSError as exc:
            if folder_refuses(exc, self.directory):
                self._warn_unwritable(exc)
            else:
                self._warn_entry(path, exc)
            return False
        _unrepaired_entries.discard(str(path))
        return True

    def _warn_invalid(self, path: Path, exc: InvalidEntry, stored: bool) -> None:
        if stored and isinstance(exc, OtherVersion):
            # Every entry of an older cache is one: said once per folder, not once per entry.
            if str(self.directory) in _other_versions:
                return
            _other_versions.add(str(self.directory))
            warnings.warn(
                f"label cache entries in {self.directory} were {exc}: each is rebuilt from its "
                "sources when first read (this warning is given once); claravid-cache rebuilds "
                "them all ahead of time",
                LabelCacheWarning,
                stacklevel=5,
            )
            return
        if stored:
            warnings.warn(
                f"label cache entry {path} is invalid ({exc}); rebuilt from the sources",
                LabelCacheWarning,
                stacklevel=5,
            )
            return
        if str(path) in _unrepaired_entries or str(path) in _unwritable_entries:  # warned before
            return
        _unrepaired_entries.add(str(path))
        warnings.warn(
            f"label cache entry {path} is invalid ({exc}) and the cache cannot be written to "
            "rebuild it: this frame's labels are decoded from the sources instead",
            LabelCacheWarning,
            stacklevel=5,
        )

    def _warn_not_an_entry(self, path: Path, exc: NotAnEntry) -> None:
        # Once per entry and process, like an entry that cannot be written.
        if str(path) in _unwritable_entries:
            return
        _unwritable_entries.add(str(path))
        warnings.warn(
            f"{exc}; its labels are decoded from the sources meanwhile (slower)",
            LabelCacheWarning,
            stacklevel=5,
        )

    def _warn_entry(self, path: Path, exc: OSError) -> None:
        # Once per entry and process; the frame is decoded, the other entries still written.
        if str(path) in _unwritable_entries:
            return
        _unwritable_entries.add(str(path))
        warnings.warn(
            f"{entry_error(exc, path)}; this frame's labels are decoded from the panoptic PNG "
            "in this process (slower), the other frames are cached as usual",
            LabelCacheWarning,
            stacklevel=5,
        )

    def _warn_unwritable(self, exc: OSError) -> None:
        # Once per folder and process: a DataLoader worker would otherwise warn every sample.
        if str(self.directory) in _unwritable_folders:
            return
        _unwritable_folders.add(str(self.directory))
        warnings.warn(
            f"{write_error(exc, self.directory)}; label codes are decoded from the panoptic "
            "PNGs instead (slower); set CLARAVID_CACHE or label_cache= to a writable folder",
            LabelCacheWarning,
            stacklevel=5,
        )


def _is_int(value: object) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def _window_of(codes: np.ndarray, window: tuple[int, int, int, int] | None) -> np.ndarray:
    """The whole codes, or a copy of their window (checked to lie inside)."""
    if window is None:
        return codes
    x, y, w, h = window
    _check_window(x, y, w, h, codes.shape[1], codes.shape[0])
    return codes[y : y + h, x : x + w].copy()


def _check_window(x: int, y: int, width: int, height: int, frame_w: int, frame_h: int) -> None:
    if x + width > frame_w or y + height > frame_h:
        raise ValueError(
            f"window {width}×{height} at ({x}, {y}) is not inside the {frame_w}×{frame_h} frame"
        )
