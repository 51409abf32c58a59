"""Which entry serves which frame: each part of the staleness key matters on its own, and an
entry records what it was built from, so a copied, stale or forged entry is refused.

Each test changes one thing only (the other parts of the key are held equal and checked to be),
and the expected codes come from ``read_label_codes`` on the PNGs, decoded directly, or from
the constant class ids the test wrote.
"""

import json
import os
import shutil
import warnings
import zlib

import numpy as np
import pytest
import tifffile

from claravid.data.index import list_frames
from claravid.data.label_cache import LabelCache, LabelCacheWarning
from claravid.io import modalities as m
from claravid.io.labels import DYNAMIC_OFFSET, read_label_codes

# Not square, not a multiple of the tile: 5×3 tiles of 16, the last column 13 wide.
W, H, TILE = 77, 41, 16


def _constant_pan(path, class_id, width=W, height=H):
    """A panoptic PNG of one class everywhere: equal sizes on disk for any class id."""
    semantic = np.full((height, width), class_id, np.uint8)
    m.write_pan_seg(path, semantic, np.zeros((height, width), np.int64))
    return path


def _set_mtime(path, ns):
    os.utime(path, ns=(ns, ns))


@pytest.fixture
def cache(tmp_path):
    return LabelCache(tmp_path / "cache", tile_size=TILE)


def _read_quietly(cache, *sources):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LabelCacheWarning)
        return cache.read(*sources)


def test_a_new_size_alone_misses(cache, tmp_path):
    """Same path and modification time, another size: the new labels, not the entry's."""
    pan = _constant_pan(tmp_path / "pan.png", 8)
    stat = pan.stat()
    assert (cache.read(pan) == 8).all()
    semantic = np.full((H, W), 8, np.uint8)
    semantic[5:30, 10:60] = 6  # a road across it: another picture, another file size
    m.write_pan_seg(pan, semantic, np.zeros((H, W), np.int64))
    _set_mtime(pan, stat.st_mtime_ns)
    assert pan.stat().st_size != stat.st_size and pan.stat().st_mtime_ns == stat.st_mtime_ns
    np.testing.assert_array_equal(_read_quietly(cache, pan), semantic)


def test_a_new_modification_time_alone_misses(cache, tmp_path):
    """Same path and size (one constant class for another), a later mtime: the new labels."""
    pan = _constant_pan(tmp_path / "pan.png", 8)
    stat = pan.stat()
    assert (cache.read(pan) == 8).all()
    _constant_pan(pan, 6)
    _set_mtime(pan, stat.st_mtime_ns + 1_000_000_000)
    assert pan.stat().st_size == stat.st_size  # the size does not tell them apart
    assert (_read_quietly(cache, pan) == 6).all()


def test_another_path_alone_misses(cache, tmp_path):
    """Two frames of equal size and modification time: each is served its own labels."""
    a = _constant_pan(tmp_path / "a" / "pan.png", 8)
    b = _constant_pan(tmp_path / "b" / "pan.png", 6)
    _set_mtime(a, 1_700_000_000_000_000_000)
    _set_mtime(b, 1_700_000_000_000_000_000)
    assert a.stat().st_size == b.stat().st_size
    assert (cache.read(a) == 8).all()
    assert (_read_quietly(cache, b) == 6).all()
    assert (cache.read(a) == 8).all()


def test_an_entry_built_without_the_dynamic_mask_is_not_served_with_it(cache, tmp_path):
    """Moving cars must read as moving once the frame is read with its dynamic mask."""
    semantic = np.full((H, W), 6, np.uint8)
    semantic[10:20, 30:50] = 9  # a vehicle
    pan = tmp_path / "pan.png"
    m.write_pan_seg(pan, semantic, np.zeros((H, W), np.int64))
    dynamic = np.full((H, W), 255, np.uint8)
    dynamic[10:20, 30:50] = 0  # it moves
    dyn = tmp_path / "dyn.png"
    m.write_dynamic_mask(dyn, dynamic)
    static = cache.read_window(pan, None, 0, 0, W, H)
    np.testing.assert_array_equal(static, semantic)
    expected = semantic.copy()
    expected[10:20, 30:50] = 9 + DYNAMIC_OFFSET
    np.testing.assert_array_equal(cache.read(pan, dyn), expected)
    np.testing.assert_array_equal(
        cache.read_window(pan, dyn, 30, 10, 20, 10), expected[10:20, 30:50]
    )
    # and the entry without it still serves the frame read without it
    np.testing.assert_array_equal(
        cache.read_window(pan, None, 30, 10, 20, 10), semantic[10:20, 30:50]
    )


def test_an_edited_dynamic_mask_alone_misses(cache, tmp_path):
    """Same panoptic file; the dynamic mask rewritten (same size: a moving box moved down), a
    later mtime."""
    pan = _constant_pan(tmp_path / "pan.png", 9)
    dyn = tmp_path / "dyn.png"
    before, after = np.full((H, W), 255, np.uint8), np.full((H, W), 255, np.uint8)
    before[10:20, 30:50] = 0
    after[20:30, 30:50] = 0
    m.write_dynamic_mask(dyn, before)
    stat = dyn.stat()
    np.testing.assert_array_equal(
        cache.read(pan, dyn), np.where(before == 0, 9 + DYNAMIC_OFFSET, 9)
    )
    m.write_dynamic_mask(dyn, after)
    _set_mtime(dyn, stat.st_mtime_ns + 1_000_000_000)
    assert dyn.stat().st_size == stat.st_size
    np.testing.assert_array_equal(
        _read_quietly(cache, pan, dyn), np.where(after == 0, 9 + DYNAMIC_OFFSET, 9)
    )


def _description(entry):
    with tifffile.TiffFile(entry) as tif:
        return json.loads(tif.pages[0].description)


def _patch(entry, old, new):
    """Replace one string of the entry's header by another of the same length (nothing moves)."""
    assert len(old) == len(new)
    data = entry.read_bytes()
    assert data.count(old.encode()) == 1
    entry.write_bytes(data.replace(old.encode(), new.encode()))


def test_an_entry_of_another_code_table_is_refused_as_such(cache, tmp_path):
    pan = _constant_pan(tmp_path / "pan.png", 8)
    cache.read(pan)
    (entry,) = cache.directory.rglob("*.tif")
    digest = _description(entry)["codes"]
    other = "0" * len(digest) if digest != "0" * len(digest) else "1" * len(digest)
    _patch(entry, f'"codes":"{digest}"', f'"codes":"{other}"')
    with pytest.warns(LabelCacheWarning) as record:
        assert (cache.read_window(pan, None, 1, 2, 30, 20) == 8).all()
    (message,) = [str(w.message) for w in record]
    assert "another class/code table" in message and "another version" not in message
    assert "rebuilt" in message and _description(entry)["codes"] == digest


def test_an_entry_of_another_version_is_refused_as_such(cache, tmp_path):
    pan = _constant_pan(tmp_path / "pan.png", 8)
    cache.read(pan)
    (entry,) = cache.directory.rglob("*.tif")
    version = _description(entry)["version"]
    _patch(entry, f'"version":{version}', f'"version":{(version + 1) % 10}')
    with pytest.warns(LabelCacheWarning, match="another version") as record:
        assert (cache.read(pan) == 8).all()
    assert "code table" not in str(record[0].message)


def _two_frames(root):
    """Frames 0 and 5 of the tiny tree (their codes differ) as (pan, dyn) pairs."""
    frames = list_frames(root, "urban_1", fields=["pan_seg", "dynamic_mask"])
    pairs = [(f.paths["pan_seg"], f.paths["dynamic_mask"]) for f in (frames[0], frames[5])]
    assert not np.array_equal(read_label_codes(*pairs[0]), read_label_codes(*pairs[1]))
    return pairs


def test_another_frame_s_valid_entry_copied_over_is_refused(claravid_root, tmp_path):
    cache = LabelCache(tmp_path / "cache")
    zero, five = _two_frames(claravid_root)
    assert cache.prepare([zero, five]).built == 2
    shutil.copyfile(cache.path_for(*five), cache.path_for(*zero))
    with pytest.warns(LabelCacheWarning, match="built from other source files") as record:
        np.testing.assert_array_equal(cache.read_window(*zero, 3, 2, 50, 40),
                                      read_label_codes(*zero)[2:42, 3:53])  # fmt: skip
    assert str(five[0]) in str(record[0].message)  # it says whose entry it was
    np.testing.assert_array_equal(cache.read(*zero), read_label_codes(*zero))


def test_prepare_rebuilds_a_copied_entry(claravid_root, tmp_path):
    cache = LabelCache(tmp_path / "cache")
    zero, five = _two_frames(claravid_root)
    cache.prepare([zero, five])
    shutil.copyfile(cache.path_for(*five), cache.path_for(*zero))
    summary = cache.prepare([zero, five])
    assert (summary.built, summary.skipped) == (1, 1)
    np.testing.assert_array_equal(tifffile.imread(cache.path_for(*zero)), read_label_codes(*zero))


def _tile(entry, index):
    with tifffile.TiffFile(entry) as tif:
        page = tif.pages[0]
        return page.dataoffsets[index], page.databytecounts[index]


def _forge_tile(entry, index, class_id):
    """Replace a tile by a valid deflate stream of another class, padded to the same length
    (zlib stops at the end of its stream: inflating it raises nothing)."""
    offset, count = _tile(entry, index)
    forged = zlib.compress(bytes([class_id]) * TILE * TILE, 1)
    assert len(forged) < count
    data = bytearray(entry.read_bytes())
    data[offset : offset + count] = forged + b"\0" * (count - len(forged))
    entry.write_bytes(bytes(data))


def _checkerboard_pan(path):
    """Class 8 and 6 in 4-pixel squares: tiles that compress to more than a forged one."""
    yy, xx = np.mgrid[:H, :W]
    semantic = np.where((yy // 4 + xx // 4) % 2 == 0, 8, 6).astype(np.uint8)
    m.write_pan_seg(path, semantic, np.zeros((H, W), np.int64))
    return semantic


def test_a_forged_tile_is_never_served(cache, tmp_path):
    pan = tmp_path / "pan.png"
    semantic = _checkerboard_pan(pan)
    cache.read(pan)
    (entry,) = cache.directory.rglob("*.tif")
    _forge_tile(entry, 6, 17)  # row 1, column 1: pixels 16..31 of both axes
    with pytest.warns(LabelCacheWarning, match="tile 6 is corrupt"):
        np.testing.assert_array_equal(
            cache.read_window(pan, None, 20, 18, 5, 4), semantic[18:22, 20:25]
        )


def test_prepare_checks_every_tile_of_a_present_entry(cache, tmp_path):
    pan = tmp_path / "pan.png"
    semantic = _checkerboard_pan(pan)
    assert cache.prepare([(pan, None)]).built == 1
    (entry,) = cache.directory.rglob("*.tif")
    _forge_tile(entry, 14, 0)  # the last tile
    summary = cache.prepare([(pan, None)])
    assert (summary.built, summary.skipped) == (1, 0)
    np.testing.assert_array_equal(tifffile.imread(entry), semantic)
    assert cache.prepare([(pan, None)]).skipped == 1
