"""Refusing a backbone that cannot fit in memory before allocating it.

DINOv3's 7B backbone holds 6.7 billion parameters: 27 GB in float32. Building it on a machine
without that much free memory would swap or be killed by the kernel long after the call, with no
message; `check_memory` says how much is needed and how much is available instead.
"""

from __future__ import annotations

from claravid.infra.memory import GIB, available_memory


class NotEnoughMemoryError(MemoryError):
    """What is about to be allocated does not fit in the available memory."""


def check_memory(needed: int, what: str) -> None:
    """Raise `NotEnoughMemoryError` when ``needed`` bytes exceed the available memory.

    Nothing is checked where the available memory is unknown (not Linux). The available memory
    is the kernel's ``MemAvailable`` (`claravid.infra.memory`).

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
