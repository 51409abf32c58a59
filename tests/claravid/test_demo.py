"""The demo end to end at a tiny size: generation, summary, sample sheet, reuse."""

import json

from PIL import Image

from claravid.demo import main


def test_demo_end_to_end(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main([str(out), "--size", "64x48", "--frames-per-viewpoint", "1"]) == 0
    text = capsys.readouterr().out
    assert "48 frames" in text  # 8 missions × 6 viewpoints × 1 frame
    assert "urban_high_1" in text and "pixel share per class" in text
    sheet = Image.open(out / "samples.png")
    assert sheet.size[0] > 300 and sheet.size[1] > 8 * 100  # one row per mission
    assert "Delentropic Scene Profile per mission" in text
    profile = json.loads((out / "dsp_urban_1.json").read_text())
    assert profile["num_images"] == 6 and profile["metric"] == "delent"
    assert 0 < profile["profile"]["mu"] < 8
    assert Image.open(out / "dsp_profiles.png").size[0] > 600
    assert main([str(out), "--size", "64x48", "--frames-per-viewpoint", "1"]) == 0
    assert "reusing" in capsys.readouterr().out
