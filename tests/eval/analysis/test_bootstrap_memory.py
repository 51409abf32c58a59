"""The memory a bootstrap may take: the kernel's MemAvailable, not MemFree."""

import os

import pytest

from claravid.eval.analysis import bootstrap
from claravid.infra import memory

GIB = 1 << 30
#: A machine that has been reading files: little is free, much more is available (the page
#: cache can be dropped). The probe that found it: 19.7 GiB refused with 21.8 GiB available.
MEMINFO = (
    f"MemTotal:       {64 * GIB // 1024} kB\n"
    f"MemFree:        {2 * GIB // 1024} kB\n"
    f"MemAvailable:   {int(21.8 * GIB) // 1024} kB\n"
    f"Cached:         {30 * GIB // 1024} kB\n"
)


@pytest.fixture
def page_cache_full(monkeypatch):
    monkeypatch.setattr(memory, "_read_meminfo", lambda: MEMINFO)
    real = os.sysconf

    def sysconf(name):  # what MemFree says, for a reader that would ask the OS that way
        if name == "SC_AVPHYS_PAGES":
            return 2 * GIB // 4096
        return 4096 if name == "SC_PAGE_SIZE" else real(name)

    monkeypatch.setattr(os, "sysconf", sysconf)


def test_available_memory_is_memavailable(page_cache_full):
    assert memory.available_memory() == int(21.8 * GIB) // 1024 * 1024


def test_the_bootstrap_check_reads_memavailable(page_cache_full):
    bootstrap.check_memory(int(19.7 * GIB), "resamples")  # was refused: "2.0 GiB are free"
    with pytest.raises(ValueError, match=r"need 22.0 GiB and 21.8 GiB are available: lower"):
        bootstrap.check_memory(22 * GIB, "resamples")


def test_unknown_memory_checks_nothing(monkeypatch):
    monkeypatch.setattr(memory, "_read_meminfo", lambda: None)  # not Linux
    assert memory.available_memory() is None
    bootstrap.check_memory(1 << 60, "resamples")
