"""A self-describing ONNX file, and one way to decide how a model is run (issue 13 §1, §2).

A training-style checkpoint records val.window=14, val.scale=0.5, the uavid palette and an input
normalisation that is not ImageNet's; its export carries them; eval and predict, from either
file, with no flags, run the same windows on the same normalised pixels.
"""

import hashlib
import json
import re

import numpy as np
import onnx
import pytest

from claravid import models
from claravid.data.palettes import load_palette
from claravid.data.transforms import IMAGENET_MEAN, IMAGENET_STD
from claravid.eval.cli.evaluate import main as eval_main
from claravid.eval.cli.export import main as export_main
from claravid.eval.cli.predict import main as predict_main
from claravid.eval.settings import InferenceSettings
from claravid.io.modalities import read_dynamic_mask as read_label  # any 8-bit grey PNG
from tests.tiny import tiny_model

FRAMES = ["001_rural_1/45deg_low_h/000000", "001_rural_1/45deg_low_v/000001",
          "003_urban_1/90deg_high_v/000002"]  # fmt: skip
#: The training run's input statistics, not ImageNet's: a reader that falls back to the
#: defaults feeds the model other numbers (and changes 0.7-2.3 % of these frames' labels).
MEAN, STD = [0.45, 0.42, 0.5], [0.2, 0.25, 0.3]


@pytest.fixture(scope="module")
def files(claravid_root, tmp_path_factory):
    folder = tmp_path_factory.mktemp("settings")
    config = {
        "data": {"root": str(claravid_root), "palette": "uavid", "split": {"seed": 0},
                 "augment": {"mean": MEAN, "std": STD}},
        "val": {"window": 14, "scale": 0.5, "batch_size": 2},
    }  # fmt: skip
    # Seed 1: a model whose maps hold two classes and change with the scale (seed 0's are flat).
    model = tiny_model(seed=1)
    ckpt = models.save_checkpoint(model, folder / "best.pt", config=config, step=7)
    # The same model trained with ImageNet's statistics: what a file without metadata runs as.
    imagenet = {**config, "data": {k: v for k, v in config["data"].items() if k != "augment"}}
    ckpt_imagenet = models.save_checkpoint(model, folder / "imagenet.pt", config=imagenet)
    onnx_path = folder / "m.onnx"
    # A fixed-size export of the recorded window (a dynamic one costs 3x the export time).
    assert export_main(["--checkpoint", str(ckpt), "-o", str(onnx_path), "--size", "14"]) == 0
    split = folder / "split.txt"
    split.write_text("\n".join(FRAMES) + "\n")
    foreign = folder / "foreign.onnx"
    proto = onnx.load(str(onnx_path))
    del proto.metadata_props[:]
    onnx.save(proto, str(foreign))
    images = [claravid_root / f.replace("/", "/left_rgb/", 1) for f in FRAMES]
    return {"ckpt": ckpt, "onnx": onnx_path, "foreign": foreign, "split": split,
            "config": config, "images": [p.with_suffix(".jpg") for p in images],
            "ckpt_imagenet": ckpt_imagenet}  # fmt: skip


def test_metadata_round_trip(files):
    runner = models.OnnxSegmenter(files["onnx"])
    uavid = load_palette("uavid")
    assert runner.palette == {
        "name": "uavid",
        "names": list(uavid.names),
        "colors": uavid.colors.tolist(),
        "ignore_index": 255,
    }
    assert (runner.window, runner.stride, runner.scale, runner.batch_size) == ((14, 14), None,
                                                                               0.5, 2)  # fmt: skip
    # The training run's statistics, not ImageNet's (a writer that records the defaults fails).
    assert runner.normalisation["mean"] == MEAN and runner.normalisation["std"] == STD
    assert list(IMAGENET_MEAN) != MEAN and list(IMAGENET_STD) != STD
    assert runner.normalisation["channels"] == "RGB" and runner.dtype == "fp32"
    text = json.dumps(files["config"], sort_keys=True, separators=(",", ":"))
    digest = hashlib.sha256(text.encode()).hexdigest()
    assert runner.training == {"step": 7, "config_sha256": digest}
    assert runner.metadata["model_args"]["backbone"] == "dinov2_vits14"
    foreign = models.OnnxSegmenter(files["foreign"])
    assert foreign.metadata is None and foreign.palette is None and foreign.window is None


def _eval(out, *argv):
    code = eval_main([*argv, "--split", str(_eval.split), "--output", str(out), "--bins", "1",
                      "--hardest", "0", "--no-progress"])  # fmt: skip
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    with np.load(out / "confusions.npz") as saved:
        return report, saved["confusions"]


def test_eval_onnx_without_flags_equals_checkpoint_and_predict_equals_eval(
    files, claravid_root, tmp_path
):
    _eval.split = files["split"]
    rep_ckpt, conf_ckpt = _eval(tmp_path / "c", "--checkpoint", str(files["ckpt"]),
                                "--save-predictions", str(tmp_path / "pc"))  # fmt: skip
    rep_onnx, conf_onnx = _eval(tmp_path / "o", "--onnx", str(files["onnx"]),
                                "--data", str(claravid_root),
                                "--save-predictions", str(tmp_path / "po"))  # fmt: skip
    np.testing.assert_array_equal(conf_onnx, conf_ckpt)  # per image
    for report, kind in ((rep_ckpt, "checkpoint"), (rep_onnx, "onnx")):
        settings = report["source"]["settings"]
        assert settings["window"] == [14, 14] and settings["scale"] == 0.5
        assert settings["batch_size"] == 2 and settings["palette"] == "uavid"
        assert settings["from"]["window"] == kind and settings["from"]["scale"] == kind
        assert settings["from"]["stride"] == "default"  # 2/3 of the recorded window
        assert settings["normalisation"] == {"mean": MEAN, "std": STD}
        assert settings["from"]["normalisation"] == kind
        assert report["palette"] == "uavid"
    for model, saved in (("--checkpoint", "pc"), ("--onnx", "po")):
        out = tmp_path / f"predict{saved}"
        file = files["ckpt"] if model == "--checkpoint" else files["onnx"]
        assert predict_main([model, str(file), *map(str, files["images"]), "--output", str(out),
                             "--no-progress"]) == 0  # fmt: skip
        for frame, image in zip(FRAMES, files["images"], strict=True):
            expected = read_label(tmp_path / saved / f"{frame}.png")
            got = read_label(out / f"{image.stem}.png")
            assert len(np.unique(expected)) > 1  # a flat map would hide a wrong scale
            np.testing.assert_array_equal(got, expected)
        marker = json.loads((out / "predictions.json").read_text())
        assert marker["source"]["settings"]["scale"] == 0.5 and marker["palette"] == "uavid"


def _one_line(capsys, prog, *needles):
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith(f"{prog}: error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    assert all(n in lines[0] for n in needles), lines[0]


def test_foreign_onnx_runs_with_flags_and_says_what_is_missing(
    files, claravid_root, tmp_path, capsys
):
    _eval.split = files["split"]
    argv = ["--onnx", str(files["foreign"]), "--data", str(claravid_root)]
    assert eval_main([*argv, "--output", str(tmp_path / "x")]) == 2
    _one_line(capsys, "claravid-eval", "no claravid metadata",
              "pass --palette, --window and --statistics", "imagenet or sat493m")  # fmt: skip
    assert eval_main([*argv, "--palette", "uavid", "--output", str(tmp_path / "y")]) == 2
    _one_line(capsys, "claravid-eval", "pass --window and --statistics")
    argv += ["--palette", "uavid", "--window", "14"]
    assert eval_main([*argv, "--output", str(tmp_path / "z")]) == 2
    _one_line(capsys, "claravid-eval", "pass --statistics to say how to run it")
    assert not any((tmp_path / n).exists() for n in "xyz")  # refused before any work
    # The statistics named, never assumed: ImageNet's equal the same model trained with them.
    report, foreign = _eval(tmp_path / "f", *argv, "--statistics", "imagenet", "--scale", "0.5")
    settings = report["source"]["settings"]
    assert settings["normalisation"] == {"mean": list(IMAGENET_MEAN), "std": list(IMAGENET_STD)}
    assert settings["from"]["normalisation"] == "flag"
    _, imagenet = _eval(tmp_path / "i", "--checkpoint", str(files["ckpt_imagenet"]))
    np.testing.assert_array_equal(foreign, imagenet)
    _, ckpt = _eval(tmp_path / "c", "--checkpoint", str(files["ckpt"]))
    assert not np.array_equal(foreign, ckpt)  # the statistics matter to this model
    report, sat = _eval(tmp_path / "s", *argv, "--statistics", "sat493m", "--scale", "0.5")
    sat_norm = report["source"]["settings"]["normalisation"]
    assert sat_norm == {"mean": [0.430, 0.411, 0.296], "std": [0.213, 0.156, 0.143]}
    assert not np.array_equal(sat, foreign)
    image = str(files["images"][0])
    assert predict_main(["--onnx", str(files["foreign"]), image, "-o", str(tmp_path / "p")]) == 2
    _one_line(capsys, "claravid-predict", "--palette, --window and --statistics")


def test_statistics_are_refused_where_the_model_file_records_its_own(
    files, claravid_root, tmp_path, capsys
):
    out = tmp_path / "r"
    for flags in (["--checkpoint", str(files["ckpt"])], ["--onnx", str(files["onnx"])]):
        argv = [*flags, "--data", str(claravid_root), "--statistics", "sat493m", "-o", str(out)]
        assert eval_main(argv) == 2
        _one_line(capsys, "claravid-eval", "--statistics is for an ONNX file exported elsewhere",
                  "records the statistics its model was trained with")  # fmt: skip
        assert not out.exists()
    argv = ["--predictions", str(tmp_path), "--data", str(claravid_root), "--statistics",
            "imagenet", "-o", str(out)]  # fmt: skip
    assert eval_main(argv) == 2
    _one_line(capsys, "claravid-eval", "--statistics does nothing with --predictions")
    with pytest.raises(SystemExit):
        eval_main([*argv[:-4], "--statistics", "lvd", "-o", str(out)])
    assert "invalid choice: 'lvd'" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r"unknown --statistics 'lvd' \(input statistics\); use "
                       r"one of imagenet, sat493m"):  # fmt: skip
        InferenceSettings(statistics="lvd")  # the Python API's check


def test_provider_flag(files, tmp_path, capsys):
    import onnxruntime as ort

    image = str(files["images"][0])
    with pytest.raises(SystemExit) as info:
        predict_main(["--onnx", str(files["onnx"]), image, "-o", str(tmp_path / "p"),
                      "--provider", "gpu"])  # fmt: skip
    assert info.value.code == 2 and "invalid choice: 'gpu'" in capsys.readouterr().err
    if "TensorrtExecutionProvider" in ort.get_available_providers():
        pytest.skip("this onnxruntime has TensorRT")
    argv = ["--onnx", str(files["onnx"]), image, "-o", str(tmp_path / "p"), "--provider",
            "tensorrt"]  # fmt: skip
    assert predict_main(argv) == 2
    _one_line(capsys, "claravid-predict", "provider tensorrt is not available here")
    assert predict_main([*argv[:-1], "cpu", "--no-progress"]) == 0


def test_eval_report_gives_the_onnx_files_dtype(files, sat_exports, claravid_root, tmp_path):
    # An ONNX file runs in the number format it was exported in (source.dtype), with no autocast
    # (source.precision null); the report once said "fp32" (PyTorch's autocast setting on a CPU)
    # for an int8 file (the session's, of the tiny SAT model).
    int8 = sat_exports["int8"]
    _eval.split = files["split"]
    foreign = ["--palette", "uavid", "--window", "14", "--statistics", "imagenet"]
    for path, flags, expected in ((int8, [], "int8"), (files["onnx"], [], "fp32"),
                                  (files["foreign"], foreign, None)):  # fmt: skip
        report, _ = _eval(tmp_path / path.stem, "--onnx", str(path), "--data",
                          str(claravid_root), *flags)  # fmt: skip
        assert report["source"]["dtype"] == expected, path.name
        assert report["source"]["precision"] is None, path.name


def test_a_fixed_size_onnx_file_names_its_size_as_a_window_flag():
    """The message suggests a --window value: width x height, like the flag."""
    from types import SimpleNamespace

    from claravid.eval.inference.sources import ModelSource, resolve_settings
    from claravid.infra.cli import UsageError

    fixed = SimpleNamespace(input_size=(28, 42), metadata={})  # height 28, width 42
    source = ModelSource(fixed, "onnx", "m.onnx", num_classes=8, patch_size=14)  # type: ignore[arg-type]
    assert resolve_settings(source, window=(28, 42)).window.size == (28, 42)
    message = "the ONNX model takes 42x28 (WxH) inputs only: use --window 42x28 or re-export"
    with pytest.raises(UsageError, match=re.escape(message)):
        resolve_settings(source, window=(42, 28))


def test_a_non_square_recorded_window_keeps_height_and_width():
    """Every fixture window is square; a 14 (high) x 28 (wide) window and a 7 x 14 stride
    must come back as (height, width) from the ONNX metadata, not swapped."""
    from claravid.eval.inference.sources import onnx_defaults
    from claravid.models.export.metadata import build_metadata, metadata_props, read_metadata

    config = {"val": {"window": [14, 28], "stride": [7, 14]}}
    document = build_metadata({}, patch_size=14, num_classes=8, config=config)
    assert document["window"] == {"size": [14, 28], "stride": [7, 14]}  # [h, w]
    read = onnx_defaults(read_metadata(metadata_props(document)))
    assert read["window"] == (14, 28) and read["stride"] == (7, 14)


def test_predict_onnx_colours_come_from_the_file(claravid_root, tmp_path):
    """A palette that ships nowhere: the ONNX file carries its names and colours, and
    claravid-predict uses them after the YAML is gone (loading it by name would fail)."""
    from importlib.resources import files as package_files

    from claravid.eval.cli.predict import main as predict_main

    shipped = package_files("claravid.configs").joinpath("palettes", "uavid.yaml").read_text()
    yaml = tmp_path / "mine.yaml"  # UAVid's classes under another name, in other colours
    yaml.write_text(shipped.replace("name: uavid", "name: mine").replace(", 0]", ", 1]"))
    names = list(load_palette(yaml).names)
    config = {"data": {"root": str(claravid_root), "palette": str(yaml)}, "val": {"window": 14}}
    ckpt = models.save_checkpoint(tiny_model(), tmp_path / "m.pt", config=config)
    onnx_path = tmp_path / "m.onnx"
    argv = ["--checkpoint", str(ckpt), "-o", str(onnx_path), "--size", "14", "--no-check"]
    assert export_main(argv) == 0
    yaml.unlink()
    image = next((claravid_root / "001_rural_1").rglob("*.jpg"))
    out = tmp_path / "pred"
    argv = ["--onnx", str(onnx_path), str(image), "-o", str(out), "--no-progress"]
    assert predict_main(argv) == 0
    marker = json.loads((out / "predictions.json").read_text())
    assert marker["palette"] == "mine" and marker["classes"] == names


@pytest.mark.parametrize("kind", ["checkpoint", "onnx"])
def test_the_recorded_normalisation_is_what_reaches_the_model(
    files, claravid_root, tmp_path, monkeypatch, kind
):
    """The first window the model receives, caught at the model's own door (a PyTorch forward
    pre-hook, ONNX Runtime's ``run``), equals the frame's pixels normalised by hand with the
    recorded statistics (not ImageNet's)."""
    import cv2
    import torch
    from onnxruntime.capi.onnxruntime_inference_collection import Session

    received = []
    if kind == "checkpoint":

        def hook(module, args):
            if isinstance(module, models.Segmenter):
                received.append(args[0].detach().cpu().numpy().copy())

        handle = torch.nn.modules.module.register_module_forward_pre_hook(hook)
        argv = ["--checkpoint", str(files["ckpt"])]
    else:
        run = Session.run

        def spy(self, output_names, feed, *args, **kwargs):
            received.append(np.array(next(iter(feed.values()))))
            return run(self, output_names, feed, *args, **kwargs)

        monkeypatch.setattr(Session, "run", spy)
        handle = None
        argv = ["--onnx", str(files["onnx"]), "--data", str(claravid_root)]
    one = tmp_path / "one.txt"
    one.write_text(FRAMES[2] + "\n")
    try:  # --scale 1: the windows cut the frame as decoded (no resize between)
        code = eval_main([*argv, "--split", str(one), "--scale", "1", "--bins", "1",
                          "--hardest", "0", "--bootstrap", "0", "--no-progress",
                          "--output", str(tmp_path / "r")])  # fmt: skip
    finally:
        if handle is not None:
            handle.remove()
    assert code == 0 and received
    rgb = cv2.cvtColor(cv2.imread(str(files["images"][2])), cv2.COLOR_BGR2RGB)
    window = rgb[:14, :14].astype(np.float64).transpose(2, 0, 1)  # the window at (0, 0)
    expected = (window / 255 - np.array(MEAN)[:, None, None]) / np.array(STD)[:, None, None]
    first = received[0][0]
    assert first.shape == (3, 14, 14)
    np.testing.assert_allclose(first, expected, atol=1e-5)
    # Every window of the frame went in: 48 x 64 px, 14-px windows every 9 px (2/3), the last
    # flush: rows 0, 9, 18, 27, 34 and columns 0, 9, ..., 45, 50.
    assert sum(len(batch) for batch in received) == 5 * 7
