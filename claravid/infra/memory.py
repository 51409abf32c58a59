"""How much memory new allocations can take now, as the kernel estimates it (Linux).

``MemAvailable`` of ``/proc/meminfo``: free memory plus the caches the kernel can drop. Not
``MemFree`` (or ``sysconf("SC_AVPHYS_PAGES")``, the same number), which leaves those caches out
and reads far too low on a machine that has been reading files: 19.7 GiB refused where 21.8
GiB were available. Building a backbone and a bootstrap both check against it before they
allocate.
"""

from __future__ import annotations

import re
from pathlib import Path

MEMINFO = Path("/proc/meminfo")
GIB = 1 << 30


def _read_meminfo() -> str | None:
    """The text of ``/proc/meminfo``, or None where there is none (not Linux)."""
    try:
        return MEMINFO.read_text()
    except OSError:
        return None


def available_memory() -> int | None:
    """Bytes of memory available to new allocations without swapping, or None when unknown."""
    match = re.search(r"^MemAvailable:\s+(\d+)\s*kB", _read_meminfo() or "", re.M)
    return int(match.group(1)) * 1024 if match else None
