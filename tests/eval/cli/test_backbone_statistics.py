"""The statistics follow the weights on every entry point (issue 26): a DINOv3 SAT model trained
without naming its statistics is evaluated, exported and predicted with SAT-493M's, and files
made before (ImageNet's statistics, a ``dinov2_*`` backbone) evaluate as they did.

What reaches the model is checked by undoing a normalisation on it: only the statistics that
were applied give back whole pixel values (the windows are at scale 1, so no resize blends
them).
"""

import json
from pathlib import Path

import numpy as np
import onnx
import pytest
import torch

from claravid import models
from claravid.data.segmentation import ClaraVidSegmentation
from claravid.eval.cli.evaluate import main as eval_main
from claravid.eval.cli.export import main as export_main
from claravid.eval.cli.predict import main as predict_main
from claravid.eval.inference.windows import WindowConfig, predict_labels
from claravid.io.modalities import read_dynamic_mask as read_label  # any 8-bit grey PNG
from claravid.models.export.metadata import build_metadata, read_metadata
from claravid.train import load_config
from claravid.train.config import to_plain
from tests.tiny import HEAD, MODEL, tiny, tiny_v3

# The published statistics, typed here (not read from the code under test).
SAT493M = ([0.430, 0.411, 0.296], [0.213, 0.156, 0.143])
IMAGENET = ([0.485, 0.456, 0.406], [0.229, 0.224, 0.225])
FRAMES = ["001_rural_1/45deg_low_h/000000", "003_urban_1/90deg_high_v/000002"]


@pytest.fixture(scope="module")
def sat_run(trained_sat, tmp_path_factory):
    """The session's tiny dinov3_vitl16_sat model, trained 2 steps from a config that names no
    statistics, and a split file of two frames."""
    folder = tmp_path_factory.mktemp("sat")
    split = folder / "split.txt"
    split.write_text("\n".join(FRAMES) + "\n")
    root = Path(trained_sat["root"])
    images = [root / f.replace("/", "/left_rgb/", 1) for f in FRAMES]
    return {"ckpt": trained_sat["ckpt"], "split": split, "root": str(root), "folder": folder,
            "images": [p.with_suffix(".jpg") for p in images]}  # fmt: skip


@pytest.fixture
def sat_onnx(sat_exports):
    """The SAT model's fixed-size export at its recorded window (32²), through claravid-export."""
    return sat_exports["fixed"]


def _inputs_while(run):
    """Every float tensor a module was called with while ``run()`` ran (the windows)."""
    seen = []

    def keep(module, args):
        x = args[0] if args else None
        if (
            isinstance(x, torch.Tensor)
            and x.is_floating_point()
            and x.ndim == 4
            and x.shape[1] == 3
        ):
            seen.append(x.detach().clone())

    handle = torch.nn.modules.module.register_module_forward_pre_hook(keep)
    try:
        assert run() == 0
    finally:
        handle.remove()
    assert seen, "the model was never called"
    return seen


def _whole_pixels(x, mean, std):
    pixels = (x * torch.tensor(std).view(3, 1, 1) + torch.tensor(mean).view(3, 1, 1)) * 255
    return bool(torch.allclose(pixels, pixels.round(), rtol=0, atol=2e-3)) and pixels.std() > 1


def _eval(out, *argv):
    code = eval_main([*argv, "--output", str(out), "--bins", "1", "--hardest", "0",
                      "--bootstrap", "0", "--no-progress"])  # fmt: skip
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    with np.load(out / "confusions.npz") as saved:
        return report, saved["confusions"]


def _eval_checkpoint(sat_run, out):
    """claravid-eval --checkpoint of the SAT model: (report, confusions, model inputs)."""
    done = {}

    def run():
        done["report"], done["conf"] = _eval(out, "--checkpoint", str(sat_run["ckpt"]),
                                             "--split", str(sat_run["split"]))  # fmt: skip
        return 0

    windows = _inputs_while(run)
    return done["report"], done["conf"], windows


def test_eval_checkpoint_runs_the_sat_model_on_sat_statistics(sat_run, tmp_path):
    report, _, windows = _eval_checkpoint(sat_run, tmp_path / "c")
    assert all(w.shape[-2:] == (32, 32) for w in windows)  # the recorded window, 2 x 2 patches
    assert all(_whole_pixels(w, *SAT493M) for w in windows)
    assert not _whole_pixels(windows[0], *IMAGENET)  # the check tells the two apart
    settings = report["source"]["settings"]
    assert settings["normalisation"] == {"mean": SAT493M[0], "std": SAT493M[1]}
    assert settings["from"]["normalisation"] == "checkpoint" and settings["window"] == [32, 32]


def test_predict_checkpoint_runs_the_sat_model_on_sat_statistics(sat_run, tmp_path):
    images = [str(p) for p in sat_run["images"]]
    out = tmp_path / "pc"
    argv = ["--checkpoint", str(sat_run["ckpt"]), *images, "--output", str(out), "--no-progress"]
    windows = _inputs_while(lambda: predict_main(argv))
    assert all(_whole_pixels(w, *SAT493M) for w in windows)
    marker = json.loads((out / "predictions.json").read_text())
    assert marker["source"]["settings"]["normalisation"]["mean"] == SAT493M[0]


@pytest.mark.slow
def test_the_export_records_sat_statistics_and_onnx_runs_as_the_checkpoint(
    sat_run, sat_onnx, tmp_path
):
    """The metadata says SAT-493M; claravid-eval --onnx and claravid-predict --onnx read it,
    so ONNX Runtime gets what the PyTorch model got: the same confusions and label maps."""
    props = {p.key: p.value for p in onnx.load(str(sat_onnx)).metadata_props}
    document = read_metadata(props)
    assert document["normalisation"]["mean"] == SAT493M[0]
    assert document["normalisation"]["std"] == SAT493M[1]
    assert document["patch_size"] == 16
    assert document["model_args"]["backbone"] == "dinov3_vitl16_sat"
    _, expected, _ = _eval_checkpoint(sat_run, tmp_path / "c")
    report, conf = _eval(tmp_path / "o", "--onnx", str(sat_onnx), "--split",
                         str(sat_run["split"]), "--data", sat_run["root"])  # fmt: skip
    settings = report["source"]["settings"]
    assert settings["normalisation"] == {"mean": SAT493M[0], "std": SAT493M[1]}
    assert settings["from"]["normalisation"] == "onnx"
    np.testing.assert_allclose(conf, expected, atol=2)  # ORT's float rounding: a pixel or two
    images = [str(p) for p in sat_run["images"]]
    for flag, model, out in (("--checkpoint", sat_run["ckpt"], "pc"), ("--onnx", sat_onnx, "po")):
        assert predict_main([flag, str(model), *images, "--output", str(tmp_path / out),
                             "--no-progress"]) == 0  # fmt: skip
    for image in sat_run["images"]:
        ours = read_label(tmp_path / "pc" / f"{image.stem}.png")
        theirs = read_label(tmp_path / "po" / f"{image.stem}.png")
        assert (ours == theirs).mean() > 0.99


@pytest.mark.slow
def test_the_sat_model_exports_dynamic_fp16_and_int8_checked_by_onnx_runtime(
    sat_run, sat_exports, tmp_path, capsys
):
    """As for DINOv2: every export passes the ONNX Runtime check (exit 0 only then) and
    records the SAT statistics."""
    for name in ("dynamic", "fp16", "int8"):
        runner = models.OnnxSegmenter(sat_exports[name])
        assert "argmax agreement" in sat_exports.printed[name], name  # the check ran
        assert runner.normalisation["mean"] == SAT493M[0] and runner.patch_size == 16
    assert models.OnnxSegmenter(sat_exports["dynamic"]).input_size is None
    # The dynamic file runs any patch multiple: a 48 x 64 frame's windows of 32.
    report, _ = _eval(tmp_path / "d", "--onnx", str(sat_exports["dynamic"]), "--split",
                      str(sat_run["split"]), "--data", sat_run["root"])  # fmt: skip
    assert report["source"]["settings"]["window"] == [32, 32]
    # A window off its patch grid: one line naming the two nearest, from --onnx too.
    argv = ["--onnx", str(sat_exports["dynamic"]), "--data", sat_run["root"], "--split",
            str(sat_run["split"]), "--window", "630", "-o", str(tmp_path / "w")]  # fmt: skip
    capsys.readouterr()
    assert eval_main(argv) == 2
    assert "patch size 16: use 624x624 or 640x640" in capsys.readouterr().err
    image = str(sat_run["images"][0])
    argv = [
        "--onnx",
        str(sat_exports["dynamic"]),
        image,
        "--window",
        "630",
        "-o",
        str(tmp_path / "p"),
    ]
    assert predict_main(argv) == 2
    assert "patch size 16: use 624x624 or 640x640" in capsys.readouterr().err


def test_statistics_a_config_named_are_the_ones_evaluation_reads(claravid_root, tmp_path):
    """A SAT model trained on ImageNet's statistics by choice (the config named them; training
    warned): claravid-eval normalises with the recorded numbers, not the backbone's."""
    stats = [f"data.augment.mean={IMAGENET[0]}", f"data.augment.std={IMAGENET[1]}"]
    cfg = to_plain(load_config("demo", tiny_v3(claravid_root, tmp_path / "run", *stats,
                                               backbone="dinov3_vitl16_sat")))  # fmt: skip
    torch.manual_seed(0)
    kwargs = cfg["model"]["backbone_kwargs"]
    model = models.build_model("dinov3_vitl16_sat", 8, backbone_kwargs=kwargs, **HEAD)
    ckpt = models.save_checkpoint(model, tmp_path / "imagenet.pt", config=cfg)
    split = tmp_path / "split.txt"
    split.write_text(FRAMES[0] + "\n")
    found = {}

    def run():
        found["report"], _ = _eval(
            tmp_path / "rep", "--checkpoint", str(ckpt), "--split", str(split)
        )
        return 0

    windows = _inputs_while(run)
    assert all(_whole_pixels(w, *IMAGENET) for w in windows)
    assert not _whole_pixels(windows[0], *SAT493M)
    settings = found["report"]["source"]["settings"]
    assert settings["normalisation"] == {"mean": IMAGENET[0], "std": IMAGENET[1]}
    assert settings["from"]["normalisation"] == "checkpoint"


def test_metadata_of_a_config_without_statistics_records_the_backbone_s():
    """A plain checkpoint's export (no training config) records the statistics of the backbone
    it names, SAT-493M's for a _sat model; a config's own numbers win."""
    sat = build_metadata({"backbone": "dinov3_vitl16_sat"}, patch_size=16, num_classes=8)
    assert (sat["normalisation"]["mean"], sat["normalisation"]["std"]) == SAT493M
    config = {"data": {"augment": {"mean": IMAGENET[0], "std": IMAGENET[1]}}}
    named = build_metadata({"backbone": "dinov3_vitl16_sat"}, patch_size=16, num_classes=8,
                           config=config)  # fmt: skip
    assert (named["normalisation"]["mean"], named["normalisation"]["std"]) == IMAGENET
    web = build_metadata({"backbone": "dinov3_vitl16"}, patch_size=16, num_classes=8)
    assert (web["normalisation"]["mean"], web["normalisation"]["std"]) == IMAGENET


def _old_checkpoint(claravid_root, folder):
    """A checkpoint as the version before the backbone defaults wrote it: a dinov2_* model and
    a resolved config recording ImageNet's mean and std and the window as numbers."""
    cfg = to_plain(load_config("demo", tiny(claravid_root, folder / "run")))
    cfg["data"]["augment"]["mean"] = list(IMAGENET[0])
    cfg["data"]["augment"]["std"] = list(IMAGENET[1])
    cfg["val"]["window"] = 28
    cfg["data"]["palette"] = "uavid"
    torch.manual_seed(4)
    model = models.build_model("dinov2_vits14", 8, **MODEL).eval()
    return model, models.save_checkpoint(model, folder / "old.pt", config=cfg, step=5)


def test_a_checkpoint_made_before_evaluates_as_it_did(claravid_root, tmp_path):
    """ImageNet's statistics and the recorded 28² windows: the label maps equal the model's
    windows over frames normalised by hand."""
    model, ckpt = _old_checkpoint(claravid_root, tmp_path)
    split = tmp_path / "split.txt"
    split.write_text("\n".join(FRAMES) + "\n")
    report, _ = _eval(tmp_path / "c", "--checkpoint", str(ckpt), "--split", str(split),
                      "--save-predictions", str(tmp_path / "pc"))  # fmt: skip
    settings = report["source"]["settings"]
    assert settings["normalisation"] == {"mean": IMAGENET[0], "std": IMAGENET[1]}
    for frame, expected in _by_hand(model, claravid_root, split):
        np.testing.assert_array_equal(read_label(tmp_path / "pc" / f"{frame}.png"), expected)


@pytest.mark.slow
def test_an_onnx_file_made_before_evaluates_as_it_did(claravid_root, tmp_path):
    """Exported from such a checkpoint, the file records ImageNet's statistics and a dinov2_*
    backbone (its document is what the previous version wrote), and evaluates the same."""
    model, ckpt = _old_checkpoint(claravid_root, tmp_path)
    split = tmp_path / "split.txt"
    split.write_text("\n".join(FRAMES) + "\n")
    path = tmp_path / "old.onnx"
    assert export_main(["--checkpoint", str(ckpt), "-o", str(path), "--size", "28",
                        "--no-progress"]) == 0  # fmt: skip
    runner = models.OnnxSegmenter(path)
    assert (
        runner.normalisation["mean"] == IMAGENET[0] and runner.normalisation["std"] == IMAGENET[1]
    )
    assert runner.metadata["model_args"]["backbone"] == "dinov2_vits14" and runner.patch_size == 14
    _eval(tmp_path / "o", "--onnx", str(path), "--split", str(split), "--save-predictions",
          str(tmp_path / "po"), "--data", str(claravid_root))  # fmt: skip
    for frame, expected in _by_hand(model, claravid_root, split):
        assert (read_label(tmp_path / "po" / f"{frame}.png") == expected).mean() > 0.99


def _by_hand(model, root, split):
    """(frame, label map) of ``model`` over each frame normalised with ImageNet's statistics
    by hand, in 28² windows."""
    data = ClaraVidSegmentation(root, split=split, palette="uavid")
    mean, std = torch.tensor(IMAGENET[0]).view(3, 1, 1), torch.tensor(IMAGENET[1]).view(3, 1, 1)
    for i, frame in enumerate(FRAMES):
        x = (data[i]["image"].float() / 255 - mean) / std
        yield frame, predict_labels(model, x, WindowConfig(size=28)).numpy()
