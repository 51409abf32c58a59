"""A per-image cache of complexity values, so reruns and the evaluator do not decode twice.

One SQLite file, ``$CLARAVID_CACHE/dsp.sqlite3`` (default ``~/.cache/claravid``), keyed by the
resolved path, file size, modification time (ns), metric, blur setting and kernel size, and the
algorithm version: a file that changes, or a different setting, misses. Only the parent process
touches it (workers compute, the parent stores), so there is one writer per run. A cache that
cannot be opened or written (read-only home, locked file on a network disk) is switched off with
a warning; it never fails a run. On a cluster, point ``CLARAVID_CACHE`` at node-local disk.
"""

from __future__ import annotations

import os
import sqlite3
import warnings
from collections.abc import Iterable
from pathlib import Path

from claravid.infra.cachedir import cache_dir

__all__ = ["ComplexityCache", "cache_dir", "cache_key"]  # cache_dir: re-exported, one helper

#: Bump when a metric's values change, so old entries are never reused.
ALGORITHM_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS complexity (
    path TEXT NOT NULL, size INTEGER NOT NULL, mtime_ns INTEGER NOT NULL,
    metric TEXT NOT NULL, blur INTEGER NOT NULL, ksize INTEGER NOT NULL, version INTEGER NOT NULL,
    value REAL NOT NULL, height INTEGER NOT NULL, width INTEGER NOT NULL,
    PRIMARY KEY (path, size, mtime_ns, metric, blur, ksize, version)
)
"""

CacheKey = tuple[str, int, int, str, int, int, int]


def cache_key(path: str | Path, metric: str, blur: bool, ksize: int) -> CacheKey | None:
    """The key of one file's value, or None when the file cannot be stat'ed."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    # Without blur the kernel size plays no part, so it does not split the cache.
    return (
        str(Path(path).resolve()),
        st.st_size,
        st.st_mtime_ns,
        metric,
        int(bool(blur)),
        int(ksize) if blur else 0,
        ALGORITHM_VERSION,
    )


class ComplexityCache:
    """Look up and store per-image values; every failure disables the cache with one warning.

    Args:
        path: the SQLite file; default ``cache_dir() / "dsp.sqlite3"``.
    """

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else cache_dir() / "dsp.sqlite3"
        self._conn: sqlite3.Connection | None = None
        self.enabled = True

    def _disable(self, exc: BaseException) -> None:
        warnings.warn(
            f"complexity cache {self.path} switched off ({exc}); values are computed but not "
            "cached. Set CLARAVID_CACHE to a writable local folder, or pass --no-cache",
            RuntimeWarning,
            stacklevel=3,
        )
        self.enabled = False
        self.close()

    def _connect(self) -> sqlite3.Connection | None:
        if not self.enabled:
            return None
        if self._conn is None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                conn = sqlite3.connect(self.path, timeout=30)
                conn.execute(_SCHEMA)
                conn.commit()
                self._conn = conn
            except (sqlite3.Error, OSError) as exc:
                self._disable(exc)
                return None
        return self._conn

    def get_many(self, keys: Iterable[CacheKey]) -> dict[CacheKey, tuple[float, int, int]]:
        """Cached (value, height, width) for the keys that are present."""
        conn = self._connect()
        if conn is None:
            return {}
        found: dict[CacheKey, tuple[float, int, int]] = {}
        try:
            for key in keys:
                row = conn.execute(
                    "SELECT value, height, width FROM complexity WHERE path=? AND size=? AND "
                    "mtime_ns=? AND metric=? AND blur=? AND ksize=? AND version=?",
                    key,
                ).fetchone()
                if row is not None:
                    found[key] = (float(row[0]), int(row[1]), int(row[2]))
        except sqlite3.Error as exc:
            self._disable(exc)
        return found

    def put_many(self, items: Iterable[tuple[CacheKey, float, int, int]]) -> None:
        """Store (key, value, height, width) rows, replacing older rows with the same key."""
        conn = self._connect()
        if conn is None:
            return
        try:
            with conn:
                conn.executemany(
                    "INSERT OR REPLACE INTO complexity VALUES (?,?,?,?,?,?,?,?,?,?)",
                    [(*key, value, h, w) for key, value, h, w in items],
                )
        except sqlite3.Error as exc:
            self._disable(exc)

    def close(self) -> None:
        """Close the connection (it reopens on the next use while enabled)."""
        if self._conn is not None:
            self._conn.close()
            self._conn = None
