"""Preparing the label cache up front: every missing or invalid entry of a selection, built in
worker processes (``LabelCache.prepare``, ``claravid-cache``, training before its first step).

An entry present is checked whole (header, sources and every tile's CRC) before it counts as
done. A frame whose label files cannot be read is listed (``failed``), as is one whose entry
location alone refuses the write (``unwritten``); a cache folder that cannot take any entry
stops the preparation with :class:`~claravid.data.cache_entries.CacheWriteError`.
"""

from __future__ import annotations

import errno
import multiprocessing
import os
import time
from collections.abc import Iterable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from tqdm.auto import tqdm

from claravid.data.cache_entries import (
    CacheWriteError,
    NotAnEntry,
    entry_error,
    entry_path_of,
    folder_refuses,
    write_atomic,
    write_error,
)
from claravid.io import label_tiff
from claravid.io.label_tiff import InvalidEntry, SourceIdentity, TileLayout
from claravid.io.labels import read_label_codes, source_identity

Sources = tuple[Path, Path | None]


class PreparedCache(Protocol):
    """What preparing entries needs of a cache (a :class:`~claravid.data.label_cache.LabelCache`,
    which calls in here: a protocol keeps the imports one way)."""

    directory: Path
    tile_size: int

    def advice(self) -> str: ...

    def open_valid(
        self, path: Path, pan_seg: Path, identity: SourceIdentity, verify: bool = False
    ) -> tuple[int, TileLayout]: ...


@dataclass
class PrepareSummary:
    """What :meth:`LabelCache.prepare` did.

    Attributes:
        directory: the cache folder.
        frames: frames of the selection (of this shard).
        built: entries written now.
        skipped: entries already present and valid.
        failed: ``(panoptic PNG, reason)`` of frames whose sources could not be read.
        unwritten: ``(panoptic PNG, reason)`` of frames whose sources were read but whose entry
            could not be written there (its location alone refused it; the others were).
        bytes_built: bytes written now.
        bytes_total: bytes of every entry of the selection now in the cache.
        seconds: wall time.
    """

    directory: Path
    frames: int = 0
    built: int = 0
    skipped: int = 0
    failed: list[tuple[str, str]] = field(default_factory=list)
    unwritten: list[tuple[str, str]] = field(default_factory=list)
    bytes_built: int = 0
    bytes_total: int = 0
    seconds: float = 0.0

    @property
    def bytes_per_frame(self) -> float:
        """Mean entry size over the selection's cached frames (0 when none)."""
        cached = self.built + self.skipped
        return self.bytes_total / cached if cached else 0.0


def prepare_entries(
    cache: PreparedCache,
    frames: Iterable[Sources],
    *,
    workers: int = 0,
    progress: bool = False,
    shard: tuple[int, int] = (0, 1),
) -> PrepareSummary:
    """Build every missing or invalid entry of ``frames`` in ``cache``, in worker processes.

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
    start = time.perf_counter()
    k, n = shard
    if not (n >= 1 and 0 <= k < n):
        raise ValueError(f"shard must be (k, n) with 0 <= k < n, got {shard}")
    unique = list(dict.fromkeys((Path(p), None if d is None else Path(d)) for p, d in frames))
    chosen = unique[k::n]
    summary = PrepareSummary(cache.directory, frames=len(chosen))
    jobs = []
    for pan, dyn in chosen:
        missing = [p for p in (pan, dyn) if p is not None and not p.is_file()]
        if missing:
            summary.failed.append((str(pan), f"file not found: {missing[0]}"))
            continue
        try:
            identity = source_identity(pan, dyn)
        except OSError as exc:
            summary.failed.append((str(pan), f"cannot read it ({exc})"))
            continue
        entry = entry_path_of(cache.directory, identity)
        try:
            fd, _ = cache.open_valid(entry, pan, identity, verify=True)
        except NotAnEntry as exc:  # a FIFO or device in its place: listed, left alone
            summary.unwritten.append((str(pan), str(exc)))
            continue
        except (OSError, InvalidEntry):  # missing, unreadable or invalid: (re)build it
            jobs.append((str(pan), None if dyn is None else str(dyn), cache.tile_size))
            continue
        summary.skipped += 1
        summary.bytes_total += os.fstat(fd).st_size
        os.close(fd)
    summary.bytes_total += _build(cache, jobs, summary, workers, progress)
    order = {str(pan): i for i, (pan, _) in enumerate(chosen)}
    for listed in (summary.failed, summary.unwritten):  # in the selection's order
        listed.sort(key=lambda failure: order[failure[0]])
    summary.seconds = time.perf_counter() - start
    return summary


def _build(
    cache: PreparedCache, jobs: list, summary: PrepareSummary, workers: int, progress: bool
) -> int:
    bar = tqdm(total=len(jobs), desc="label cache", unit="frame", disable=not progress or not jobs)
    executor = None
    try:
        if workers <= 1 or len(jobs) <= 1:
            outputs: Iterable = (_build_entry(cache.directory, *job) for job in jobs)
        else:
            executor = ProcessPoolExecutor(
                max_workers=workers,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=_init_worker,
            )
            outputs = executor.map(_build_job, [(cache.directory, *job) for job in jobs])
        for pan, size, unreadable, unwritten, folder_errno in outputs:
            if folder_errno is not None:
                error = CacheWriteError(unwritten, summary.built, cache.advice())
                error.errno = folder_errno
                raise error
            if unreadable is not None:
                summary.failed.append((pan, unreadable))
            elif unwritten is not None:
                summary.unwritten.append((pan, unwritten))
            else:
                summary.built += 1
                summary.bytes_built += size
            bar.update(1)
    finally:
        bar.close()
        if executor is not None:
            executor.shutdown(cancel_futures=True)
    return summary.bytes_built


def _init_worker() -> None:
    import cv2

    cv2.setNumThreads(1)  # the processes already fill the cores


Built = tuple[str, int, str | None, str | None, int | None]


def _build_job(job: tuple) -> Built:
    return _build_entry(*job)


def _build_entry(directory: Path, pan_seg: str, dynamic_mask: str | None, tile_size: int) -> Built:
    """Decode a frame's sources and write its entry.

    Returns ``(pan, bytes, unreadable, unwritten, folder errno)``: why the sources could not be
    read, or why the entry could not be written, and the errno when the folder itself cannot
    take any entry (which stops the preparation). Errors come back as values, not exceptions: a
    worker's exception may not survive pickling, and one bad frame must not stop the others.
    """
    pan, dyn = Path(pan_seg), None if dynamic_mask is None else Path(dynamic_mask)
    try:
        identity = source_identity(pan, dyn)  # before decoding: what was read is what's named
        codes = read_label_codes(pan, dyn)
    except (OSError, ValueError) as exc:  # a missing, cut or foreign source file
        return pan_seg, 0, str(exc), None, None
    path = entry_path_of(directory, identity)
    data = label_tiff.encode_codes(codes, tile_size, identity)
    try:
        write_atomic(path, data)
    except OSError as exc:
        if folder_refuses(exc, directory):
            return pan_seg, 0, None, write_error(exc, directory), exc.errno or errno.EIO
        return pan_seg, 0, None, entry_error(exc, path), None
    return pan_seg, len(data), None, None, None
