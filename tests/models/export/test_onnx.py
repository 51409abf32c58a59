"""ONNX export, onnxruntime on other shapes than the export example, and the CLI."""

import numpy as np
import pytest
import torch

from claravid.eval.cli.export import main
from claravid.models import (
    ExportCheckError,
    OnnxSegmenter,
    build_model,
    export_onnx,
    load_checkpoint,
    save_checkpoint,
)
from claravid.models.export.onnx import ExportSettings, check_export
from tests.models.weights.official_v3 import random_official_v3_state
from tests.tiny import VIT
from tests.tiny import VIT_56 as TINY
from tests.tiny import WIDE_HEAD as HEAD


def _model(name):
    torch.manual_seed(0)
    return build_model(name, num_classes=3, backbone_kwargs=TINY, **HEAD).eval()


def _as_version_1(src, dst):
    """``src`` with the metadata claravid 0.1 wrote: version 1, ``claravid.input_size`` HxW."""
    import json

    import onnx

    proto = onnx.load(str(src))
    props = {p.key: p.value for p in proto.metadata_props}
    document = json.loads(props["claravid"])
    document["version"] = 1
    props["claravid"] = json.dumps(document)
    height, width = document["input_size"]
    props["claravid.input_size"] = f"{height}x{width}"
    del proto.metadata_props[:]
    for key, value in props.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(dst))
    return dst


def test_version_1_readable_size_without_a_document_reads_hxw():
    from claravid.models.export.metadata import read_input_size

    assert read_input_size({"claravid.input_size": "42x70"}) == (42, 70)  # no document: v1
    v2 = '{"format": "claravid-onnx", "version": 2, "input_size": null}'
    assert read_input_size({"claravid": v2, "claravid.input_size": "70x42"}) == (42, 70)


def _torch_logits(model, x):
    with torch.no_grad():
        return model(torch.from_numpy(x)).numpy()


@pytest.mark.slow
def test_fixed_size_export(tmp_path, capsys):
    model = _model("dinov2_vits14_reg")  # antialiased bicubic: stored positional table
    result = export_onnx(model, tmp_path / "m.onnx", ExportSettings(height=42, width=70))
    assert result["check_shape"] == (3, 3, 42, 70) and result["max_abs_diff"] < 1e-4
    assert model.backbone._frozen_pos is None  # export leaves the model as it was
    runner = OnnxSegmenter(tmp_path / "m.onnx")
    assert runner.input_size == (42, 70) and runner.num_classes == 3 and runner.patch_size == 14
    meta = runner.session.get_modelmeta().custom_metadata_map
    assert meta["claravid.input_size"] == "70x42"  # WxH, as every size the project prints
    # A version-1 file (HxW readable key) still reads as (height, width).
    old = _as_version_1(tmp_path / "m.onnx", tmp_path / "old.onnx")
    assert OnnxSegmenter(old).input_size == (42, 70)
    assert runner.model_args["backbone"] == "dinov2_vits14_reg"
    x = np.random.default_rng(0).standard_normal((1, 3, 42, 70)).astype(np.float32)
    np.testing.assert_allclose(runner(x), _torch_logits(model, x), atol=1e-4)
    with pytest.raises(
        ValueError, match=r"exported for 70x42 \(WxH\) inputs, got 70x56.*--dynamic"
    ):
        runner(np.zeros((1, 3, 56, 70), np.float32))
    # The same input checks as the PyTorch model (one implementation, models/inputs.py).
    with pytest.raises(TypeError, match=r"dtype uint8: convert to float and normalise"):
        runner(np.zeros((1, 3, 42, 70), np.uint8))
    with pytest.raises(ValueError, match=r"got shape \[3, 42, 70\]"):
        runner(np.zeros((3, 42, 70), np.float32))
    with torch.no_grad():  # a changed model no longer matches the file
        model.head.head[-1].bias += 1.0
    with pytest.raises(ExportCheckError, match="differs from PyTorch by 1"):
        check_export(model, tmp_path / "m.onnx", 42, 70, dynamic=False)


@pytest.mark.slow
def test_dynamic_export_other_sizes(model_files, model_onnx):
    """The session's dynamic export, made at the native 4x4 grid: the offset bicubic must still
    follow other sizes."""
    model = model_files["model"]
    assert model_onnx["export"]["max_abs_diff"] < 1e-4
    runner = OnnxSegmenter(model_onnx["onnx"])
    assert runner.input_size is None
    rng = np.random.default_rng(1)
    for shape in [(1, 3, 56, 56), (4, 3, 84, 42), (1, 3, 14, 98)]:
        x = rng.standard_normal(shape).astype(np.float32)
        np.testing.assert_allclose(runner(x), _torch_logits(model, x), atol=1e-4)
    with pytest.raises(ValueError, match="patch size 14: pad or resize it to 56x70"):
        runner(np.zeros((1, 3, 50, 60), np.float32))


@pytest.mark.slow
def test_dinov3_fixed_and_dynamic_export(trained_sat, sat_exports, tmp_path):
    """RoPE exports both ways: stored sin/cos at a fixed size, computed from the symbolic grid
    when H and W are dynamic (ONNX Runtime then agrees at sizes other than the example's).
    Both use the periods the model holds (a loaded file's), not the formula's."""
    torch.manual_seed(0)
    model = build_model("dinov3_vits16", num_classes=3, backbone_kwargs=VIT, **HEAD).eval()
    # Weights of official scale (a random init's attention is nearly uniform, and RoPE would
    # hardly show in the logits), then periods no formula gives.
    model.backbone.load_state_dict(random_official_v3_state(model.backbone, seed=1))
    probe = np.random.default_rng(0).standard_normal((1, 3, 48, 80)).astype(np.float32)
    before = _torch_logits(model, probe)
    with torch.no_grad():
        model.backbone.rope_embed.periods.mul_(1.5)
    assert np.abs(_torch_logits(model, probe) - before).max() > 1e-3  # 40x the checks below
    fixed = export_onnx(model, tmp_path / "f.onnx", ExportSettings(height=48, width=80))
    assert fixed["max_abs_diff"] < 1e-4
    assert model.backbone.rope_embed._frozen is None  # export leaves the model as it was
    runner = OnnxSegmenter(tmp_path / "f.onnx")
    assert runner.patch_size == 16 and runner.input_size == (48, 80)
    x = np.random.default_rng(2).standard_normal((2, 3, 48, 80)).astype(np.float32)
    np.testing.assert_allclose(runner(x), _torch_logits(model, x), atol=1e-4)
    model = load_checkpoint(trained_sat["ckpt"]).eval()
    runner = OnnxSegmenter(sat_exports["dynamic"])
    assert runner.patch_size == 16 and runner.input_size is None
    rng = np.random.default_rng(3)
    for shape in [(1, 3, 48, 48), (2, 3, 64, 96), (1, 3, 80, 48)]:
        x = rng.standard_normal(shape).astype(np.float32)
        np.testing.assert_allclose(runner(x), _torch_logits(model, x), atol=1e-4)
    with pytest.raises(ValueError, match="patch size 16: pad or resize it to 64x64"):
        runner(np.zeros((1, 3, 50, 60), np.float32))


@pytest.mark.slow
def test_cli(tmp_path, capsys):
    model = _model("dinov2_vits14")
    ckpt = save_checkpoint(model, tmp_path / "m.pt")
    out = tmp_path / "cli.onnx"
    assert main(["--checkpoint", str(ckpt), "--output", str(out), "--size", "42x28"]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {out}" in printed and "max abs diff of logits" in printed
    x = np.random.default_rng(2).standard_normal((2, 3, 28, 42)).astype(np.float32)
    np.testing.assert_allclose(OnnxSegmenter(out)(x), _torch_logits(model, x), atol=1e-4)


def test_cli_errors(tmp_path, capsys):
    assert main(["--checkpoint", str(tmp_path / "none.pt"), "-o", str(tmp_path / "x.onnx")]) == 2
    assert "none.pt not found" in capsys.readouterr().err
    ckpt = save_checkpoint(_model("dinov2_vits14"), tmp_path / "m.pt")
    assert main(["--checkpoint", str(ckpt), "-o", str(tmp_path / "x.onnx"), "--size", "70x30"]) == 2
    # Said as --size values, width x height, the two nearest: 30 rounds to 28 or 42.
    err = capsys.readouterr().err
    assert "input size 70x30 (WxH) is not a multiple of the model's patch size 14" in err
    assert "use --size 70x28 or --size 70x42" in err
    with pytest.raises(FileNotFoundError, match="claravid-export"):
        OnnxSegmenter(tmp_path / "x.onnx")


def _one_error_line(capsys, match):
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("claravid-export: error:")]
    assert len(lines) == 1 and match in lines[0], err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--tolerance", "-1"], "expected a finite number > 0, got '-1'"),
        (["--tolerance", "nan"], "expected a finite number > 0"),
        (["--tolerance", "0"], "expected a finite number > 0"),
        (["--size", "0x28"], "width and height must be positive, got '0x28'"),
        (["--size", "28by28"], "expected WxH (width x height, e.g. 640x480) or N"),
    ],
)
def test_cli_rejects_nonsense_numbers(tmp_path, capsys, args, match):
    with pytest.raises(SystemExit) as info:
        main(["--checkpoint", "m.pt", "-o", str(tmp_path / "x.onnx"), *args])
    assert info.value.code == 2
    assert match in capsys.readouterr().err


def test_cli_checkpoint_flag_and_size(tmp_path, capsys):
    """``--checkpoint`` as on claravid-eval/predict, ``--size`` width x height as on every
    command."""
    ckpt = save_checkpoint(_model("dinov2_vits14"), tmp_path / "m.pt")
    out = tmp_path / "m.onnx"
    assert main(["--checkpoint", str(ckpt), "-o", str(out), "--size", "42x28", "--no-check"]) == 0
    assert OnnxSegmenter(out).input_size == (28, 42)  # (height, width), as the tensors
    x = str(tmp_path / "x.onnx")
    for argv, match in [
        (["--checkpoint", str(ckpt), "-o", x, "--size", "28x20"],
         "input size 28x20 (WxH) is not a multiple of the model's patch size 14: use --size 28x14 "
         "or --size 28x28"),
    ]:  # fmt: skip
        assert main(argv) == 2
        _one_error_line(capsys, match)
    assert not (tmp_path / "x.onnx").exists()


def test_python_api_rejects_nonsense_numbers(tmp_path):
    model = _model("dinov2_vits14")
    for kwargs, match in [
        ({"tolerance": -1.0}, "tolerance must be a finite number > 0"),
        ({"tolerance": float("inf")}, "tolerance must be a finite number > 0"),
        ({"height": 0}, "height must be a positive multiple of the patch size 14, got 0"),
        ({"width": 14.0}, "width must be a positive multiple"),
        ({"height": 20}, "pad or resize it to 28x630"),
    ]:
        with pytest.raises(ValueError, match=match):
            export_onnx(model, tmp_path / "x.onnx", ExportSettings(**kwargs))
    assert not any(tmp_path.iterdir())  # rejected before anything is written


def test_cli_checks_paths_before_loading(tmp_path, capsys):
    ckpt = save_checkpoint(_model("dinov2_vits14"), tmp_path / "m.pt")
    (tmp_path / "afile").write_text("x")
    cases = [
        ([str(ckpt), "-o", str(tmp_path)], "is a folder"),
        ([str(ckpt), "-o", str(tmp_path / "afile" / "m.onnx")], "afile is a file, not a folder"),
        ([str(ckpt), "-o", str(tmp_path / "m.pt")], "must end in .onnx"),
        ([str(tmp_path), "-o", str(tmp_path / "x.onnx")], "is a folder; give the file itself"),
        ([str(tmp_path / "afile"), "-o", str(tmp_path / "x.onnx")], "not a PyTorch tensor file"),
    ]
    for argv, match in cases:
        assert main(["--checkpoint", *argv]) == 2
        _one_error_line(capsys, match)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "m.pt"]


def test_failed_check_writes_nothing_and_keeps_the_old_file(tmp_path, capsys, monkeypatch):
    import claravid.models.export.onnx as export

    def fake_export(model, path, height, width, dynamic):
        path.write_bytes(b"new onnx")

    def failing_check(model, path, *args):
        raise ExportCheckError(f"exported model {path} differs from PyTorch by 1")

    monkeypatch.setattr(export, "_export", fake_export)
    monkeypatch.setattr(export, "_write_metadata", lambda path, document: None)
    monkeypatch.setattr(export, "check_export", failing_check)
    ckpt = save_checkpoint(_model("dinov2_vits14"), tmp_path / "m.pt")
    out = tmp_path / "x.onnx"
    out.write_bytes(b"old onnx")
    args = ["--checkpoint", str(ckpt), "-o", str(out), "--size", "28", "--overwrite"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert f"exported model {out} differs" in err and "nothing was written" in err
    assert out.read_bytes() == b"old onnx"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.pt", "x.onnx"]  # no temp left
    assert main([*args, "--no-check"]) == 0
    assert out.read_bytes() == b"new onnx"


def test_an_output_it_did_not_write_needs_overwrite(tmp_path, capsys):
    ckpt = save_checkpoint(_model("dinov2_vits14"), tmp_path / "m.pt")
    out = tmp_path / "existing.txt.onnx"
    out.write_text("someone's notes")
    args = ["--checkpoint", str(ckpt), "-o", str(out), "--size", "28", "--no-check"]
    assert main(args) == 2
    _one_error_line(capsys, "exists; pass --overwrite")
    assert out.read_text() == "someone's notes"
    assert main([*args, "--overwrite"]) == 0
    assert OnnxSegmenter(out).num_classes == 3
    assert main(args) == 0  # its own export: replaced without --overwrite


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (b"", "is empty"),
        (b"just some text\n", "is a text file"),
        (b"PK\x03\x04" + bytes(60), "is a PyTorch file, not ONNX"),
        (b"\x08\x07" + bytes(10), "cannot be loaded as an ONNX model"),  # truncated protobuf
    ],
)
def test_a_file_that_is_not_onnx_is_named(content, match, tmp_path):
    path = tmp_path / "model.onnx"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=match) as info:
        OnnxSegmenter(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
