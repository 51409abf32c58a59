"""claravid-predict --raster: COG class maps on the input's grid, GSD matching, bad rasters."""

import sys

import numpy as np
import pytest
import torch

from claravid import models
from claravid.data.palettes import load_palette
from claravid.eval.cli.predict import main
from claravid.eval.inference.windows import WindowConfig, sliding_window_logits
from tests.helpers.rasters import noise, write_raster

rasterio = pytest.importorskip("rasterio")


@pytest.fixture(scope="module")
def with_gsd(model_files, tmp_path_factory):
    """`model_files`' model, its training config, and a recorded GSD of 0.1 m/px."""
    import torch as t

    ckpt = t.load(model_files["checkpoint"], weights_only=True)
    path = tmp_path_factory.mktemp("gsd") / "gsd.pt"
    record = {"metres_per_pixel": 0.1, "source": "data.gsd"}
    return models.save_checkpoint(model_files["model"], path, config=ckpt["config"], gsd=record)


def _predict(ckpt, raster, out, *flags):
    return main(["--checkpoint", str(ckpt), str(raster), "--raster", "-o", str(out),
                 "--no-progress", *flags])  # fmt: skip


def _in_memory(model, pixels, scale=1.0):
    config = WindowConfig(size=28, scale=scale, batch_size=8)
    with torch.inference_mode():
        return sliding_window_logits(model, torch.from_numpy(pixels), config).argmax(0).numpy()


def test_a_cog_class_map_on_the_inputs_grid(model_files, tmp_path, capsys):
    pixels = noise(4, 45, 70, seed=5)
    pixels[3] = 255
    pixels[3, 10:20, 30:50] = 0  # transparent
    raster = write_raster(tmp_path / "ortho.tif", pixels, alpha=True)
    out = tmp_path / "pred"
    assert _predict(model_files["checkpoint"], raster, out, "--confidence") == 0
    assert sorted(p.name for p in out.iterdir()) == ["ortho.tif", "predictions.json"]
    expected = _in_memory(model_files["model"], pixels[:3]).astype(np.uint8)
    expected[10:20, 30:50] = 255
    with rasterio.open(out / "ortho.tif") as src, rasterio.open(raster) as inp:
        assert (src.crs, src.transform, src.shape) == (inp.crs, inp.transform, inp.shape)
        assert src.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG"
        np.testing.assert_array_equal(src.read(1), expected)
        conf = src.read(2)
        colors = load_palette("uavid").colors
        assert src.colormap(1)[3] == (*map(int, colors[3]), 255)
    assert (conf[10:20, 30:50] == 255).all()
    valid = np.ones(conf.shape, bool)
    valid[10:20, 30:50] = False
    assert conf[valid].min() >= 254 // 8 and conf[valid].max() <= 254  # p >= 1/K
    assert "1 class map" in capsys.readouterr().out


def test_gsd_auto_resamples_to_the_models_scale(with_gsd, model_files, tmp_path, capsys):
    pixels = noise(3, 56, 84, seed=6)
    raster = write_raster(tmp_path / "fine.tif", pixels, gsd=0.05)  # twice the model's detail
    assert _predict(with_gsd, raster, tmp_path / "out", "--gsd", "auto") == 0
    with rasterio.open(tmp_path / "out" / "fine.tif") as src:
        assert src.shape == (56, 84)
        labels = src.read(1)
    # 0.05 m/px for a model of 0.1: read at 42x28, one row of two 28² windows (84x56: six).
    assert "84x56, GSD 0.05 m/px, 2 windows" in capsys.readouterr().out
    halved = _in_memory(model_files["model"], pixels, scale=0.5)
    assert (labels == halved).mean() >= 0.9


def _fails(capsys, code, pattern):
    assert code == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error:" in line]
    assert len(errors) == 1 and "Traceback" not in err, err
    assert pattern in errors[0], errors[0]


def test_bad_rasters_are_one_line_and_leave_nothing(model_files, with_gsd, tmp_path, capsys):
    ckpt = model_files["checkpoint"]
    u16 = write_raster(tmp_path / "u16.tif", noise(3, 30, 30, dtype=np.uint16))
    _fails(capsys, _predict(ckpt, u16, tmp_path / "a"), "--value-range LOW,HIGH")
    grey = write_raster(tmp_path / "grey.tif", noise(1, 30, 30))
    _fails(capsys, _predict(ckpt, grey, tmp_path / "b"), "pass --bands R,G,B")
    plain = write_raster(tmp_path / "plain.tif", noise(3, 30, 30), crs=None)
    _fails(capsys, _predict(with_gsd, plain, tmp_path / "c", "--gsd", "auto"), "--gsd METRES")
    rgb = write_raster(tmp_path / "rgb.tif", noise(3, 30, 30))
    _fails(capsys, _predict(ckpt, rgb, tmp_path / "d", "--gsd", "auto"), "records no ground")
    _fails(capsys, main(["--checkpoint", str(ckpt), str(rgb), "-o", str(tmp_path / "e"),
                         "--bands", "1,2,3"]), "apply to rasters: add --raster")  # fmt: skip
    # A raster is streamed in one copy: test-time augmentation is refused, not ignored.
    _fails(capsys, _predict(ckpt, rgb, tmp_path / "g", "--tta", "dinov3"),
           "--tta do not apply to --raster")  # fmt: skip
    _fails(capsys, _predict(ckpt, rgb, tmp_path / "g", "--flip", "--tta-size", "512"),
           "--flip, --tta-size do not apply to --raster")  # fmt: skip
    with pytest.raises(SystemExit) as exit_:  # argparse's own: exit 2, one line
        _predict(ckpt, rgb, tmp_path / "f", "--gsd", "-1")
    _fails(capsys, exit_.value.code, "--gsd takes 'auto'")
    for folder in "abcdefg":
        assert not list((tmp_path / folder).glob("*.tif")) if (tmp_path / folder).exists() else 1


def test_a_block_that_fails_mid_way_leaves_no_class_map(model_files, tmp_path, capsys):
    raster = write_raster(tmp_path / "bad.tif", noise(3, 64, 48), block=16)
    with rasterio.open(raster) as src:
        offset = int(src.get_tag_item("BLOCK_OFFSET_1_3", "TIFF", bidx=1))  # rows 48..63
    with open(raster, "r+b") as f:
        f.seek(offset)
        f.write(b"\xff" * 64)
    out = tmp_path / "out"
    _fails(capsys, _predict(model_files["checkpoint"], raster, out), "cannot read rows")
    assert not [p for p in out.rglob("*") if p.suffix == ".tif"]


def test_no_crs_is_a_warning_and_none_out(model_files, tmp_path, capsys):
    raster = write_raster(tmp_path / "plain.tif", noise(3, 20, 33), crs=None)  # under a window
    assert _predict(model_files["checkpoint"], raster, tmp_path / "out") == 0
    assert capsys.readouterr().err.count("has no CRS") == 1
    with rasterio.open(tmp_path / "out" / "plain.tif") as src:
        assert src.crs is None and src.shape == (20, 33)


def test_without_rasterio_one_line_names_the_extra(model_files, tmp_path, capsys, monkeypatch):
    raster = write_raster(tmp_path / "r.tif", noise(3, 20, 20))
    monkeypatch.setitem(sys.modules, "rasterio", None)
    _fails(capsys, _predict(model_files["checkpoint"], raster, tmp_path / "out"),
           "pip install 'claravid-toolkit[geo]'")  # fmt: skip
