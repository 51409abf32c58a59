"""claravid-eval and claravid-predict with test-time augmentation: the flags reach the
probabilities, the report records the protocol, a comparison names a mismatch."""

import json

import cv2
import numpy as np
import torch

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.transforms import eval_transforms
from claravid.eval.cli.evaluate import main
from claravid.eval.cli.predict import main as predict_main
from claravid.eval.inference.augment import TTAConfig
from claravid.eval.inference.windows import WindowConfig, predict_labels
from claravid.io import modalities

FRAMES = ["001_rural_1/45deg_low_h/000000", "003_urban_1/45deg_low_h/000001"]
TTA = ["--tta", "mmseg", "--tta-scales", "0.5,1"]  # 0.5: windows shrunk below the patch grid


def test_eval_with_tta_records_it_and_compare_names_the_mismatch(
    model_files, claravid_root, tmp_path, capsys
):
    split = tmp_path / "split.txt"
    split.write_text("\n".join(FRAMES) + "\n")
    common = ["--checkpoint", str(model_files["checkpoint"]), "--split", str(split),
              "--window", "56x42", "--bins", "1", "--bootstrap", "100", "--no-progress",
              "--no-consistency", "--no-boundary"]  # fmt: skip
    assert main([*common, "--output", str(tmp_path / "plain")]) == 0
    assert main([*common, *TTA, "--output", str(tmp_path / "tta")]) == 0
    report = json.loads((tmp_path / "tta" / "report.json").read_text())
    record = {"rule": "mmseg", "scales": [0.5, 1.0], "flip": True, "size": None}
    assert report["source"]["window"]["tta"] == record
    assert report["source"]["settings"]["tta"] == record
    assert report["source"]["settings"]["from"]["tta"] == "flag"
    assert (
        "test-time augmentation (mmseg rule): ratios 0.5, 1 and the mirror"
        in (tmp_path / "tta" / "report.md").read_text()
    )
    plain = json.loads((tmp_path / "plain" / "report.json").read_text())
    assert plain["source"]["window"]["tta"] is None
    # The confusions are those of the augmented prediction, image by image.
    ds = ClaraVidSegmentation(claravid_root, split=split, palette="uavid",
                              transforms=eval_transforms())  # fmt: skip
    config = WindowConfig(size=(42, 56), tta=TTAConfig((0.5, 1.0), True, "mmseg"))
    model = model_files["model"]
    with np.load(tmp_path / "tta" / "confusions.npz") as saved:
        by_path = dict(zip([str(p) for p in saved["paths"]], saved["confusions"], strict=True))
    for i in range(len(ds)):
        sample = ds[i]
        pred = predict_labels(model, sample["image"], config).numpy()
        mask = np.asarray(sample["mask"])
        valid = mask != 255
        expected = np.bincount(mask[valid] * 8 + pred[valid], minlength=64).reshape(8, 8)
        np.testing.assert_array_equal(by_path[str(sample["path"])], expected)
    # A paired comparison of the two runs says the protocols differ.
    capsys.readouterr()
    out = tmp_path / "cmp"
    assert main(["compare", str(tmp_path / "plain"), str(tmp_path / "tta"), "--output",
                 str(out)]) == 0  # fmt: skip
    text = (out / "compare.md").read_text()
    assert "evaluation protocols differ: plain windows 56x42" in text
    assert "one copy (no test-time augmentation); tta windows" in text


def test_tta_flags_that_mean_nothing_are_one_line(tmp_path, capsys):
    assert main(["--predictions", "P", "--tta", "dinov3", "-o", str(tmp_path / "x")]) == 2
    assert (
        capsys.readouterr().err.strip().endswith("--tta does nothing with --predictions; drop it")
    )
    assert main(["--predictions", "P", "--flip", "-o", str(tmp_path / "x")]) == 2
    assert "--flip does nothing with --predictions" in capsys.readouterr().err
    argv = ["--checkpoint", "m.pt", "--tta", "none", "--flip", "-o", str(tmp_path / "y")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--tta none turns test-time augmentation off" in err[0]
    assert not (tmp_path / "y").exists()


def test_predict_with_tta_writes_the_averaged_argmax(model_files, claravid_root, tmp_path):
    frame = sorted((claravid_root / "003_urban_1" / "left_rgb" / "45deg_low_h").glob("*.jpg"))[0]
    out = tmp_path / "pred"
    argv = ["--checkpoint", str(model_files["checkpoint"]), str(frame), "--output", str(out),
            "--window", "56x42", "--tta-scales", "0.75,1.25", "--flip",
            "--no-overlays"]  # fmt: skip
    assert predict_main(argv) == 0
    ids = cv2.imread(str(out / f"{frame.stem}.png"), cv2.IMREAD_UNCHANGED)
    image = eval_transforms()({"image": modalities.read_rgb(frame).transpose(2, 0, 1)})["image"]
    config = WindowConfig(size=(42, 56), tta=TTAConfig((0.75, 1.25), True))
    expected = predict_labels(model_files["model"], torch.as_tensor(image), config).numpy()
    np.testing.assert_array_equal(ids, expected)
