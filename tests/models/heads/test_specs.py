"""The choice of head: one recorded model argument, so checkpoints, exports and the command
lines rebuild the same head from the file alone; bad names and settings refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from claravid.eval.cli.export import main as export_main
from claravid.models import (
    ExportSettings,
    OnnxSegmenter,
    build_model,
    export_onnx,
    load_checkpoint,
    save_checkpoint,
)
from tests.tiny import VIT as TINY

SETTINGS = {
    "dpt": {"layers": [0, 1, 2, 3], "features": 8, "out_channels": [8, 8, 16, 16]},
    "linear": {"layers": [1, 3], "use_cls": True},
    "upernet": {"layers": [0, 1, 2, 3], "features": 8},
}


def _model(head, backbone="dinov3_vits16", seed=0, num_classes=3):
    """A tiny model whose BatchNorm statistics are not their init (they must travel too)."""
    torch.manual_seed(seed)
    model = build_model(backbone, num_classes, head=head, backbone_kwargs=TINY, **SETTINGS[head])
    with torch.no_grad():
        for module in model.head.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.running_mean.normal_()
                module.running_var.uniform_(0.5, 2.0)
                module.weight.normal_()
        # The classifiers start near zero (std 0.01, as the protocols): label maps would be flat.
        if head != "dpt":
            last = model.head.classifier if head == "upernet" else model.head.conv
            last.weight.normal_(0.0, 0.3)
            last.bias.normal_(0.0, 0.3)
    return model.eval()


def _logits(model, x):
    with torch.no_grad():
        return model.eval()(x)


@pytest.mark.parametrize("head", ["dpt", "linear", "upernet"])
def test_checkpoint_rebuilds_the_head_from_the_file_alone(head, tmp_path):
    model = _model(head)
    assert model.model_args["head"] == head
    assert {k: model.model_args[k] for k in SETTINGS[head]} == SETTINGS[head]
    path = save_checkpoint(model, tmp_path / "m.pt")
    ckpt = torch.load(path, weights_only=True)
    # Only the head's own settings are recorded: none of another head's.
    own = {"dpt": {"layers", "features", "out_channels", "use_cls"},
           "linear": {"layers", "use_cls"}, "upernet": {"layers", "features"}}[head]  # fmt: skip
    assert own <= set(ckpt["model_args"])
    assert not ({"layers", "features", "out_channels", "use_cls"} - own) & set(ckpt["model_args"])
    loaded = load_checkpoint(path)
    assert type(loaded.head) is type(model.head) and loaded.layers == model.layers
    x = torch.randn(2, 3, 48, 80)
    torch.testing.assert_close(_logits(loaded, x), _logits(model, x), atol=0, rtol=0)


def test_a_checkpoint_without_a_head_entry_is_dpt(tmp_path):
    """Checkpoints written before the choice existed name no head: they hold DPT."""
    model = _model("dpt", backbone="dinov2_vits14")
    ckpt = torch.load(save_checkpoint(model, tmp_path / "m.pt"), weights_only=True)
    del ckpt["model_args"]["head"]
    torch.save(ckpt, tmp_path / "old.pt")
    loaded = load_checkpoint(tmp_path / "old.pt")
    x = torch.randn(1, 3, 28, 42)
    torch.testing.assert_close(_logits(loaded, x), _logits(model, x), atol=0, rtol=0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"head": "fcn"}, r"unknown head 'fcn': choose one of dpt, linear, upernet"),
        ({"head": "linear", "features": 64}, r"features is not a setting of the linear head "
                                             r"\(it takes layers, use_cls; features belongs to "
                                             r"dpt, upernet\)"),
        ({"head": "upernet", "out_channels": [8, 8, 8, 8]}, r"out_channels is not a setting of "
                                                            r"the upernet head"),
        ({"head": "upernet", "use_cls": True}, r"use_cls is not a setting of the upernet head"),
        ({"head": "upernet", "layers": [1, 2, 3]}, r"layers needs 4 block indices for the "
                                                   r"upernet head, got \[1, 2, 3\]"),
        ({"head": "dpt", "layers": [3]}, r"layers needs 4 block indices for the dpt head"),
        ({"head": "linear", "layers": []}, r"at least one block index for the linear head"),
        ({"head": "linear", "layers": [4]}, r"layers \[4\] outside the backbone's 4 blocks"),
    ],
)  # fmt: skip
def test_bad_heads_and_settings_are_clear_value_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        build_model("dinov3_vits16", 3, backbone_kwargs=TINY, **kwargs)


def _foreign_checkpoints(tmp_path):
    """A checkpoint naming a head this version lacks, and one with another head's setting."""
    ckpt = torch.load(save_checkpoint(_model("linear"), tmp_path / "m.pt"), weights_only=True)
    future = {**ckpt, "model_args": {**ckpt["model_args"], "head": "segformer"}}
    mixed = {**ckpt, "model_args": {**ckpt["model_args"], "out_channels": [8, 8, 8, 8]}}
    torch.save(future, tmp_path / "future.pt")
    torch.save(mixed, tmp_path / "mixed.pt")
    return {
        tmp_path / "future.pt": "unknown head 'segformer': choose one of dpt, linear, upernet",
        tmp_path / "mixed.pt": "out_channels is not a setting of the linear head",
    }


def test_checkpoints_with_a_foreign_head_are_refused_by_name(tmp_path, capsys):
    import cv2

    from claravid.eval.cli.evaluate import main as eval_main
    from claravid.eval.cli.predict import main as predict_main

    image = tmp_path / "image.png"
    cv2.imwrite(str(image), np.zeros((32, 48, 3), np.uint8))
    commands = {
        "claravid-export": (export_main, ["-o", str(tmp_path / "x.onnx")]),
        "claravid-eval": (eval_main, ["--data", str(tmp_path), "--palette", "uavid",
                                      "--output", str(tmp_path / "report"), "--no-progress"]),
        "claravid-predict": (predict_main, [str(image), "-o", str(tmp_path / "pred"),
                                            "--palette", "uavid", "--no-progress"]),
    }  # fmt: skip
    for path, match in _foreign_checkpoints(tmp_path).items():
        with pytest.raises(ValueError, match=match):
            load_checkpoint(path)
        for prog, (main, argv) in commands.items():
            assert main(["--checkpoint", str(path), *argv]) == 2, prog
            err = capsys.readouterr().err
            lines = [line for line in err.splitlines() if line.startswith(f"{prog}: error:")]
            assert len(lines) == 1 and match in lines[0], (prog, err)
            assert "Traceback" not in err
    assert not (tmp_path / "x.onnx").exists()


@pytest.mark.parametrize("head", ["linear", "upernet"])
def test_predict_labels_an_image_with_the_checkpoint_s_head(head, tmp_path, capsys):
    """claravid-predict rebuilds the head from the checkpoint: the label map of a one-window
    image is the model's argmax on the pixels normalised by hand."""
    import cv2

    from claravid.eval.cli.predict import main as predict_main
    from claravid.models.backbones.specs import IMAGENET_MEAN, IMAGENET_STD

    model = _model(head, num_classes=8)  # the uavid palette's classes
    checkpoint = save_checkpoint(model, tmp_path / "m.pt", config={"data": {"palette": "uavid"}})
    rng = np.random.default_rng(0)
    coarse = rng.integers(0, 256, (3, 5, 3)).astype(np.uint8)  # smooth colour fields
    bgr = cv2.resize(coarse, (80, 48), interpolation=cv2.INTER_LINEAR)
    cv2.imwrite(str(tmp_path / "a.png"), bgr)
    argv = ["--checkpoint", str(checkpoint), str(tmp_path / "a.png"), "-o",
            str(tmp_path / "pred"), "--window", "80x48", "--no-overlays",
            "--no-progress"]  # fmt: skip
    assert predict_main(argv) == 0, capsys.readouterr().err
    x = (bgr[..., ::-1] / 255 - np.array(IMAGENET_MEAN)) / np.array(IMAGENET_STD)
    expected = _logits(model, torch.from_numpy(x.transpose(2, 0, 1)[None]).float())[0].argmax(0)
    assert len(np.unique(expected.numpy())) > 1  # a flat map would pass with any image
    label_map = cv2.imread(str(tmp_path / "pred" / "a.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(label_map, expected.numpy())


@pytest.mark.slow
@pytest.mark.parametrize("head", ["linear", "upernet"])
def test_exports_fixed_and_dynamic_in_every_precision(head, tmp_path):
    """fp32 fixed and dynamic (ONNX Runtime at other sizes than the example: UperNet's pooling
    cells follow the symbolic size), fp16 dynamic, int8 fixed; the file rebuilds nothing but
    records the head."""
    model = _model(head)
    fixed = export_onnx(model, tmp_path / "f.onnx", ExportSettings(height=48, width=80))
    assert fixed["max_abs_diff"] < 1e-4
    runner = OnnxSegmenter(tmp_path / "f.onnx")
    assert runner.model_args["head"] == head and runner.input_size == (48, 80)
    export_onnx(model, tmp_path / "d.onnx", ExportSettings(height=48, width=48, dynamic=True))
    runner = OnnxSegmenter(tmp_path / "d.onnx")
    rng = np.random.default_rng(0)
    for shape in [(1, 3, 48, 48), (2, 3, 64, 112), (1, 3, 112, 32)]:
        x = rng.standard_normal(shape).astype(np.float32)
        np.testing.assert_allclose(runner(x), _logits(model, torch.from_numpy(x)), atol=1e-4)
    fp16 = ExportSettings(height=48, width=48, dynamic=True, dtype="fp16")
    assert export_onnx(model, tmp_path / "h.onnx", fp16)["max_abs_diff"] < 5e-2
    int8 = ExportSettings(height=48, width=80, dtype="int8")
    assert export_onnx(model, tmp_path / "q.onnx", int8)["agreement"] >= 0.97
