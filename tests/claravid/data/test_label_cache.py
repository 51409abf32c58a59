"""LabelCache: windows read from tiled TIFF entries, prepared up front, robust to damage.

Expected codes always come from ``read_label_codes`` on the PNGs, decoded directly.
"""

import errno
import os
import threading
import warnings

import numpy as np
import pytest
import tifffile

from claravid.data.cache_cli import main
from claravid.data.index import list_frames
from claravid.data.label_cache import CacheWriteError, LabelCache, LabelCacheWarning
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.io import label_tiff
from claravid.io import modalities as m
from claravid.io.labels import read_label_codes
from tests.helpers.files import sha256

#: A full disk and an exceeded quota both leave no room for any entry, and are said apart.
NO_SPACE = [(errno.ENOSPC, "disk is full"), (errno.EDQUOT, "disk quota is exceeded")]

# 70×50 with 16-pixel tiles: 5×4 tiles, the last column 6 wide and the last row 2 high.
W, H, TILE = 70, 50, 16


def _labels(width, height, seed):
    """Class ids in rectangles and a disc (regions, as real labels), a few unknown ids."""
    rng = np.random.default_rng(seed)
    semantic = np.full((height, width), 8, np.uint8)
    for class_id in (0, 6, 7, 9, 9, 3, 17, 255, 11):
        x, y = rng.integers(0, width), rng.integers(0, height)
        w, h = rng.integers(3, width // 2), rng.integers(3, height // 2)
        semantic[y : y + h, x : x + w] = class_id
    yy, xx = np.mgrid[:height, :width]
    semantic[(xx - width // 3) ** 2 + (yy - height // 2) ** 2 < (height // 4) ** 2] = 16
    dynamic = np.full((height, width), 255, np.uint8)
    dynamic[height // 3 :, width // 2 :] = 0
    return semantic, dynamic


@pytest.fixture
def frame(tmp_path):
    """A 70×50 frame's panoptic PNG and dynamic mask."""
    semantic, dynamic = _labels(W, H, seed=3)
    pan, dyn = tmp_path / "src" / "pan.png", tmp_path / "src" / "dyn.png"
    m.write_pan_seg(pan, semantic, np.arange(W * H).reshape(H, W) % 997)
    m.write_dynamic_mask(dyn, dynamic)
    return pan, dyn


@pytest.fixture
def cache(tmp_path):
    return LabelCache(tmp_path / "cache", tile_size=TILE)


def _page(path):
    """The entry's one page (its tile table stays readable once the file is closed)."""
    with tifffile.TiffFile(path) as tif:
        return tif.pages[0]


def _entries(cache):
    return sorted(cache.directory.rglob("*.tif"))


def _leftovers(cache):
    return [p for p in cache.directory.rglob("*") if p.is_file() and p.suffix != ".tif"]


WINDOWS = [
    (0, 0, W, H),  # the whole frame
    (0, 0, 1, 1),  # 1 pixel at each corner
    (W - 1, 0, 1, 1),
    (0, H - 1, 1, 1),
    (W - 1, H - 1, 1, 1),
    (15, 15, 2, 2),  # 4 tiles meet
    (16, 16, 16, 16),  # exactly one tile
    (10, 3, 40, 30),  # across tile borders
    (60, 40, 10, 10),  # the partial corner tile
    (0, 20, W, 1),  # one row, every tile column
    (33, 0, 1, H),  # one column, every tile row
    (64, 0, 6, H),  # the narrow last column
    (5, 48, 60, 2),  # the short last row
]


@pytest.mark.parametrize("window", WINDOWS)
@pytest.mark.parametrize("with_dynamic", [True, False])
def test_window_equals_direct_decode_cold_and_warm(cache, frame, window, with_dynamic):
    pan, dyn = frame if with_dynamic else (frame[0], None)
    x, y, w, h = window
    expected = read_label_codes(pan, dyn)[y : y + h, x : x + w]
    for _ in range(2):  # built from the PNGs, then read from the entry
        got = cache.read_window(pan, dyn, x, y, w, h)
        assert got.dtype == np.uint8 and got.shape == (h, w)
        np.testing.assert_array_equal(got, expected)
    assert len(_entries(cache)) == 1


def test_whole_frame_read_and_entry_layout(cache, frame):
    expected = read_label_codes(*frame)
    np.testing.assert_array_equal(cache.read(*frame), expected)
    np.testing.assert_array_equal(cache.read(*frame), expected)
    (entry,) = _entries(cache)
    page = _page(entry)
    assert page.is_tiled and (page.tilelength, page.tilewidth) == (TILE, TILE)
    assert page.compression == 8 and len(page.dataoffsets) == 5 * 4  # deflate, 5×4 tiles
    np.testing.assert_array_equal(tifffile.imread(entry), expected)  # a plain TIFF


def test_every_window_of_generated_frames_with_the_default_tile(claravid_root, tmp_path):
    cache = LabelCache(tmp_path)
    for frame in list_frames(claravid_root, "urban_1", "low", "h")[:2]:
        pan, dyn = frame.paths["pan_seg"], frame.paths["dynamic_mask"]
        expected = read_label_codes(pan, dyn)
        cache.prepare([(pan, dyn)])
        for x, y, w, h in [(0, 0, 64, 48), (63, 47, 1, 1), (7, 5, 30, 41)]:
            np.testing.assert_array_equal(
                cache.read_window(pan, dyn, x, y, w, h), expected[y : y + h, x : x + w]
            )


@pytest.mark.parametrize("window", [(-1, 0, 5, 5), (0, 0, 0, 5), (66, 0, 5, 5), (0, 46, 5, 5)])
def test_window_outside_the_frame_is_refused(cache, frame, window):
    cache.prepare([frame])
    with pytest.raises(ValueError, match="window"):
        cache.read_window(*frame, *window)


def test_a_window_reads_only_the_tiles_it_touches(cache, frame, monkeypatch):
    """Counts the bytes read from the entry: fails if the whole page were read or decoded."""
    cache.prepare([frame])
    (entry,) = _entries(cache)
    page = _page(entry)
    read = []
    real_pread = os.pread

    def counting_pread(fd, length, offset):
        read.append((offset, length))
        return real_pread(fd, length, offset)

    monkeypatch.setattr(os, "pread", counting_pread)
    cache.read_window(*frame, 15, 15, 2, 2)  # tiles (0,0) (0,1) (1,0) (1,1) of 5×4
    touched = [0, 1, 5, 6]
    assert sum(n for _, n in read) == sum(page.databytecounts[i] for i in touched)
    assert {o for o, _ in read} == {page.dataoffsets[0], page.dataoffsets[5]}  # a read per row


def test_a_corrupt_tile_outside_the_window_is_never_decoded(cache, frame):
    cache.prepare([frame])
    (entry,) = _entries(cache)
    page = _page(entry)
    last = len(page.dataoffsets) - 1  # the bottom-right tile
    data = bytearray(entry.read_bytes())
    start = page.dataoffsets[last]
    data[start : start + page.databytecounts[last]] = b"\x00" * page.databytecounts[last]
    entry.write_bytes(bytes(data))
    expected = read_label_codes(*frame)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # served from the entry: no rebuild
        np.testing.assert_array_equal(cache.read_window(*frame, 0, 0, 16, 16), expected[:16, :16])
    with pytest.warns(LabelCacheWarning, match="tile 19 is corrupt"):
        np.testing.assert_array_equal(cache.read(*frame), expected)  # touches it: rebuilt


def test_an_edited_source_is_never_served_stale(cache, frame):
    pan, dyn = frame
    before = cache.read(pan, dyn)
    semantic, _ = _labels(W, H, seed=4)
    m.write_pan_seg(pan, semantic, np.zeros((H, W), np.int64))
    os.utime(pan, ns=(1, 1))  # even with an mtime moved back, the size or path key changes
    after = cache.read_window(pan, dyn, 0, 0, W, H)
    np.testing.assert_array_equal(after, read_label_codes(pan, dyn))
    assert not np.array_equal(after, before)


@pytest.mark.parametrize("method", ["read", "read_window"])
def test_many_threads_on_one_missing_entry(tmp_path, method):
    """Each writer has its own temporary name (the process id alone crashed in os.replace).

    Frames large enough (~10 ms to decode, outside the GIL) that the threads all miss together.
    """
    n, sources = 12, []
    for i in range(3):
        semantic, dynamic = _labels(1200, 900, seed=i)
        pan, dyn = tmp_path / f"pan{i}.png", tmp_path / f"dyn{i}.png"
        m.write_pan_seg(pan, semantic, np.zeros(semantic.shape, np.int64))
        m.write_dynamic_mask(dyn, dynamic)
        sources.append((pan, dyn))
    cache = LabelCache(tmp_path / "cache")
    barrier = threading.Barrier(n)
    results, errors = {}, []

    def work(i):
        for pan, dyn in sources:
            barrier.wait()
            try:
                if method == "read":
                    results[i, pan] = cache.read(pan, dyn)[4:44, 3:53]
                else:
                    results[i, pan] = cache.read_window(pan, dyn, 3, 4, 50, 40)
            except Exception as exc:
                errors.append(exc)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(n)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert errors == [] and [str(w.message) for w in caught] == []  # no write failed either
    for pan, dyn in sources:
        expected = read_label_codes(pan, dyn)[4:44, 3:53]
        for i in range(n):
            np.testing.assert_array_equal(results[i, pan], expected)
    assert len(_entries(cache)) == 3 and _leftovers(cache) == []


def _wrong_size_tiff(path):
    path.write_bytes(label_tiff.encode_codes(np.zeros((H + 16, W), np.uint8), TILE))


def _foreign_tiff(path):
    tifffile.imwrite(path, np.zeros((H, W), np.uint8), tile=(16, 16), compression="zlib")


def _uint16_tiff(path):
    description = _page(path).description  # ours, from the entry it replaces
    tifffile.imwrite(path, np.zeros((H, W), np.uint16), tile=(16, 16), compression="zlib",
                     description=description, metadata=None)  # fmt: skip


def _flip_tile_bytes(path):
    page = _page(path)
    start, count = page.dataoffsets[7], page.databytecounts[7]
    data = bytearray(path.read_bytes())
    data[start + 2 : start + count] = bytes(b ^ 0x5A for b in data[start + 2 : start + count])
    path.write_bytes(bytes(data))


DAMAGE = {
    "cut in half": lambda p: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]),
    "last bytes cut": lambda p: p.write_bytes(p.read_bytes()[:-3]),
    "empty": lambda p: p.write_bytes(b""),
    "garbage": lambda p: p.write_bytes(os.urandom(p.stat().st_size)),
    "tile bytes flipped": _flip_tile_bytes,
    "another frame size": _wrong_size_tiff,
    "a TIFF not ours": _foreign_tiff,
    "uint16 pixels": _uint16_tiff,
    "a folder": lambda p: (p.unlink(), p.mkdir()),
}


@pytest.mark.parametrize("damage", DAMAGE)
def test_a_damaged_entry_is_rebuilt_never_served(cache, frame, damage):
    expected = read_label_codes(*frame)
    cache.read(*frame)
    (entry,) = _entries(cache)
    before = sha256(entry)
    DAMAGE[damage](entry)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LabelCacheWarning)
        np.testing.assert_array_equal(cache.read_window(*frame, 0, 0, W, H), expected)
        np.testing.assert_array_equal(cache.read(*frame), expected)
    if damage != "a folder":  # a folder in its place cannot be replaced by a file: decoded
        assert sha256(entry) == before  # rebuilt, and now served without a warning
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            np.testing.assert_array_equal(cache.read_window(*frame, 1, 2, 3, 4), expected[2:6, 1:4])


def test_prepare_rebuilds_a_damaged_entry(cache, frame):
    cache.prepare([frame])
    (entry,) = _entries(cache)
    entry.write_bytes(entry.read_bytes()[:-10])
    summary = cache.prepare([frame])
    assert (summary.built, summary.skipped) == (1, 0)
    np.testing.assert_array_equal(tifffile.imread(entry), read_label_codes(*frame))


def test_unwritable_cache_folder_decodes_instead_with_one_warning(frame, tmp_path):
    """A cache path under a regular file cannot be created, even by root."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    cache = LabelCache(blocker / "cache")
    expected = read_label_codes(*frame)
    with pytest.warns(LabelCacheWarning, match="cannot write the label cache") as record:
        for _ in range(5):
            np.testing.assert_array_equal(
                cache.read_window(*frame, 2, 2, 9, 9), expected[2:11, 2:11]
            )
            np.testing.assert_array_equal(cache.read(*frame), expected)
    assert len(record) == 1


def test_read_only_file_system_decodes_instead_with_one_warning(frame, tmp_path, monkeypatch):
    real_open = os.open

    creates = []

    def read_only_open(path, flags, *args, **kwargs):
        if flags & os.O_CREAT:
            creates.append(path)
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", read_only_open)
    cache = LabelCache(tmp_path / "ro")
    expected = read_label_codes(*frame)
    with pytest.warns(LabelCacheWarning, match=r"ro/label_codes is not writable") as record:
        for _ in range(3):
            np.testing.assert_array_equal(cache.read(*frame), expected)
    assert len(record) == 1 and _entries(cache) == []
    assert len(creates) == 1  # after the first refusal, no entry is encoded and tried again
    with pytest.raises(CacheWriteError, match="is not writable"):
        cache.prepare([frame])


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_chmod_read_only_cache_folder(frame, tmp_path):
    folder = tmp_path / "ro"
    (folder / "label_codes").mkdir(parents=True)
    (folder / "label_codes").chmod(0o555)
    try:
        with pytest.warns(LabelCacheWarning, match="not writable"):
            np.testing.assert_array_equal(LabelCache(folder).read(*frame), read_label_codes(*frame))
    finally:
        (folder / "label_codes").chmod(0o755)


@pytest.mark.parametrize(("code", "words"), NO_SPACE)
def test_full_disk_while_preparing_leaves_nothing_half_written(
    cache, frame, tmp_path, monkeypatch, code, words
):
    real_write = os.write
    calls = []

    def write_then_full(fd, data):
        if calls:  # the first write goes through (a partial file), the next finds the disk full
            raise OSError(code, os.strerror(code))
        calls.append(fd)
        return real_write(fd, bytes(data[: len(data) // 2]))

    monkeypatch.setattr(os, "write", write_then_full)
    with pytest.raises(CacheWriteError, match=f"{words}.*" + str(cache.directory)) as info:
        cache.prepare([frame])
    assert info.value.errno == code and calls
    assert _entries(cache) == [] and _leftovers(cache) == []
    monkeypatch.undo()
    np.testing.assert_array_equal(cache.read(*frame), read_label_codes(*frame))


@pytest.mark.parametrize(("code", "words"), NO_SPACE)
def test_full_disk_while_training_decodes_instead(cache, frame, monkeypatch, code, words):
    monkeypatch.setattr(os, "write", lambda fd, data: (_ for _ in ()).throw(OSError(code, "full")))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        np.testing.assert_array_equal(cache.read(*frame), read_label_codes(*frame))
        # The folder takes no entry: writing stops there, one warning, not one per frame.
        np.testing.assert_array_equal(cache.read(*frame), read_label_codes(*frame))
    messages = [str(w.message) for w in caught if issubclass(w.category, LabelCacheWarning)]
    assert len(messages) == 1 and words in messages[0], messages
    assert _entries(cache) == [] and _leftovers(cache) == []


def _sources(root, **selection):
    frames = list_frames(root, fields=["pan_seg", "dynamic_mask"], **selection)
    return [(f.paths["pan_seg"], f.paths["dynamic_mask"]) for f in frames]


def test_prepare_is_idempotent_and_counts_bytes(claravid_root, tmp_path):
    sources = _sources(claravid_root, missions="rural_1")
    cache = LabelCache(tmp_path)
    first = cache.prepare(sources)
    assert (first.frames, first.built, first.skipped, first.failed) == (18, 18, 0, [])
    sizes = [p.stat().st_size for p in _entries(cache)]
    assert first.bytes_built == first.bytes_total == sum(sizes)
    assert first.bytes_per_frame == pytest.approx(sum(sizes) / 18)
    again = cache.prepare(sources)
    assert (again.built, again.skipped, again.bytes_total) == (0, 18, first.bytes_total)
    for pan, dyn in sources[:3]:
        np.testing.assert_array_equal(cache.read(pan, dyn), read_label_codes(pan, dyn))


def test_shards_split_the_work_and_workers_build_the_same(claravid_root, tmp_path):
    sources = _sources(claravid_root, missions="urban_1", altitude="low")
    cache = LabelCache(tmp_path / "a")
    counts = [cache.prepare(sources, shard=(k, 3)).built for k in range(3)]
    assert counts == [2, 2, 2] and len(_entries(cache)) == 6
    parallel = LabelCache(tmp_path / "b")
    assert parallel.prepare(sources, workers=2).built == 6
    for a, b in zip(_entries(cache), _entries(parallel), strict=True):
        assert a.name == b.name
        np.testing.assert_array_equal(tifffile.imread(a), tifffile.imread(b))


def test_prepare_lists_unreadable_frames_and_goes_on(writable_root, tmp_path):
    sources = _sources(writable_root, missions="urban_1", altitude="low", direction="h")
    sources[0][0].write_bytes(b"not a png")
    sources[1][1].unlink()
    summary = LabelCache(tmp_path).prepare(sources)
    assert summary.built == 1 and [p for p, _ in summary.failed] == [
        str(sources[0][0]), str(sources[1][0])
    ]  # fmt: skip


def test_cli_prepares_then_has_nothing_to_do(claravid_root, tmp_path, capsys):
    argv = ["--data", str(claravid_root), "--missions", "urban_1", "--altitude", "low,mid",
            "-o", str(tmp_path), "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "built 12 entries" in out and f"in {tmp_path / 'label_codes'}" in out
    assert "per frame" in out
    assert main(argv) == 0
    assert "nothing to do: all 12 frames are already cached" in capsys.readouterr().out
    # The entries every palette's dataset reads: nothing to build for either.
    for palette in ("claravid", "uavid"):
        ds = ClaraVidSegmentation(
            claravid_root,
            split="all",
            missions=["urban_1"],
            altitude=["low", "mid"],
            palette=palette,
            label_cache=tmp_path,
        )
        assert ds.prepare_label_cache().built == 0  # fmt: skip


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--data", "{missing}"], "ClaraVid root not found"),
        (["--data", "{tmp}"], "ClaraVid mission folders not found"),
        (["--data", "{root}", "--shard", "2/2"], "out of range"),
        (["--data", "{root}", "--shard", "x"], "k/n"),
        (["--data", "{root}", "--missions", "nowhere"], "unknown ClaraVid mission"),
        (["--data", "{root}", "--workers", "-1"], "integer >= 0"),
        (["{root}"], "the following arguments are required: --data"),  # no positional root
    ],
)
def test_cli_user_errors_are_one_line_exit_2(claravid_root, tmp_path, capsys, argv, message):
    names = {"missing": tmp_path / "nope", "tmp": tmp_path, "root": claravid_root}
    argv = [a.format(**names) for a in argv]
    code = 2
    try:
        code = main([*argv, "-o", str(tmp_path / "c")])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(("code", "words"), NO_SPACE)
def test_cli_full_disk_is_a_one_line_error(
    claravid_root, tmp_path, capsys, monkeypatch, code, words
):
    monkeypatch.setattr(os, "write", lambda fd, data: (_ for _ in ()).throw(OSError(code, "full")))
    argv = ["--data", str(claravid_root), "--missions", "urban_1", "-o", str(tmp_path)]
    assert main([*argv, "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and str(tmp_path) in err[0]
