"""Refusing a backbone that cannot fit in memory before allocating it.

DINOv3's 7B backbone holds 6.7 billion parameters: 27 GB in float32. Building it on a machine
without that much free memory would swap or be killed by the kernel long after the call, with no
message; `check_memory` says how much is needed and how much is available instead.
"""

from __future__ import annotations

import re
from pathlib import Path

MEMINFO = Path("/proc/meminfo")
GIB = 1 << 30


class NotEnoughMemoryError(MemoryError):
    """What is about to be allocated does not fit in the available memory."""


def _read_meminfo() -> str | None:
    """The text of ``/proc/meminfo`` (Linux), or None where there is none."""
    try:
        return MEMINFO.read_text()
    except OSError:
        return None


def available_memory() -> int | None:
    """Bytes of memory available to new allocations without swapping, or None when unknown.

    ``MemAvailable`` of ``/proc/meminfo``: the kernel's estimate of free memory plus the caches
    it can drop (not ``MemFree``, which leaves those out and reads far too low).
    """
    text = _read_meminfo()
    match = re.search(r"^MemAvailable:\s+(\d+)\s*kB", text or "", re.M)
    return int(match.group(1)) * 1024 if match else None


def check_memory(needed: int, what: str) -> None:
    """Raise `NotEnoughMemoryError` when ``needed`` bytes exceed the available memory.

    Nothing is checked where the available memory is unknown (not Linux).

    Args:
        needed: Bytes about to be allocated.
        what: What needs them, for the message (e.g. ``"backbone dinov3_vit7b16 (float32)"``).
    """
    available = available_memory()
    if available is None or needed <= available:
        return
    raise NotEnoughMemoryError(
        f"{what} needs {needed / GIB:.1f} GiB of memory, but only {available / GIB:.1f} GiB "
        "are available (MemAvailable of /proc/meminfo): free memory, use a machine with more, "
        "or pick a smaller backbone"
    )
