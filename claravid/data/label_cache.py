"""``LabelCache``: frames' label codes prepared once, then read whole or by window.

An entry is a tiled TIFF (:mod:`claravid.io.label_tiff`) named after the fingerprint (path, size,
mtime) of its source files, so an edited source misses instead of serving stale labels. A
630×630 training crop reads the ~16 tiles it touches instead of decoding a 12 MP PNG.

Entries are written under a name unique to the writer (host, process, thread, random) and
renamed into place: concurrent writers, on one machine or several sharing a network file
system, never see or leave half a file. An entry that fails its checks (cut, corrupt, foreign,
another size) is rebuilt from the sources, never served. When the cache cannot be written
(read-only, full disk) reads fall back to decoding the sources, with one warning per process;
:meth:`LabelCache.prepare` instead stops with an error that says why and where.
"""

from __future__ import annotations

import errno
import multiprocessing
import os
import re
import socket
import struct
import threading
import time
import uuid
import warnings
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from claravid.infra.cachedir import cache_dir
from claravid.io import label_tiff
from claravid.io.label_tiff import InvalidEntry, TileLayout
from claravid.io.labels import read_label_codes, source_fingerprint

Sources = tuple[Path, Path | None]

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_HOST = re.sub(r"[^A-Za-z0-9.-]", "_", socket.gethostname()) or "host"
_warned_unwritable: set[str] = set()  # folders that refused a write: warned once, not retried


class LabelCacheWarning(UserWarning):
    """The label cache could not be written (labels decoded instead) or an entry was rebuilt."""


class CacheWriteError(OSError):
    """The cache could not be written while preparing it (full disk, read-only folder)."""


@dataclass
class PrepareSummary:
    """What :meth:`LabelCache.prepare` did.

    Attributes:
        directory: the cache folder.
        frames: frames of the selection (of this shard).
        built: entries written now.
        skipped: entries already present and valid.
        failed: ``(panoptic PNG, reason)`` of frames whose sources could not be read.
        bytes_built: bytes written now.
        bytes_total: bytes of every entry of the selection now in the cache.
        seconds: wall time.
    """

    directory: Path
    frames: int = 0
    built: int = 0
    skipped: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    bytes_built: int = 0
    bytes_total: int = 0
    seconds: float = 0.0

    @property
    def bytes_per_frame(self) -> float:
        """Mean entry size over the selection's cached frames (0 when none)."""
        cached = self.built + self.skipped
        return self.bytes_total / cached if cached else 0.0


def png_shape(path: Path) -> tuple[int, int] | None:
    """(height, width) from a PNG's header (24 bytes read), or None when it is not a PNG."""
    with open(path, "rb") as fh:
        head = fh.read(24)
    if len(head) < 24 or not head.startswith(_PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return None
    width, height = struct.unpack(">II", head[16:24])
    return height, width


def entry_path(directory: Path, pan_seg: Path, dynamic_mask: Path | None) -> Path:
    """``directory/<2 hex>/<fingerprint>.tif``: the entry of a frame's sources."""
    dyn = None if dynamic_mask is None else Path(dynamic_mask)
    key = source_fingerprint(Path(pan_seg), dyn)
    return Path(directory) / key[:2] / f"{key}.tif"


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` under a name unique to this writer, then rename it in place.

    The temporary name carries host, process, thread and a random part: two threads, processes
    or machines (a cache on a network file system) writing one entry never share it. On any
    failure the temporary file is removed, so nothing half-written remains.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.parent / (
        f".{path.name}.{_HOST}.{os.getpid()}.{threading.get_ident()}.{uuid.uuid4().hex}.tmp"
    )
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _write_error(exc: OSError, directory: Path) -> str:
    """Why writing the cache failed, in words, naming the folder."""
    if exc.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
        return f"the disk is full (no space left for the label cache in {directory})"
    if exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
        return f"the label cache folder {directory} is not writable ({exc.strerror})"
    return f"cannot write the label cache in {directory} ({exc.strerror or exc})"


class LabelCache:
    """Label codes of frames, stored once as tiled TIFFs under ``directory/label_codes``.

    Args:
        directory: the cache root; None: ``$CLARAVID_CACHE`` or ``~/.cache/claravid``.
        tile_size: tile side of the entries this cache writes (reading takes any).
    """

    def __init__(self, directory: str | Path | None = None, tile_size: int = label_tiff.TILE):
        self.directory = Path(directory) if directory is not None else cache_dir()
        self.directory = self.directory / "label_codes"
        self.tile_size = tile_size
        # Parsed headers of entries read before, keyed by path and checked against the file's
        # identity (inode, size, mtime): a warm window read is one open and a few reads.
        self._layouts: dict[str, tuple[tuple[int, int, int], TileLayout]] = {}

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

        Idempotent: entries present and valid are counted as skipped, not rewritten.

        Args:
            frames: ``(panoptic PNG, dynamic mask or None)`` of each frame.
            workers: worker processes; 0 or 1 builds in this process.
            progress: show a progress bar on stderr.
            shard: ``(k, n)``: only every n-th frame from the k-th (a job array's part).

        Raises:
            CacheWriteError: the cache cannot be written (full disk, read-only); the message
                says which and where. Entries written before stay; none is half-written.
        """
        start = time.perf_counter()
        k, n = shard
        if not (n >= 1 and 0 <= k < n):
            raise ValueError(f"shard must be (k, n) with 0 <= k < n, got {shard}")
        unique = list(dict.fromkeys((Path(p), None if d is None else Path(d)) for p, d in frames))
        chosen = unique[k::n]
        summary = PrepareSummary(self.directory, frames=len(chosen))
        jobs = []
        for pan, dyn in chosen:
            missing = [p for p in (pan, dyn) if p is not None and not p.is_file()]
            if missing:
                summary.failed.append((str(pan), f"file not found: {missing[0]}"))
                continue
            try:
                fd, _ = self._open_valid(self.path_for(pan, dyn), pan)
            except (OSError, InvalidEntry):  # missing, unreadable or invalid: (re)build it
                jobs.append((str(pan), None if dyn is None else str(dyn), self.tile_size))
                continue
            summary.skipped += 1
            summary.bytes_total += os.fstat(fd).st_size
            os.close(fd)
        summary.bytes_total += self._build(jobs, summary, workers, progress)
        order = {str(pan): i for i, (pan, _) in enumerate(chosen)}
        summary.failed.sort(key=lambda failure: order[failure[0]])  # in the selection's order
        summary.seconds = time.perf_counter() - start
        return summary

    # --------------------------------------------------------------------------------------

    def _build(self, jobs: list, summary: PrepareSummary, workers: int, progress: bool) -> int:
        bar = tqdm(
            total=len(jobs), desc="label cache", unit="frame", disable=not progress or not jobs
        )
        executor = None
        try:
            if workers <= 1 or len(jobs) <= 1:
                outputs: Iterable = (_build_entry(self.directory, *job) for job in jobs)
            else:
                executor = ProcessPoolExecutor(
                    max_workers=workers,
                    mp_context=multiprocessing.get_context("spawn"),
                    initializer=_init_worker,
                )
                outputs = executor.map(_build_job, [(self.directory, *job) for job in jobs])
            for pan, size, failure, write_errno in outputs:
                if write_errno is not None:
                    error = CacheWriteError(
                        f"{failure}; {summary.built} entries were written before it, none is "
                        "half-written; free some space or choose another cache folder "
                        "(--cache-dir, CLARAVID_CACHE)"
                    )
                    error.errno = write_errno
                    raise error
                if failure is not None:
                    summary.failed.append((pan, failure))
                else:
                    summary.built += 1
                    summary.bytes_built += size
                bar.update(1)
        finally:
            bar.close()
            if executor is not None:
                executor.shutdown(cancel_futures=True)
        return summary.bytes_built

    def _open_valid(self, path: Path, pan_seg: Path) -> tuple[int, TileLayout]:
        """An open descriptor on a valid entry and its layout; raises when missing or invalid."""
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_BINARY", 0))
        try:
            st = os.fstat(fd)
            identity = (st.st_ino, st.st_size, st.st_mtime_ns)
            known = self._layouts.get(str(path))
            if known is not None and known[0] == identity:
                return fd, known[1]
            layout = label_tiff.read_layout(fd, png_shape(pan_seg), path.name)
            self._layouts[str(path)] = (identity, layout)
            return fd, layout
        except BaseException:
            os.close(fd)
            raise

    def _read(
        self, pan_seg: Path, dynamic_mask: Path | None, window: tuple[int, int, int, int] | None
    ) -> np.ndarray:
        path = self.path_for(pan_seg, dynamic_mask)
        try:
            fd, layout = self._open_valid(path, pan_seg)
        except OSError:  # missing, or a cache folder we cannot even read: decode instead
            pass
        except InvalidEntry as exc:
            self._rebuilt(path, exc)
        else:
            try:
                x, y, w, h = window or (0, 0, layout.width, layout.height)
                _check_window(x, y, w, h, layout.width, layout.height)
                return label_tiff.read_window(fd, layout, x, y, w, h)
            except InvalidEntry as exc:
                self._rebuilt(path, exc)
            finally:
                os.close(fd)
        codes = read_label_codes(pan_seg, dynamic_mask)
        if str(self.directory) not in _warned_unwritable:  # once refused, not encoded again
            try:
                write_atomic(path, label_tiff.encode_codes(codes, self.tile_size))
            except OSError as exc:
                self._warn_unwritable(exc)
        if window is None:
            return codes
        x, y, w, h = window
        _check_window(x, y, w, h, codes.shape[1], codes.shape[0])
        return codes[y : y + h, x : x + w].copy()

    def _rebuilt(self, path: Path, exc: InvalidEntry) -> None:
        self._layouts.pop(str(path), None)
        warnings.warn(
            f"label cache entry {path} is invalid ({exc}); rebuilt from the sources",
            LabelCacheWarning,
            stacklevel=4,
        )

    def _warn_unwritable(self, exc: OSError) -> None:
        # Once per folder and process: a DataLoader worker would otherwise warn every sample.
        if str(self.directory) in _warned_unwritable:
            return
        _warned_unwritable.add(str(self.directory))
        warnings.warn(
            f"{_write_error(exc, self.directory)}; label codes are decoded from the panoptic "
            "PNGs instead (slower); set CLARAVID_CACHE or label_cache= to a writable folder",
            LabelCacheWarning,
            stacklevel=4,
        )


def _check_window(x: int, y: int, width: int, height: int, frame_w: int, frame_h: int) -> None:
    if x + width > frame_w or y + height > frame_h:
        raise ValueError(
            f"window {width}×{height} at ({x}, {y}) is not inside the {frame_w}×{frame_h} frame"
        )


def _init_worker() -> None:
    import cv2

    cv2.setNumThreads(1)  # the processes already fill the cores


def _build_job(job: tuple) -> tuple[str, int, str | None, int | None]:
    return _build_entry(*job)


def _build_entry(
    directory: Path, pan_seg: str, dynamic_mask: str | None, tile_size: int
) -> tuple[str, int, str | None, int | None]:
    """Decode a frame's sources and write its entry: ``(pan, bytes, failure, write errno)``.

    Errors come back as values, not exceptions: a worker's exception may not survive pickling,
    and one unreadable frame must not stop the others.
    """
    pan, dyn = Path(pan_seg), None if dynamic_mask is None else Path(dynamic_mask)
    try:
        codes = read_label_codes(pan, dyn)
        path = entry_path(directory, pan, dyn)
    except (OSError, ValueError) as exc:  # a missing, cut or foreign source file
        return pan_seg, 0, str(exc), None
    data = label_tiff.encode_codes(codes, tile_size)
    try:
        write_atomic(path, data)
    except OSError as exc:
        return pan_seg, 0, _write_error(exc, directory), exc.errno or errno.EIO
    return pan_seg, len(data), None, None
