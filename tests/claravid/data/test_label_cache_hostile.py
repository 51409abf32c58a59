"""The label cache against what a hostile or unlucky file system puts in its way: a FIFO where an
entry should be, a cache folder that is a broken symbolic link, a cache of an older version,
and arguments it cannot use. Each says so once, in words, and the labels stay right.

Expected codes come from ``read_label_codes`` on the PNGs, decoded directly.
"""

import os
import signal
import warnings
from contextlib import contextmanager

import numpy as np
import pytest

from claravid.data.cache_cli import main as cache_main
from claravid.data.index import list_frames
from claravid.data.label_cache import LabelCache, LabelCacheWarning
from claravid.io import label_tiff
from claravid.io.labels import read_label_codes

#: A FIFO opened for reading blocks until a writer comes: the tests give up after this.
GUARD_SECONDS = 20


class Blocked(BaseException):
    """Raised by the alarm: a BaseException, so no ``except OSError`` on the way swallows it."""


@contextmanager
def hang_guard(seconds=GUARD_SECONDS):
    """Fail (instead of hanging the suite) when the body blocks for ``seconds``."""

    def _alarm(signum, frame):
        raise Blocked(f"blocked for {seconds} s: a FIFO was opened for reading")

    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def _sources(root, **selection):
    frames = list_frames(root, fields=["pan_seg", "dynamic_mask"], **selection)
    return [(f.paths["pan_seg"], f.paths["dynamic_mask"]) for f in frames]


def _label_messages(record):
    return [str(w.message) for w in record if issubclass(w.category, LabelCacheWarning)]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_at_an_entry_s_path_is_left_alone_not_read(claravid_root, tmp_path):
    cache = LabelCache(tmp_path / "cache")
    frame, other = _sources(claravid_root, missions=["urban_1"])[:2]
    fifo = cache.path_for(*frame)
    fifo.parent.mkdir(parents=True)
    os.mkfifo(fifo)
    with hang_guard(), warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        for _ in range(2):  # the second read says nothing more
            np.testing.assert_array_equal(cache.read(*frame), read_label_codes(*frame))
            np.testing.assert_array_equal(
                cache.read_window(*frame, 3, 2, 30, 20), read_label_codes(*frame)[2:22, 3:33]
            )
        np.testing.assert_array_equal(cache.read(*other), read_label_codes(*other))
    (message,) = _label_messages(record)
    assert f"the label cache entry {fifo} is a FIFO, not a file" in message
    assert "remove it" in message and "decoded from the sources" in message
    assert fifo.exists() and not fifo.is_file()  # never replaced
    assert cache.path_for(*other).is_file()  # the other frames are cached as usual
    with hang_guard():
        summary = cache.prepare([frame, other])
    assert summary.unwritten == [(str(frame[0]), message.split("; its labels")[0])]
    assert summary.skipped == 1 and summary.built == 0


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_claravid_cache_lists_a_fifo_and_goes_on(claravid_root, tmp_path, capsys):
    cache = LabelCache(tmp_path)
    frames = _sources(claravid_root, missions=["urban_1"])
    fifo = cache.path_for(*frames[0])
    fifo.parent.mkdir(parents=True)
    os.mkfifo(fifo)
    argv = ["--data", str(claravid_root), "--missions", "urban_1", "-o", str(tmp_path),
            "--no-progress"]  # fmt: skip
    with hang_guard():
        assert cache_main(argv) == 1  # some frames could not be cached: listed
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"skipped {frames[0][0]}: the label cache entry {fifo} is a FIFO, not a file, "
                   "and is left alone; remove it to cache this frame"]  # fmt: skip
    assert len([p for p in tmp_path.rglob("*.tif") if p.is_file()]) == len(frames) - 1


@pytest.mark.parametrize("link", ["loop", "dangling"])
def test_a_broken_link_as_the_cache_folder_warns_once(claravid_root, tmp_path, link, capsys):
    root = tmp_path / "cache"
    root.mkdir()
    if link == "loop":
        os.symlink(root / "label_codes", root / "label_codes")
    else:
        os.symlink(tmp_path / "gone" / "codes", root / "label_codes")
    cache = LabelCache(root)
    frames = _sources(claravid_root, missions=["urban_1"], altitude=["low"])
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        for frame in frames:  # was one warning per frame
            np.testing.assert_array_equal(cache.read(*frame), read_label_codes(*frame))
    (message,) = _label_messages(record)
    assert f"{root / 'label_codes'} is a symbolic link that leads nowhere" in message
    # claravid-cache: the folder cannot take any entry, one line, exit 2.
    argv = ["--data", str(claravid_root), "--missions", "urban_1", "-o", str(root), "--no-progress"]
    assert cache_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "symbolic link that leads nowhere" in err[0], err


def test_entries_of_an_older_version_warn_once_for_the_folder(claravid_root, tmp_path,
                                                              monkeypatch):  # fmt: skip
    frames = _sources(claravid_root, missions=["urban_1"], altitude=["low"])
    cache = LabelCache(tmp_path / "cache")
    monkeypatch.setattr(label_tiff, "VERSION", label_tiff.VERSION - 1)  # a cache written before
    assert cache.prepare(frames).built == len(frames) > 1
    monkeypatch.undo()
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        for frame in frames:
            np.testing.assert_array_equal(cache.read(*frame), read_label_codes(*frame))
    (message,) = _label_messages(record)  # was one per entry
    assert "were written by another version of the cache" in message
    assert str(cache.directory) in message and "once" in message
    # Each was rebuilt: a second pass reads them, quietly.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for frame in frames:
            cache.read(*frame)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"tile_size": 0}, r"tile_size=0: TIFF tiles are a positive multiple of 16"),
        ({"tile_size": 100}, r"tile_size=100: TIFF tiles are a positive multiple of 16"),
        ({"tile_size": -16}, r"tile_size=-16"),
        ({"tile_size": 256.0}, r"tile_size=256.0"),
        ({"layouts": -1}, r"layouts=-1: how many parsed entry headers to keep"),
        ({"layouts": None}, r"layouts=None: .*an integer >= 0"),
        ({"layouts": True}, r"layouts=True"),
    ],
)
def test_arguments_it_cannot_use_are_refused_when_made(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        LabelCache(tmp_path, **kwargs)


def test_arguments_at_their_bounds_work(claravid_root, tmp_path):
    frame = _sources(claravid_root, missions=["urban_1"])[0]
    cache = LabelCache(tmp_path, tile_size=16, layouts=0)  # the smallest tile, no header kept
    for _ in range(2):
        np.testing.assert_array_equal(cache.read(*frame), read_label_codes(*frame))
