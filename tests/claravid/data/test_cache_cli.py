"""``claravid-cache`` on damaged caches, one unwritable entry, and the flags' spellings.

Counts are stated from the tiny tree: 2 missions × 6 viewpoints × 3 frames, 18 per mission.
"""

import errno
import os
import re
import shutil

import pytest
import tifffile

from claravid.data.cache_cli import main
from claravid.data.index import list_frames
from claravid.data.label_cache import LabelCache
from tests.helpers.files import png_claiming


def _run(argv):
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own errors
        return exc.code


def _argv(root, cache, *extra):
    return ["--data", str(root), "-o", str(cache), "--no-progress", *extra]


def _entries(cache):
    return sorted((cache / "label_codes").rglob("*.tif"))


def _sources(root, mission):
    frames = list_frames(root, mission, fields=["pan_seg", "dynamic_mask"])
    return [(f.paths["pan_seg"], f.paths["dynamic_mask"]) for f in frames]


def test_missions_are_one_comma_separated_list(claravid_root, tmp_path, capsys):
    """As for claravid-eval: ``--missions a,b``; ``--missions a b`` is a usage error."""
    cache = tmp_path / "c"
    assert _run(_argv(claravid_root, cache, "--missions", "urban_1", "rural_1")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rural_1" in err[0] and "claravid-cache: error:" in err[0]
    assert _entries(cache) == []
    assert _run(_argv(claravid_root, cache, "--missions", "urban_1,rural_1")) == 0
    assert "built 36 entries" in capsys.readouterr().out
    assert _run(_argv(claravid_root, tmp_path / "d", "--altitude", "low,high", "--direction",
                      "v")) == 0  # fmt: skip
    assert "built 12 entries" in capsys.readouterr().out  # 2 missions × 2 altitudes × 3


@pytest.mark.parametrize("flag", ["--missions", "--altitude", "--direction"])
def test_an_empty_selection_is_a_usage_error(claravid_root, tmp_path, capsys, flag):
    assert _run(_argv(claravid_root, tmp_path / "c", flag, " , ")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{flag} is empty" in err[0]


def test_an_empty_shard_is_a_usage_error(claravid_root, tmp_path, capsys):
    """``--shard $UNSET`` must not prepare every frame."""
    assert _run(_argv(claravid_root, tmp_path / "c", "--shard", "")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "k/n" in err[0] and "''" in err[0]
    assert _entries(tmp_path / "c") == []


def test_a_shard_prepares_its_part(claravid_root, tmp_path, capsys):
    assert (
        _run(_argv(claravid_root, tmp_path / "c", "--missions", "rural_1", "--shard", "1/4")) == 0
    )
    out = capsys.readouterr().out
    assert "built 5 entries" in out and "(shard 1/4 of 18)" in out  # frames 1, 5, 9, 13, 17


def test_a_corrupt_tile_is_rebuilt_not_nothing_to_do(claravid_root, tmp_path, capsys):
    argv = _argv(claravid_root, tmp_path, "--missions", "urban_1")
    assert _run(argv) == 0
    entry = _entries(tmp_path)[3]
    with tifffile.TiffFile(entry) as tif:
        offset, count = tif.pages[0].dataoffsets[0], tif.pages[0].databytecounts[0]
    data = bytearray(entry.read_bytes())
    data[offset + count - 5] ^= 0xFF  # one byte of the tile's deflate stream
    entry.write_bytes(bytes(data))
    capsys.readouterr()
    assert _run(argv) == 0
    out = capsys.readouterr().out
    assert "nothing to do" not in out and "built 1 entries" in out and "17 already cached" in out


def test_another_frame_s_entry_copied_over_is_rebuilt(claravid_root, tmp_path, capsys):
    argv = _argv(claravid_root, tmp_path, "--missions", "urban_1")
    assert _run(argv) == 0
    cache = LabelCache(tmp_path)
    zero, five = _sources(claravid_root, "urban_1")[0], _sources(claravid_root, "urban_1")[5]
    shutil.copyfile(cache.path_for(*five), cache.path_for(*zero))
    capsys.readouterr()
    assert _run(argv) == 0
    out = capsys.readouterr().out
    assert "nothing to do" not in out and "built 1 entries" in out


def test_one_unwritable_entry_location_is_listed_and_the_others_built(
    claravid_root, tmp_path, capsys, monkeypatch
):
    cache = LabelCache(tmp_path)
    sources = _sources(claravid_root, "rural_1")
    refused = cache.path_for(*sources[2]).parent
    blocked = [s for s in sources if cache.path_for(*s).parent == refused]
    real_open = os.open

    def open_refusing_one_folder(path, flags, *args, **kwargs):
        if flags & os.O_CREAT and os.path.dirname(str(path)) == str(refused):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", open_refusing_one_folder)
    assert _run(_argv(claravid_root, tmp_path, "--missions", "rural_1")) == 1
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == len(blocked)
    for line, (pan, dyn) in zip(err, blocked, strict=True):
        assert line.startswith(f"skipped {pan}: ") and str(cache.path_for(pan, dyn)) in line
        assert "Permission denied" in line
    assert f"built {18 - len(blocked)} entries" in captured.out
    assert len(_entries(tmp_path)) == 18 - len(blocked)


def test_a_full_disk_advises_the_cache_dir_flag(claravid_root, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(
        os, "write", lambda fd, data: (_ for _ in ()).throw(OSError(errno.ENOSPC, "full"))
    )
    assert _run(_argv(claravid_root, tmp_path, "--missions", "urban_1")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "disk is full" in err[0] and "--output" in err[0]


@pytest.mark.parametrize("workers", ["0", "2"])
def test_a_label_png_claiming_more_than_2_30_pixels_is_listed(
    writable_root, tmp_path, capsys, workers
):
    # OpenCV's cv2.error ended the run in a traceback (in the workers and without them).
    pan = sorted(writable_root.glob("003_urban_1/panoptic_seg/45deg_low_h/*.png"))[1]
    pan.write_bytes(png_claiming(40000, 30000))
    argv = ["--data", str(writable_root), "--missions", "urban_1", "--altitude", "low", "-o",
            str(tmp_path / "cache"), "--no-progress", "--workers", workers]  # fmt: skip
    assert main(argv) == 1
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert "Traceback" not in text and "cv2.error" not in text
    lines = [line for line in text.splitlines() if str(pan) in line]
    assert len(lines) == 1, text
    assert re.search(
        r"its header claims 40000×30000 = 1,200,000,000 pixels, more than the 1,073,741,824 "
        r"\(2\^30\) the readers decode",
        lines[0],
    ), lines[0]
    assert "built 5 entries" in text, text
