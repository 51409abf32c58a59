"""The demo end to end at a tiny size: generation, summary, sample sheet, reuse."""

import json

import pytest
from PIL import Image

from claravid.synth.demo import main, prepare_data
from tests.claravid.dsp.reference import official_image_complexity
from tests.claravid.dsp.reference_profile import official_profile


def test_demo_end_to_end(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["-o", str(out), "--size", "64x48", "--frames-per-viewpoint", "1"]) == 0
    text = capsys.readouterr().out
    assert "48 frames" in text  # 8 missions × 6 viewpoints × 1 frame
    assert "urban_high_1" in text and "pixel share per class" in text
    sheet = Image.open(out / "samples.png")
    assert sheet.size[0] > 300 and sheet.size[1] > 8 * 100  # one row per mission
    assert "Delentropic Scene Profile per mission" in text
    profile = json.loads((out / "dsp_urban_1.json").read_text())
    assert profile["num_images"] == 6 and profile["metric"] == "delent"
    # The profile of urban_1's 6 frames, recomputed by the reference formulation of the paper.
    frames = sorted((out / "data" / "003_urban_1" / "left_rgb").glob("*/*.jpg"))
    assert len(frames) == 6
    expected = official_profile([official_image_complexity(p) for p in frames])
    for key in ("mu", "sigma", "alpha", "beta"):
        assert profile["profile"][key] == pytest.approx(expected[key], rel=1e-9), key
    assert Image.open(out / "dsp_profiles.png").size[0] > 600
    assert main(["-o", str(out), "--size", "64x48", "--frames-per-viewpoint", "1"]) == 0
    assert "reusing" in capsys.readouterr().out


def test_demo_refuses_a_folder_it_did_not_write(tmp_path, capsys):
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "samples.png").write_bytes(b"my picture")
    assert main(["-o", str(theirs), "--size", "64x48", "--frames-per-viewpoint", "1"]) == 2
    err = capsys.readouterr().err
    assert "claravid-demo: error:" in err and "--overwrite" in err and "Traceback" not in err
    assert (theirs / "samples.png").read_bytes() == b"my picture"
    assert sorted(p.name for p in theirs.iterdir()) == ["samples.png"]
    with pytest.raises(SystemExit) as info:
        main(["-o", str(tmp_path / "d"), "--workers", "-1"])
    assert info.value.code == 2
    assert "argument --workers: expected an integer >= 0, got '-1'" in capsys.readouterr().err


def test_new_settings_leave_no_frame_of_the_old_scene(tmp_path, monkeypatch):
    import functools

    import claravid.synth.demo as demo

    # One mission and viewpoint is enough to see stale frames, and 16x faster than all.
    small = functools.partial(demo.synthesize, missions="rural_1", altitude="low", direction="h")
    monkeypatch.setattr(demo, "synthesize", small)
    data = prepare_data(tmp_path, (16, 12), frames=2, seed=0)
    assert {p.stem for p in data.rglob("*.jpg")} == {"000000", "000001"}
    prepare_data(tmp_path, (16, 12), frames=1, seed=0)
    assert {p.stem for p in data.rglob("*.jpg")} == {"000000"}
    assert (data / ".demo-complete").read_text() == "size=(16, 12) frames=1 seed=0"


def test_make_demo_runs_the_evaluation_training_suggests(tmp_path, monkeypatch, capsys):
    """The evaluation line of `make demo` is the command `claravid-train --config demo` prints
    (before: training suggested runs/demo/train/report, the Makefile wrote runs/demo/report)."""
    import shlex
    from pathlib import Path
    from types import SimpleNamespace

    import claravid.train.loop as loop
    from claravid.train.cli import main as train_main

    makefile = (Path(__file__).resolve().parents[3] / "Makefile").read_text()
    recipe = [line.split() for line in makefile.splitlines() if "claravid-eval" in line]
    assert len(recipe) == 1
    make_eval = [word.replace("$(BIN)/", "") for word in recipe[0]]

    monkeypatch.chdir(tmp_path)  # the demo's relative out_dir, with the best.pt it leaves
    (tmp_path / "runs" / "demo" / "train").mkdir(parents=True)
    (tmp_path / "runs" / "demo" / "train" / "best.pt").touch()
    result = SimpleNamespace(out_dir=Path("runs/demo/train"), best_miou=None, last_val={})
    monkeypatch.setattr(loop, "train", lambda cfg, resume=False: result)
    assert train_main(["--config", "demo", "--resume"]) == 0
    printed = [
        line for line in capsys.readouterr().out.splitlines() if line.startswith("evaluate:")
    ]
    assert len(printed) == 1
    assert shlex.split(printed[0].removeprefix("evaluate:")) == make_eval
