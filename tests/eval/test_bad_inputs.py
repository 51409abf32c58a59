"""Bad inputs a hostile new user found (issue 12 §6): one line each, and no lost or false work."""

import json
import threading

import cv2
import numpy as np
import pytest
import torch

import claravid.eval.run as run_module
from claravid.eval.cli import main
from claravid.eval.predict import main as predict_main
from tests.eval.conftest import WINDOW

FRAMES = ["001_rural_1/45deg_low_h/000000", "003_urban_1/55deg_mid_v/000001"]


@pytest.fixture(scope="module")
def two_frames(tmp_path_factory):
    split = tmp_path_factory.mktemp("split") / "two.txt"
    split.write_text("\n".join(FRAMES) + "\n")
    return split


def _one_line(capsys, *words, prog="claravid-eval"):
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith(f"{prog}: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def _eval(out, *argv):
    return main([*argv, "--output", str(out), "--window", WINDOW, "--bins", "1", "--no-progress"])


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a PyTorch without a GPU")
def test_cuda_on_a_cpu_only_machine_is_one_line(model_files, claravid_root, tmp_path, capsys):
    ckpt = str(model_files["checkpoint"])
    assert _eval(tmp_path / "r", "--checkpoint", ckpt, "--device", "cuda") == 2
    _one_line(capsys, "--device 'cuda'", "use cpu")
    image = next((claravid_root / "001_rural_1").rglob("*.jpg"))
    argv = ["--checkpoint", ckpt, str(image), "-o", str(tmp_path / "p"), "--device", "cuda:1"]
    assert predict_main(argv) == 2
    _one_line(capsys, "--device 'cuda:1'", prog="claravid-predict")


def test_saved_predictions_are_scored_in_their_own_palette(
    model_files, two_frames, tmp_path, capsys
):
    preds, direct = tmp_path / "preds", tmp_path / "direct"
    ckpt = str(model_files["checkpoint"])  # trained with the uavid palette
    argv = ["--split", str(two_frames)]
    assert _eval(direct, "--checkpoint", ckpt, *argv, "--save-predictions", str(preds)) == 0
    assert json.loads((preds / "predictions.json").read_text())["palette"] == "uavid"
    root = json.loads((direct / "report.json").read_text())["source"]["data"]
    data = ["--data", root]
    assert _eval(tmp_path / "again", "--predictions", str(preds), *data, *argv) == 0
    again = json.loads((tmp_path / "again" / "report.json").read_text())
    first = json.loads((direct / "report.json").read_text())
    assert again["palette"] == "uavid"  # from predictions.json, not the ClaraVid default
    assert again["overall"]["miou"] == pytest.approx(first["overall"]["miou"])
    bad = ["--palette", "claravid"]
    assert _eval(tmp_path / "x", "--predictions", str(preds), *data, *argv, *bad) == 2
    _one_line(capsys, "--palette claravid contradicts", "palette uavid")


def test_a_missing_predictions_folder_is_named(claravid_root, tmp_path, capsys):
    argv = ["--predictions", str(tmp_path / "nodir"), "--data", str(claravid_root)]
    assert _eval(tmp_path / "r", *argv) == 2
    _one_line(capsys, f"--predictions {tmp_path / 'nodir'}: folder not found")


def test_interrupted_save_predictions_can_be_run_again(
    model_files, two_frames, tmp_path, monkeypatch
):
    preds = tmp_path / "preds"
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--split", str(two_frames),
            "--save-predictions", str(preds)]  # fmt: skip
    real = run_module.save_label_map

    def ctrl_c(*args, **kwargs):  # injected: the user presses Ctrl-C after the first map
        real(*args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(run_module, "save_label_map", ctrl_c)
    assert _eval(tmp_path / "r", *argv) == 130
    assert (preds / "predictions.json").is_file()  # the marker came first
    monkeypatch.undo()
    assert _eval(tmp_path / "r", *argv) == 0  # the same command, not "not written by this tool"
    assert len(list(preds.rglob("*.png"))) == 2


def test_a_data_error_stops_the_complexity_threads(model_files, tmp_path, capsys):
    """The model path fails on the first image while complexity is still being measured: the
    error must not leave a thread inside OpenCV (the process would abort at exit)."""
    images, masks = tmp_path / "images", tmp_path / "masks"
    images.mkdir(), masks.mkdir()
    rng = np.random.default_rng(0)
    for i in range(24):
        cv2.imwrite(str(images / f"{i:02d}.png"), rng.integers(0, 256, (210, 280, 3), np.uint8))
        size = (20, 30) if i == 0 else (210, 280)  # the first mask belongs to no image here
        cv2.imwrite(str(masks / f"{i:02d}.png"), np.zeros(size, np.uint8))
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--dataset", "folder",
            "--data", str(images), "--masks", str(masks), "--palette", "uavid",
            "--measures", "delent,glcment,pixent"]  # fmt: skip
    assert _eval(tmp_path / "r", *argv) == 2
    alive = [t for t in threading.enumerate() if t.name == "complexity" and t.is_alive()]
    assert not alive
    _one_line(capsys, "size mismatch")


@pytest.mark.parametrize(
    ("flag", "value"), [("--workers", "-1"), ("--hardest", "-2"), ("--window", "0")]
)
def test_bad_numbers_name_the_flag_in_one_line(flag, value, tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["--predictions", str(tmp_path), "--output", str(tmp_path / "o"), flag, value])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "usage:" not in err
    assert f"argument {flag}" in err


def test_predict_finds_webp_in_a_folder(model_files, tmp_path, capsys):
    flight = tmp_path / "flight"
    flight.mkdir()
    cv2.imwrite(str(flight / "a.webp"), np.full((28, 28, 3), 100, np.uint8))
    out = tmp_path / "pred"
    argv = ["--checkpoint", str(model_files["checkpoint"]), str(flight), "-o", str(out),
            "--window", "28", "--no-progress"]  # fmt: skip
    assert predict_main(argv) == 0
    assert (out / "a.png").is_file() and (out / "overlays" / "a.jpg").is_file()
