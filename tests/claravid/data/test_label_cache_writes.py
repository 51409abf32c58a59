"""LabelCache when writing fails, what it keeps in memory, and its life in worker processes.

- One entry that cannot be written (a folder in its place, one sub-folder refused, a transient
  I/O error) concerns that entry alone: one warning names it, the other frames are cached.
  Only what proves the folder cannot take any entry (read-only file system, full disk) turns
  writing off (those cases: test_label_cache.py).
- A read-only cache holding an invalid entry says so once, and never that it was rebuilt.
- Parsed headers are bounded and hold nothing of tifffile; a cache and a dataset that read
  through it pickle, so DataLoader workers started by spawn or forkserver work.

Expected codes come from ``read_label_codes`` on the PNGs, decoded directly.
"""

import errno
import gc
import os
import pickle
import tracemalloc
import warnings
import weakref

import numpy as np
import pytest
import tifffile
import torch
from torch.utils.data import DataLoader

import claravid.io.label_tiff as label_tiff
from claravid.data.index import list_frames
from claravid.data.label_cache import LabelCache, LabelCacheWarning
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.io import modalities as m
from claravid.io.labels import read_label_codes


def _sources(root, **selection):
    frames = list_frames(root, fields=["pan_seg", "dynamic_mask"], **selection)
    return [(f.paths["pan_seg"], f.paths["dynamic_mask"]) for f in frames]


def _in_two_folders(cache, sources):
    """Two frames whose entries lie in different sub-folders of the cache."""
    first = sources[0]
    other = next(s for s in sources if cache.path_for(*s).parent != cache.path_for(*first).parent)
    return first, other


def _messages(record):
    return [str(w.message) for w in record if issubclass(w.category, LabelCacheWarning)]


def _read_all(cache, sources, times=2):
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        for _ in range(times):
            for pan, dyn in sources:
                np.testing.assert_array_equal(cache.read(pan, dyn), read_label_codes(pan, dyn))
                np.testing.assert_array_equal(
                    cache.read_window(pan, dyn, 5, 3, 40, 30),
                    read_label_codes(pan, dyn)[3:33, 5:45],
                )
    return _messages(record)


def test_a_folder_at_one_entry_s_path_leaves_the_others_cached(claravid_root, tmp_path):
    cache = LabelCache(tmp_path / "cache")
    blocked, other = _in_two_folders(cache, _sources(claravid_root, missions="urban_1"))
    cache.path_for(*blocked).mkdir(parents=True)
    (cache.path_for(*blocked) / "keep").write_text("")  # not an empty folder either
    messages = _read_all(cache, [blocked, other])
    assert len(messages) == 1, messages  # one warning, not one per read
    assert str(cache.path_for(*blocked)) in messages[0]
    assert cache.path_for(*other).is_file()  # the other frame is cached
    third = _sources(claravid_root, missions="rural_1")[0]
    cache.read(*third)
    assert cache.path_for(*third).is_file()


def test_one_refused_sub_folder_leaves_the_others_cached(claravid_root, tmp_path, monkeypatch):
    """EACCES on one sub-folder (simulated: the tests may run as root, who passes chmod)."""
    cache = LabelCache(tmp_path / "cache")
    refused, other = _in_two_folders(cache, _sources(claravid_root, missions="urban_1"))
    folder = str(cache.path_for(*refused).parent)
    real_open = os.open

    def open_refusing_one_folder(path, flags, *args, **kwargs):
        if flags & os.O_CREAT and str(path).startswith(folder + os.sep):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", open_refusing_one_folder)
    messages = _read_all(cache, [refused, other])
    assert len(messages) == 1 and str(cache.path_for(*refused)) in messages[0], messages
    assert "Permission denied" in messages[0]
    assert not cache.path_for(*refused).exists() and cache.path_for(*other).is_file()


def test_a_transient_io_error_leaves_the_other_entries_cached(claravid_root, tmp_path, monkeypatch):
    cache = LabelCache(tmp_path / "cache")
    first, second = _sources(claravid_root, missions="rural_1")[:2]
    real_write, calls = os.write, []

    def write_failing_once(fd, data):
        calls.append(fd)
        if len(calls) == 1:
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", write_failing_once)
    messages = _read_all(cache, [first, second])
    assert len(messages) == 1 and str(cache.path_for(*first)) in messages[0], messages
    assert cache.path_for(*second).is_file() and not cache.path_for(*first).exists()
    assert sorted(p.name for p in cache.directory.rglob("*") if p.is_file()) == [
        cache.path_for(*second).name
    ]  # no temporary file left behind


def test_a_read_only_cache_with_an_invalid_entry_says_so_once(claravid_root, tmp_path, monkeypatch):
    cache = LabelCache(tmp_path / "cache")
    cut, fine = _sources(claravid_root, missions="urban_1")[:2]
    cache.prepare([cut, fine])
    entry = cache.path_for(*cut)
    entry.write_bytes(entry.read_bytes()[:-40])
    real_open = os.open

    def read_only(path, flags, *args, **kwargs):
        if flags & os.O_CREAT:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", read_only)
    messages = _read_all(cache, [cut, fine], times=3)
    assert not [m for m in messages if "rebuilt" in m], messages
    about_entry = [m for m in messages if str(entry) in m]
    assert len(about_entry) == 1 and "invalid" in about_entry[0], messages
    assert "decoded from the sources" in about_entry[0]


def _counting_parses(monkeypatch):
    """Count the entry headers tifffile parses (and keep weak references to its files and
    their first pages)."""
    real, opened = tifffile.TiffFile, []

    def counting(*args, **kwargs):
        tif = real(*args, **kwargs)
        opened.append((weakref.ref(tif), weakref.ref(tif.pages.first)))
        return tif

    monkeypatch.setattr(label_tiff.tifffile, "TiffFile", counting)
    return opened


def test_parsed_headers_are_bounded_least_recently_used_first(claravid_root, tmp_path, monkeypatch):
    sources = _sources(claravid_root, missions="rural_1")[:5]
    cache = LabelCache(tmp_path / "cache", layouts=3)
    cache.prepare(sources)
    opened = _counting_parses(monkeypatch)

    def parses_of(pan, dyn):
        before = len(opened)
        cache.read_window(pan, dyn, 0, 0, 8, 8)
        return len(opened) - before

    # Kept, least recent first: [2, 3, 4] after the first five reads.
    assert [parses_of(*s) for s in sources] == [1, 1, 1, 1, 1]
    assert parses_of(*sources[4]) == 0  # [2, 3, 4]
    assert parses_of(*sources[2]) == 0  # [3, 4, 2]: a read makes it the most recent
    assert parses_of(*sources[0]) == 1  # [4, 2, 0]: 3 dropped (first in, but not last used)
    assert parses_of(*sources[3]) == 1  # [2, 0, 3]
    assert parses_of(*sources[2]) == 0  # [0, 3, 2]
    assert parses_of(*sources[4]) == 1


def test_a_parsed_header_keeps_its_tile_tables_only(tmp_path, monkeypatch):
    """About 20 bytes a tile (offset, byte count, CRC) and nothing of tifffile: no file or
    page object outlives a read. 30 entries of 400×300 in 16-pixel tiles (475 tiles each)."""
    rng = np.random.default_rng(0)
    sources = []
    for i in range(30):
        semantic = rng.integers(0, 10, (300, 400)).astype(np.uint8)
        sources.append(tmp_path / f"pan{i}.png")
        m.write_pan_seg(sources[-1], semantic, np.zeros(semantic.shape, np.int64))
    cache = LabelCache(tmp_path / "cache", tile_size=16)
    cache.prepare([(p, None) for p in sources])
    opened = _counting_parses(monkeypatch)
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.take_snapshot()
        for pan in sources:
            cache.read_window(pan, None, 0, 0, 4, 4)
        gc.collect()
        kept = sum(d.size_diff for d in tracemalloc.take_snapshot().compare_to(before, "filename"))
    finally:
        tracemalloc.stop()
    assert len(opened) == 30
    assert [(tif(), page()) for tif, page in opened] == [(None, None)] * 30
    tiles = 19 * 25
    assert kept / 30 < 32 * tiles, kept / 30  # 4 kB per tile table of a 12 MP frame


def test_a_cache_pickles_after_reads_and_reads_the_same(claravid_root, tmp_path):
    sources = _sources(claravid_root, missions="urban_1")[:2]
    cache = LabelCache(tmp_path / "cache", tile_size=16, layouts=7)
    for pan, dyn in sources:
        cache.read_window(pan, dyn, 3, 4, 20, 10)
    copy = pickle.loads(pickle.dumps(cache))
    assert (copy.directory, copy.tile_size, copy.max_layouts) == (cache.directory, 16, 7)
    for pan, dyn in sources:
        np.testing.assert_array_equal(
            copy.read_window(pan, dyn, 3, 4, 20, 10), read_label_codes(pan, dyn)[4:14, 3:23]
        )


def _dataset(root, cache):
    return ClaraVidSegmentation(root, split="all", missions=["urban_1"], altitude=["low"],
                                palette="uavid", label_cache=cache)  # fmt: skip


def test_a_dataset_pickles_after_reading_through_the_cache(claravid_root, tmp_path):
    ds = _dataset(claravid_root, tmp_path / "cache")
    ds.prepare_label_cache()
    first = ds[0]  # both read from entries that exist
    ds.read_window(1, (2, 3, 30, 20))
    copy = pickle.loads(pickle.dumps(ds))
    again = copy[0]
    assert torch.equal(again["mask"], first["mask"]) and torch.equal(again["image"], first["image"])


@pytest.mark.parametrize("context", ["spawn", "forkserver"])
def test_loader_workers_started_by_spawn_or_forkserver(claravid_root, tmp_path, context):
    """One worker, two frames, over a dataset whose cache exists and that has read through it
    (what a training process hands its workers)."""
    ds = _dataset(claravid_root, tmp_path / "cache")
    assert ds.prepare_label_cache().built == len(ds)
    expected = [ds[i]["mask"] for i in range(2)]
    loader = DataLoader(ds, batch_size=None, sampler=[1, 0], num_workers=1,
                        multiprocessing_context=context)  # fmt: skip
    masks = [sample["mask"] for sample in loader]
    assert torch.equal(masks[0], expected[1]) and torch.equal(masks[1], expected[0])
