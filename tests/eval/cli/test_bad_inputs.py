"""Bad inputs a hostile new user found (issue 12 §6): one line each, and no lost or false work."""

import json
import threading

import cv2
import numpy as np
import pytest
import torch
from PIL import Image

import claravid.eval.inference.collect as collect_module
from claravid.data.palettes import load_palette
from claravid.eval.cli.evaluate import main
from claravid.eval.cli.predict import main as predict_main
from claravid.eval.report.build import build_report
from claravid.eval.report.files import load_result
from tests.tiny import WINDOW

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
    real = collect_module.save_label_map

    def ctrl_c(*args, **kwargs):  # injected: the user presses Ctrl-C after the first map
        real(*args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(collect_module, "save_label_map", ctrl_c)
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


def test_predict_finds_webp_in_a_folder(claravid_root, tmp_path, capsys):
    """The WebP is found, decoded and predicted: its label map is the model's argmax on the
    pixels normalised by hand (one 28-px window is the whole image), its overlay the image and
    the uavid colours half and half."""
    from claravid import models
    from claravid.data.transforms import IMAGENET_MEAN, IMAGENET_STD
    from tests.tiny import tiny_model

    # Seed 1: a model whose labels follow the pixels (seed 0's are one class everywhere).
    checkpoint = models.save_checkpoint(tiny_model(seed=1), tmp_path / "m.pt",
                                        config={"data": {"palette": "uavid"}})  # fmt: skip
    flight = tmp_path / "flight"
    flight.mkdir()
    frame = claravid_root / "001_rural_1" / "left_rgb" / "45deg_low_h" / "000000.jpg"
    pixels = np.ascontiguousarray(cv2.imread(str(frame))[10:38, 20:48])  # a 28-px crop, BGR
    cv2.imwrite(str(flight / "a.webp"), pixels, [cv2.IMWRITE_WEBP_QUALITY, 101])  # lossless
    out = tmp_path / "pred"
    argv = ["--checkpoint", str(checkpoint), str(flight), "-o", str(out), "--window", "28",
            "--no-progress"]  # fmt: skip
    assert predict_main(argv) == 0
    rgb = pixels[..., ::-1].astype(np.float64)  # written as BGR
    x = (rgb / 255 - np.array(IMAGENET_MEAN)) / np.array(IMAGENET_STD)
    model = models.load_checkpoint(checkpoint).eval()
    with torch.no_grad():
        logits = model(torch.from_numpy(x.transpose(2, 0, 1)[None]).float())[0].numpy()
    expected = logits.argmax(0)
    assert len(np.unique(expected)) > 1  # a flat map would pass with any image
    label_map = cv2.imread(str(out / "a.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(label_map, expected)
    blend = 0.5 * rgb + 0.5 * COLORS[expected]
    overlay = cv2.cvtColor(cv2.imread(str(out / "overlays" / "a.jpg")), cv2.COLOR_BGR2RGB)
    # JPEG (chroma halved): a few levels off on average; the image's channels swapped (BGR
    # blended as RGB) would be far more.
    off = np.abs(overlay - blend).mean()
    swapped = np.abs(overlay - (0.5 * rgb[..., ::-1] + 0.5 * COLORS[expected])).mean()
    assert off < 5 and swapped > 3 * off


COLORS = load_palette("uavid").colors


def _uavid(root, ids):
    """uavid_val/seq1 with one 32×24 frame labelled ``ids`` (colour labels), random pixels."""
    base = root / "uavid_val" / "seq1"
    (base / "Images").mkdir(parents=True)
    (base / "Labels").mkdir(parents=True)
    image = np.random.default_rng(0).integers(0, 256, (24, 32, 3), dtype=np.uint8)
    cv2.imwrite(str(base / "Images" / "000000.png"), image)
    cv2.imwrite(str(base / "Labels" / "000000.png"), COLORS[ids][..., ::-1])
    return root


@pytest.fixture
def uavid_case(tmp_path):
    ids = np.zeros((24, 32), np.uint8)
    ids[:, :16], ids[:, 16:] = 1, 4  # half Building, half Tree
    root = _uavid(tmp_path / "uavid", ids)
    preds = tmp_path / "preds" / "uavid_val" / "seq1" / "Images"
    preds.mkdir(parents=True)
    return root, ids, preds / "000000.png"


def _uavid_args(root, preds, out, *extra):
    return ["--predictions", str(preds), "--dataset", "uavid", "--data", str(root), "--split",
            "val", "--bins", "1", "--output", str(out), "--no-progress", "--palette", "uavid",
            *extra]  # fmt: skip


def test_a_palette_mode_png_prediction_is_read_by_its_indices(uavid_case, tmp_path):
    root, ids, target = uavid_case
    image = Image.fromarray(ids, mode="P")
    image.putpalette([v for i in range(256) for v in (i, 255 - i, (7 * i) % 256)])
    image.save(target)
    out = tmp_path / "rep"
    assert main(_uavid_args(root, tmp_path / "preds", out)) == 0
    assert json.loads((out / "report.json").read_text())["overall"]["miou"] == 1.0


def test_edges_that_leave_images_outside_are_reported(uavid_case, tmp_path, capsys):
    root, ids, target = uavid_case
    cv2.imwrite(str(target), ids)
    argv = _uavid_args(root, tmp_path / "preds", tmp_path / "rep")
    argv.remove("--bins"), argv.remove("1")
    assert main([*argv, "--edges", "1,2"]) == 0  # random pixels: delentropy far above 2
    err = capsys.readouterr().err
    assert "1 of 1 image(s) fall outside --edges" in err


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["compare", "a", "b", "--bins", "3"], "unrecognized arguments: --bins 3"),
        (["compare", "a", "--window", "28"], "unrecognized arguments: --window 28"),
        (["merge", "a", "--measures", "pixent", "-o", "x"], "unrecognized arguments: --measures"),
    ],
)
def test_options_that_do_nothing_in_a_mode_are_refused(argv, flag, capsys):
    assert main(argv) == 2
    _one_line(capsys, flag, prog=f"claravid-eval {argv[0]}")


def test_masks_with_a_dataset_that_has_its_own_labels_is_refused(uavid_case, tmp_path, capsys):
    root, ids, target = uavid_case
    cv2.imwrite(str(target), ids)
    argv = _uavid_args(root, tmp_path / "preds", tmp_path / "rep", "--masks", str(tmp_path))
    assert main(argv) == 2
    _one_line(capsys, "--masks does nothing with --dataset uavid")


def test_merging_reports_of_different_data_warns_and_group_by_is_checked(
    uavid_case, tmp_path, capsys
):
    root, ids, target = uavid_case
    cv2.imwrite(str(target), ids)
    other = _uavid(tmp_path / "other", ids)
    assert main(_uavid_args(root, tmp_path / "preds", tmp_path / "a")) == 0
    assert main(_uavid_args(other, tmp_path / "preds", tmp_path / "b")) == 0
    capsys.readouterr()
    merged = ["merge", str(tmp_path / "a"), str(tmp_path / "b"), "--bins", "1"]
    assert main([*merged, "--output", str(tmp_path / "m")]) == 0
    assert "merging reports of different data roots" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown --group-by 'color'"):
        build_report(load_result(tmp_path / "a"), bins=1, group_by="color")
    # A saved report regroups by any stored unit: UAVid sequence and folder too.
    saved = load_result(tmp_path / "a")
    for unit in ("sequence", "folder"):
        rows = build_report(saved, bins=1, group_by=unit)["groups"]
        assert [r["name"] for r in rows] == sorted(set(saved.attributes[unit]))
        assert sum(r["num_images"] for r in rows) == len(saved.paths)
    with pytest.raises(ValueError, match="--group-by mission is not available"):
        build_report(saved, bins=1, group_by="mission")


def test_labels_read_with_the_wrong_palette_stop_naming_the_right_one(uavid_case, tmp_path, capsys):
    root, ids, target = uavid_case
    cv2.imwrite(str(target), ids)
    argv = _uavid_args(root, tmp_path / "preds", tmp_path / "rep", "--palette", "claravid")
    assert main(argv) == 2
    _one_line(capsys, "outside palette claravid", "--palette uavid")


def test_a_moved_data_root_says_the_path_came_from_the_checkpoint(tmp_path, capsys):
    from claravid import models
    from tests.tiny import tiny_model

    moved = tmp_path / "moved"
    ckpt = models.save_checkpoint(
        tiny_model(), tmp_path / "m.pt", config={"data": {"root": str(moved)}}
    )
    assert _eval(tmp_path / "r", "--checkpoint", str(ckpt)) == 2
    _one_line(capsys, str(moved), "comes from the checkpoint", "pass --data")


def test_an_exif_rotated_photo_is_explained(tmp_path):
    from claravid.data.targets import FolderSegmentation

    images, masks = tmp_path / "images", tmp_path / "masks"
    images.mkdir(), masks.mkdir()
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90° clockwise to display": stored 30×20, shown 20×30
    Image.new("RGB", (30, 20), (90, 120, 30)).save(images / "a.jpg", exif=exif)
    cv2.imwrite(str(masks / "a.png"), np.zeros((30, 20), np.uint8))  # drawn on the shown one
    data = FolderSegmentation(images, masks, palette="udd6")
    with pytest.raises(ValueError, match="EXIF orientation tag rotates it") as info:
        data[0]
    assert "a.jpg is 30×20 but its mask" in str(info.value)
    cv2.imwrite(str(masks / "a.png"), np.zeros((7, 9), np.uint8))  # simply another image's
    with pytest.raises(ValueError, match="does not belong to this image"):
        data[0]


def test_hardest_images_have_a_legend_of_the_class_colours(tmp_path):
    from claravid.eval.report.plots import hardest_figure, plot_hardest

    palette = load_palette("uavid")
    mask = np.array([[0, 1], [255, 1]], np.uint8)
    item = {"image": np.zeros((2, 2, 3), np.uint8), "mask": mask,
            "prediction": np.array([[4, 1], [1, 1]], np.uint8), "title": "a"}  # fmt: skip
    fig = hardest_figure([item], palette.colors, palette.names)
    (legend,) = fig.legends
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels == [palette.names[0], palette.names[1], palette.names[4], "ignored"]
    colours = [
        tuple(np.round(np.asarray(h.get_facecolor()[:3]) * 255)) for h in legend.legend_handles
    ]
    assert colours[:3] == [tuple(palette.colors[k].astype(float)) for k in (0, 1, 4)]
    assert plot_hardest([item], palette.colors, tmp_path / "h.png", palette.names).is_file()


def test_merging_a_val_and_a_test_report_warns(model_files, two_frames, tmp_path, capsys):
    ckpt = ["--checkpoint", str(model_files["checkpoint"])]
    split = two_frames.parent / "one.txt"
    split.write_text(FRAMES[0] + "\n")
    assert _eval(tmp_path / "a", *ckpt, "--split", str(split)) == 0
    rest = two_frames.parent / "rest.txt"
    rest.write_text(FRAMES[1] + "\n")
    assert _eval(tmp_path / "b", *ckpt, "--split", str(rest)) == 0
    capsys.readouterr()
    merge = ["merge", str(tmp_path / "a"), str(tmp_path / "b"), "--bins", "1", "--output"]
    assert main([*merge, str(tmp_path / "m")]) == 0  # two shards of one split: no warning
    assert "warning" not in capsys.readouterr().err
    for part, split in (("a", "val"), ("b", "test")):  # as if run with --split val / test
        file = tmp_path / part / "report.json"
        report = json.loads(file.read_text())
        report["source"]["split"] = split
        file.write_text(json.dumps(report))
    assert main([*merge, str(tmp_path / "m2")]) == 0
    assert "merging reports of different splits" in capsys.readouterr().err


def test_a_label_png_claiming_more_than_2_30_pixels_is_one_line(
    model_files, writable_root, two_frames, tmp_path, capsys
):
    # OpenCV's cv2.error, which nothing mapped, ended the evaluation in a traceback.
    from tests.helpers.files import png_claiming

    pan = writable_root / "003_urban_1" / "panoptic_seg" / "55deg_mid_v" / "000001.png"
    pan.write_bytes(png_claiming(40000, 30000))
    argv = ["--checkpoint", str(model_files["checkpoint"]), "--data", str(writable_root)]
    assert _eval(tmp_path / "r", *argv, "--split", str(two_frames)) == 2
    line = _one_line(capsys, str(pan), "40000×30000", "more than the 1,073,741,824 (2^30)")
    assert "cv2.error" not in line
