"""``claravid-dsp`` end to end: folders, list files, official JSON, shards, merge, compare."""

from __future__ import annotations

import json
import math
import os
import sqlite3
from pathlib import Path

import cv2
import numpy as np
import pytest

from claravid.dsp import load_results, profile_images
from claravid.dsp.cache import cache_dir
from claravid.dsp.cli import main

from .reference import official_image_complexity, textured
from .reference_profile import official_profile


@pytest.fixture
def collection(tmp_path) -> Path:
    """Six small images in two sub-folders, PNG and JPEG, plus one corrupt file."""
    rng = np.random.default_rng(42)
    root = tmp_path / "scene"
    for i in range(6):
        folder = root / "left_rgb" / ("45deg_low_h" if i < 3 else "55deg_mid_v")
        folder.mkdir(parents=True, exist_ok=True)
        img = np.dstack([textured(rng, 48, 64) for _ in range(3)])
        cv2.imwrite(str(folder / f"{i:06d}.{'jpg' if i % 2 else 'png'}"), img)
    (root / "left_rgb" / "45deg_low_h" / "000099.png").write_bytes(b"\x89PNG broken")
    return root


def _run(argv) -> int:
    return main([*argv, "--no-progress", "--workers", "0"])


def test_folder_with_recursive_pattern(collection, tmp_path, capsys):
    out, plot = tmp_path / "r.json", tmp_path / "p.png"
    argv = ["--data", str(collection), "--pattern", "left_rgb/**/*.png", "--output", str(out)]
    assert _run([*argv, "--plot", str(plot)]) == 0
    data = json.loads(out.read_text())
    assert list(data)[:5] == ["metric", "num_images", "use_blur", "blur_ksize", "results"]
    assert (data["metric"], data["num_images"], data["use_blur"], data["blur_ksize"]) == (
        "delent",
        3,
        True,
        3,
    )
    for row in data["results"]:
        assert row["complexity"] == pytest.approx(
            official_image_complexity(row["image_path"]), abs=1e-9
        )
        assert (row["height"], row["width"]) == (48, 64)
    assert [Path(e["image_path"]).name for e in data["errors"]] == ["000099.png"]
    assert "could not decode" in data["errors"][0]["error"]
    expected = official_profile([r["complexity"] for r in data["results"]])
    assert data["profile"] == pytest.approx(expected, rel=1e-12)
    assert plot.read_bytes()[:4] == b"\x89PNG"
    assert "000099.png" in capsys.readouterr().err


def test_list_file_and_other_settings(collection, tmp_path, monkeypatch):
    images = sorted(collection.glob("left_rgb/*/*.jpg"))
    assert len(images) == 3  # the loops below check something
    listing = tmp_path / "list.txt"
    listing.write_text("\n".join(os.path.relpath(p, tmp_path) for p in images) + "\n\n")
    monkeypatch.chdir(collection)  # relative paths resolve from the list file's folder
    out = tmp_path / "g.json"
    assert (
        _run(["--data", str(listing), "--metric", "glcment", "--no-blur", "--output", str(out)])
        == 0
    )
    data = json.loads(out.read_text())
    assert data["metric"] == "glcment" and data["use_blur"] is False
    got = {r["image_path"]: r["complexity"] for r in data["results"]}
    assert list(got) == [str(p) for p in images]
    for p in images:
        assert got[str(p)] == pytest.approx(
            official_image_complexity(p, "glcment", blur=False), abs=1e-9
        )


def test_official_json_is_profiled_without_recomputing(tmp_path):
    official = {
        "metric": "delent",
        "num_images": 4,
        "use_blur": True,
        "blur_ksize": 3,
        "results": [
            {"image_path": f"/nowhere/{i}.jpg", "complexity": v}
            for i, v in enumerate([4.1, 3.9, float("nan"), 4.3])
        ],
    }
    src = tmp_path / "complexity_results.json"
    src.write_text(json.dumps(official))  # json writes NaN like the official script
    out = tmp_path / "profiled.json"
    assert _run(["--data", str(src), "--output", str(out), "--plot", str(tmp_path / "p.png")]) == 0
    data = json.loads(out.read_text())
    assert data["num_images"] == 3 and data["errors"][0]["image_path"] == "/nowhere/2.jpg"
    assert data["profile"] == pytest.approx(official_profile([4.1, 3.9, 4.3]), rel=1e-12)


def test_shards_merge_to_the_full_run(collection, tmp_path, capsys):
    pattern = ["--pattern", "**/*.*"]
    full = tmp_path / "full.json"
    assert _run(["--data", str(collection), *pattern, "--output", str(full), "--no-cache"]) == 0
    parts = []
    for k in range(3):
        part = tmp_path / f"part{k}.json"
        assert (
            _run(["--data", str(collection), *pattern, "--shard", f"{k}/3", "--output", str(part)])
            == 0
        )
        assert json.loads(part.read_text())["shard"] == {
            "index": k,
            "count": 3,
            "num_candidates": 7,
        }
        parts.append(str(part))
    merged = tmp_path / "merged.json"
    assert main(["--merge", *parts, "--output", str(merged)]) == 0
    a, b = json.loads(full.read_text()), json.loads(merged.read_text())
    assert a["results"] == b["results"] and a["profile"] == b["profile"]
    assert [e["image_path"] for e in a["errors"]] == [e["image_path"] for e in b["errors"]]
    capsys.readouterr()
    assert main(["--merge", *parts[:2], "--output", str(tmp_path / "m2.json")]) == 0
    err = capsys.readouterr().err
    # The warning's message on one line, not the Python source line that raised it.
    assert "claravid-dsp: warning: shards [2] are missing" in err
    assert "warnings.warn" not in err and "UserWarning" not in err


@pytest.mark.filterwarnings("ignore::claravid.dsp.profile.DegenerateProfileWarning")  # one image
def test_merge_refuses_mismatches(collection, tmp_path, capsys):
    p0, p0b, g1 = (tmp_path / n for n in ("p0.json", "p0b.json", "g1.json"))
    pngs = ["--data", str(collection), "--pattern", "**/*.png"]
    assert _run([*pngs, "--shard", "0/2", "--output", str(p0)]) == 0
    p0b.write_text(p0.read_text())
    assert main(["--merge", str(p0), str(p0b)]) == 2
    assert "given more than once" in capsys.readouterr().err
    assert _run([*pngs, "--shard", "1/2", "--metric", "pixent", "--output", str(g1)]) == 0
    assert main(["--merge", str(p0), str(g1)]) == 2
    assert "same settings" in capsys.readouterr().err


def test_compare_warns_on_resolution_gap(collection, tmp_path, capsys):
    small = tmp_path / "small"
    small.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(small / f"{i}.png"), textured(rng, 40, 53))  # ~17 % smaller
    a, b, c = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "c.json"
    assert _run(["--data", str(collection), "--pattern", "**/*.png", "--output", str(a)]) == 0
    assert _run(["--data", str(collection), "--pattern", "**/*.jpg", "--output", str(b)]) == 0
    assert _run(["--data", str(small), "--pattern", "*.png", "--output", str(c)]) == 0
    capsys.readouterr()
    assert main(["--compare", str(a), str(b)]) == 0
    table = capsys.readouterr().out
    assert "64x48" in table and "WARNING" not in table
    assert main(["--compare", str(a), str(c)]) == 0
    table = capsys.readouterr().out
    assert "WARNING: image resolutions differ by 20 %" in table
    mu = load_results(c).profile.mu
    assert f"{mu:.3f}" in table


@pytest.mark.filterwarnings("ignore::claravid.dsp.profile.DegenerateProfileWarning")  # one image
def test_cache_is_reused_until_the_file_changes(collection, tmp_path):
    image = sorted(collection.glob("**/*.png"))[0]
    truth = profile_images([image]).results[0].complexity
    db = cache_dir() / "dsp.sqlite3"
    with sqlite3.connect(db) as conn:
        assert (
            conn.execute("SELECT value FROM complexity WHERE path=?", (str(image),)).fetchone()[0]
            == truth
        )
        conn.execute("UPDATE complexity SET value=123.0")
    assert profile_images([image]).results[0].complexity == 123.0  # served from the cache
    assert profile_images([image], blur=False).results[0].complexity != 123.0  # other key
    assert profile_images([image], cache=False).results[0].complexity == truth
    st = image.stat()
    os.utime(image, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    assert profile_images([image]).results[0].complexity == truth  # stale entry ignored


@pytest.mark.filterwarnings("ignore::claravid.dsp.profile.DegenerateProfileWarning")  # one image
def test_unwritable_cache_warns_and_still_computes(collection, tmp_path, monkeypatch):
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("")
    monkeypatch.setenv("CLARAVID_CACHE", str(blocker))
    image = sorted(collection.glob("**/*.png"))[0]
    with pytest.warns(RuntimeWarning, match="cache .* switched off"):
        run = profile_images([image])
    assert run.results[0].complexity == pytest.approx(official_image_complexity(image), abs=1e-9)


@pytest.mark.slow
def test_worker_processes_give_the_same_values(collection):
    paths = sorted(collection.glob("**/*.*"))
    serial = profile_images(paths, cache=False)
    parallel = profile_images(paths, workers=2, cache=False)
    assert parallel.results == serial.results and parallel.errors == serial.errors


@pytest.mark.filterwarnings("ignore::claravid.dsp.profile.DegenerateProfileWarning")  # one image
def test_error_paths(collection, tmp_path, capsys):
    missing = tmp_path / "nope"
    assert _run(["--data", str(missing)]) == 2
    assert f"input {missing} does not exist" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert _run(["--data", str(empty), "--pattern", "*.jpg"]) == 2
    err = capsys.readouterr().err
    assert "no files match the pattern '*.jpg'" in err and str(empty) in err
    blank = tmp_path / "blank.txt"
    blank.write_text("\n\n")
    assert _run(["--data", str(blank)]) == 2
    assert "names no images" in capsys.readouterr().err
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "x.jpg").write_bytes(b"nope")
    assert _run(["--data", str(bad), "--output", str(tmp_path / "bad.json")]) == 1
    assert "no image could be read" in capsys.readouterr().err
    assert json.loads((tmp_path / "bad.json").read_text())["profile"]["mu"] is None
    assert _run(["--data", str(collection), "--shard", "3/3"]) == 2
    assert "0 <= k < n" in capsys.readouterr().err
    assert _run(["--data", str(collection), "--shard", "one"]) == 2
    assert "k/n" in capsys.readouterr().err
    assert (
        _run(["--data", str(collection), "--blur-ksize", "4", "--output", str(tmp_path / "k.json")])
        == 2
    )
    assert "must be odd" in capsys.readouterr().err
    notres = tmp_path / "other.json"
    notres.write_text('{"hello": 1}')
    assert _run(["--data", str(notres)]) == 2
    assert "not a complexity results file" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--metric", "entropy", "--data", str(collection)])
    assert main([]) == 2
    assert "give --data (a folder, a list file or a results JSON)" in capsys.readouterr().err
    assert main(["--data", str(collection), "--merge", "a.json"]) == 2
    assert "--merge takes JSON files only; drop --data" in capsys.readouterr().err


def test_profile_images_reports_values_and_errors(collection):
    paths = sorted(collection.glob("left_rgb/45deg_low_h/*"))
    run = profile_images(paths, metric="pixent", cache=False)
    assert [Path(e.image_path).name for e in run.errors] == ["000099.png"]
    assert len(run.results) == 3 and not math.isnan(run.profile.mu)
    assert run.profile.to_dict() == pytest.approx(official_profile(run.values), rel=1e-12)


def _one_error(capsys, match: str) -> str:
    """The run printed exactly one error line containing ``match``, and no traceback."""
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("claravid-dsp: error:")]
    assert len(lines) == 1 and match in lines[0], err
    assert "Traceback" not in err
    return lines[0]


FOREIGN_JSON = {
    "list.json": ([1, 2, 3], "it holds a JSON list"),
    "other_keys.json": ({"hello": 1}, "no 'results' list"),
    "rows_are_strings.json": ({"results": ["a.jpg"]}, "results[0] is 'a.jpg'"),
    "no_path.json": ({"results": [{"complexity": 4.0}]}, "results[0] is {'complexity': 4.0}"),
    "text_value.json": (
        {"results": [{"image_path": "a", "complexity": "4.1"}]},
        "results[0].complexity is '4.1', not a number",
    ),
    "bool_value.json": (
        {"results": [{"image_path": "a", "complexity": True}]},
        "results[0].complexity is True",
    ),
    "text_size.json": (
        {"results": [{"image_path": "a", "complexity": 4.0, "height": "48", "width": 64}]},
        "height/width ('48', 64)",
    ),
    "metric_number.json": ({"metric": 3, "results": []}, "'metric' is 3"),
    "blur_text.json": ({"use_blur": "no", "results": []}, "'use_blur' 'no' must be true/false"),
    "errors_dict.json": ({"results": [], "errors": {"a": 1}}, "'errors' is {'a': 1}"),
    "errors_rows.json": ({"results": [], "errors": [["a", "b"]]}, "errors[0] is ['a', 'b']"),
    "shard_text.json": ({"results": [], "shard": "0/2"}, "'shard' is '0/2'"),
    "shard_range.json": ({"results": [], "shard": {"index": 3, "count": 2}}, "0 <= k < n"),
}


@pytest.mark.parametrize("name", sorted(FOREIGN_JSON))
def test_foreign_json_is_one_line_exit_2_in_every_mode(tmp_path, capsys, name):
    data, match = FOREIGN_JSON[name]
    bad = tmp_path / name
    bad.write_text(json.dumps(data))
    good = tmp_path / "good.json"
    good.write_text(
        json.dumps(
            {
                "metric": "delent",
                "results": [
                    {"image_path": "x", "complexity": 1.0},
                    {"image_path": "y", "complexity": 2.0},
                ],
            }
        )
    )
    for argv in (
        ["--data", str(bad)],
        ["--merge", str(good), str(bad)],
        ["--compare", str(good), str(bad)],
    ):
        assert main(argv) == 2, argv
        line = _one_error(capsys, match)
        assert str(bad) in line and "not a complexity results file" in line


def test_unreadable_json_inputs(tmp_path, capsys):
    (tmp_path / "binary.json").write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff")
    (tmp_path / "folder.json").mkdir()
    for argv, match in [
        (["--merge", str(tmp_path / "binary.json")], "cannot read results JSON"),
        (["--compare", str(tmp_path / "folder.json")], "is a folder, not a results JSON"),
        (["--merge", str(tmp_path / "nope.json")], "results JSON"),
    ]:
        assert main(argv) == 2
        _one_error(capsys, match)


def test_foreign_inputs_and_arguments(collection, tmp_path, capsys):
    image = sorted(collection.glob("**/*.jpg"))[0]
    argvs = [
        (["--data", str(image)], "not a text file listing image paths"),
        (
            ["--data", str(collection), "--pattern", "/abs/*.jpg"],
            "must be a non-empty glob relative",
        ),
        (["--data", str(collection), "--pattern", ""], "must be a non-empty glob relative"),
    ]
    for argv, match in argvs:
        assert main([*argv, "--no-progress", "--output", str(tmp_path / "o.json")]) == 2
        _one_error(capsys, match)
    with pytest.raises(SystemExit) as info:  # argparse's own check, the same on every command
        main(["--data", str(collection), "--workers", "-2", "--output", str(tmp_path / "o.json")])
    assert info.value.code == 2
    assert "argument --workers: expected an integer >= 0, got '-2'" in capsys.readouterr().err
    assert not (tmp_path / "o.json").exists()


def test_unusable_outputs_fail_before_the_computation(collection, tmp_path, capsys, monkeypatch):
    import claravid.dsp.cli as cli

    def forbidden(*args, **kwargs):
        raise AssertionError("the computation must not start")

    monkeypatch.setattr(cli, "profile_images", forbidden)
    blocker = tmp_path / "afile"
    blocker.write_text("mine")
    photo = tmp_path / "photo.jpg"
    photo.write_bytes(b"precious")
    cases = [
        (["--output", str(tmp_path)], "is a folder"),
        (["--output", str(blocker / "r.json")], "is a file, not a folder"),
        (["--plot", str(tmp_path)], "is a folder"),
        (["--plot", str(blocker / "p.png")], "is a file, not a folder"),
        (["--plot", str(tmp_path / "p.xyz")], "give a file name ending in one of"),
        (["--output", str(photo)], "is not a complexity results file; choose another name"),
    ]
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        cases.append((["--output", str(locked / "r.json")], "not writable"))
    for extra, match in cases:
        assert _run(["--data", str(collection), *extra]) == 2, extra
        _one_error(capsys, match)
    assert photo.read_bytes() == b"precious" and blocker.read_text() == "mine"
    monkeypatch.undo()
    # The default output name never replaces a file that is not ours either.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "complexity_results.json").write_text("my notes")
    assert _run(["--data", str(collection), "--pattern", "**/*.png"]) == 2
    _one_error(capsys, "pass --overwrite")
    assert _run(["--data", str(collection), "--pattern", "**/*.png", "--overwrite"]) == 0
    assert json.loads((tmp_path / "complexity_results.json").read_text())["num_images"] == 3
    # ... while a results file of ours is replaced without asking (re-running is normal).
    assert _run(["--data", str(collection), "--pattern", "**/*.jpg"]) == 0
    assert json.loads((tmp_path / "complexity_results.json").read_text())["num_images"] == 3
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert leftovers == []  # atomic writes leave no temp files


def test_an_empty_shard_is_a_usage_error(collection, tmp_path, capsys):
    """``--shard $UNSET`` must not make one task of a job array measure every image."""
    out = tmp_path / "part.json"
    assert (
        _run(
            [
                "--data",
                str(collection),
                "--pattern",
                "**/*.png",
                "--shard",
                "",
                "--output",
                str(out),
            ]
        )
        == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "k/n" in err[0] and "''" in err[0]
    assert not out.exists()
    assert (
        _run(["--data", str(collection), "--pattern", "**/*.png", "--shard", " ", "-o", str(out)])
        == 2
    )
    assert not out.exists()


def test_a_jpeg_header_claiming_more_than_2_30_pixels_is_an_unreadable_image(
    collection, tmp_path, capsys
):
    # OpenCV raised cv2.error for it, which nothing mapped: a traceback. Now it is one more
    # unreadable image, listed with the reason, like the collection's broken PNG.
    good = next(collection.glob("left_rgb/**/*.jpg"))
    data = good.read_bytes()
    sof = data.index(b"\xff\xc0")
    huge = good.with_name("000098.jpg")
    huge.write_bytes(data[: sof + 5] + (65500).to_bytes(2, "big") * 2 + data[sof + 9 :])
    out = tmp_path / "r.json"
    assert (
        _run(["--data", str(collection), "--pattern", "left_rgb/**/*.jpg", "--output", str(out)])
        == 0
    )
    err = capsys.readouterr().err
    assert "Traceback" not in err and "cv2.error" not in err
    errors = {e["image_path"]: e["error"] for e in json.loads(out.read_text())["errors"]}
    assert list(errors) == [str(huge)]
    assert (
        "its header claims 65500×65500 = 4,290,250,000 pixels, more than the " in errors[str(huge)]
    )
