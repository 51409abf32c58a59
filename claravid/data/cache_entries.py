"""One label-cache entry on disk: where it lives, how it is written, what a failed write means.

An entry of a frame's sources is ``<cache>/label_codes/<2 hex>/<fingerprint>.tif``, the
fingerprint a hash of the sources' identity (:func:`claravid.io.labels.source_identity`). It is
written under a name unique to the writer (host, process, thread, random) and renamed into
place: concurrent writers, on one machine or several sharing a network file system, never see
or leave half a file.

A failed write either proves that the cache folder cannot take any entry
(:func:`folder_refuses`: a read-only file system, a full disk or quota, the folder itself not
writable) or concerns that entry alone (a folder where it should be, one sub-folder without
permission, a transient I/O error); :mod:`claravid.data.label_cache` and
:mod:`claravid.data.cache_prepare` act on the difference.
"""

from __future__ import annotations

import errno
import os
import re
import socket
import stat
import struct
import threading
import uuid
from pathlib import Path

from claravid.io.label_tiff import SourceIdentity
from claravid.io.labels import identity_fingerprint, source_identity

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_HOST = re.sub(r"[^A-Za-z0-9.-]", "_", socket.gethostname()) or "host"
#: No room for any entry: a full disk, or the user's quota exceeded (EDQUOT, where it exists).
_EDQUOT = getattr(errno, "EDQUOT", None)
_FULL_ERRNOS = {errno.ENOSPC} | ({_EDQUOT} if _EDQUOT is not None else set())
_FOLDER_ERRNOS = {errno.EROFS, *_FULL_ERRNOS}


class LabelCacheWarning(UserWarning):
    """The label cache could not be written (labels decoded instead) or an entry was rebuilt."""


class NotAnEntry(OSError):
    """Something other than a file or folder (a FIFO, socket or device) where an entry should
    be: never opened for reading (a FIFO would block forever) nor replaced; its frame is decoded
    from the sources instead."""


_KINDS = {stat.S_IFIFO: "a FIFO", stat.S_IFSOCK: "a socket", stat.S_IFCHR: "a character device",
          stat.S_IFBLK: "a block device"}  # fmt: skip


def open_entry(path: Path) -> int:
    """A read-only descriptor on the entry file ``path``, opened without blocking.

    Raises:
        OSError: no entry there (missing, or a folder in its place).
        NotAnEntry: a FIFO, socket or device in its place, naming it and what to do.
    """
    flags = os.O_RDONLY | getattr(os, "O_BINARY", 0) | getattr(os, "O_NONBLOCK", 0)
    fd = os.open(path, flags)
    mode = os.fstat(fd).st_mode
    if stat.S_ISREG(mode):
        return fd
    os.close(fd)
    if stat.S_ISDIR(mode):  # a folder in its place: no entry there (its write fails alone)
        raise IsADirectoryError(errno.EISDIR, "not a file", str(path))
    kind = _KINDS.get(stat.S_IFMT(mode), "not a regular file")
    raise NotAnEntry(
        f"the label cache entry {path} is {kind}, not a file, and is left alone; remove it to "
        "cache this frame"
    )


class CacheWriteError(OSError):
    """The cache could not be written while preparing it (full disk, read-only folder).

    Attributes:
        reason: why and where, in words.
        written: entries written before it (none is half-written).
    """

    def __init__(self, reason: str, written: int | None = None, advice: str = "") -> None:
        if written is None:  # rebuilt from its message (a worker's error, a pickle)
            super().__init__(reason)
            self.reason, self.written = reason, None
            return
        super().__init__(
            f"{reason}; {written} entries were written before it, none is half-written; "
            f"free some space or {advice}"
        )
        self.reason, self.written = reason, written


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
    return entry_path_of(Path(directory), source_identity(pan_seg, dynamic_mask))


def entry_path_of(directory: Path, identity: SourceIdentity) -> Path:
    """The entry of sources whose identity is known (one ``stat`` per file saved)."""
    key = identity_fingerprint(identity)
    return directory / key[:2] / f"{key}.tif"


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


def folder_refuses(exc: OSError, directory: Path) -> bool:
    """Whether a failed write proves that ``directory`` cannot take any entry.

    True for a read-only file system, a full disk or quota, and when the folder itself (or,
    while it does not exist, the nearest path above it) is not a writable folder. Anything else
    (a folder where one entry should be, one sub-folder without permission, a transient I/O
    error) concerns that entry alone.
    """
    if exc.errno in _FOLDER_ERRNOS or broken_link(directory) is not None:
        return True
    anchor = Path(directory)
    while not anchor.exists() and anchor != anchor.parent:
        anchor = anchor.parent
    return not anchor.is_dir() or not os.access(anchor, os.W_OK | os.X_OK)


def broken_link(directory: Path) -> Path | None:
    """The symbolic link on the way to ``directory`` (itself or a folder above it) that leads
    nowhere, dangling or in a loop; None when there is none. Nothing can be written below it."""
    path = Path(directory)
    while not path.exists():  # False for a dangling link and for a loop (ELOOP)
        if path.is_symlink():
            return path
        if path == path.parent:
            return None
        path = path.parent
    return None


def write_error(exc: OSError, directory: Path) -> str:
    """Why writing the cache failed, in words, naming the folder."""
    if exc.errno in _FULL_ERRNOS:
        full = "disk quota is exceeded" if exc.errno == _EDQUOT else "disk is full"
        return f"the {full} (no space left for the label cache in {directory})"
    link = broken_link(directory)
    if link is not None:
        return (
            f"the label cache folder {directory} cannot be made: {link} is a symbolic link "
            "that leads nowhere (dangling, or a loop)"
        )
    if exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
        return f"the label cache folder {directory} is not writable ({exc.strerror})"
    return f"cannot write the label cache in {directory} ({exc.strerror or exc})"


def entry_error(exc: OSError, path: Path) -> str:
    """Why one entry could not be written, in words, naming it."""
    return f"cannot write the label cache entry {path} ({exc.strerror or exc})"
