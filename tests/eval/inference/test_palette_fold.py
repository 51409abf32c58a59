"""A model of ClaraVid's 19 classes scored through another palette: the fine softmax
probabilities summed per palette class, argmax; calibration from the summed probabilities;
the model's label maps mapped by the same table. Expected values restated here from the rule,
with the table written out by class name (not read from the code under test)."""

import json

import numpy as np
import pytest
import torch

from claravid.eval import DataChoice, InferenceSettings, ReportSettings
from claravid.eval.analysis.bootstrap import Bootstrap
from claravid.eval.run import evaluate
from claravid.infra.cli import UsageError
from tests.tiny import HEAD, VIT_56

#: ClaraVid's 19 classes in the fine palette's train-id order.
# fmt: off
FINE = ["Building", "Fence", "Wire", "Pedestrian", "Pole", "RoadLine", "Road", "SideWalk",
        "Vegetation", "Vehicles", "TrafficSign", "GreenEnergy", "GuardRail", "Urban props",
        "Water", "Terrain", "Tent", "Constr props", "Bridge"]
#: The test's coarse palette: Car has no static source (only the dynamic override, which a
#: model does not see), four fine classes are ignored.
COARSE = {
    "Ground": ["Road", "RoadLine", "SideWalk", "Terrain"],
    "Built": ["Building", "Fence", "Bridge", "Wire", "Pole", "TrafficSign", "GuardRail",
              "Urban props", "Constr props", "Tent"],
    "Green": ["Vegetation"],
    "Car": [],
}
# fmt: on
IGNORED = ["Vehicles", "Pedestrian", "Water", "GreenEnergy"]
BINS = 15
# Width x height (56x42): the WINDOW of tests.tiny as the (height, width) pair.
WINDOW_HW = (42, 56)


def _palette_yaml(path):
    lines = ["name: coarse4", "classes:"]
    for i, name in enumerate(COARSE):
        lines.append(f"  - {{id: {i}, name: {name}, color: [{i * 40}, {i * 30}, {i * 20}]}}")
    lines.append("mapping:")
    lines += [f"  {fine}: {coarse}" for coarse, fines in COARSE.items() for fine in fines]
    lines += [f"  {fine}: ignore" for fine in IGNORED]
    lines += ["dynamic:", "  Vehicles: Car"]
    path.write_text("\n".join(lines) + "\n")
    return path


#: Six frames of the tiny tree, two per mission and altitude (fast, and both missions).
FRAMES = [
    "001_rural_1/45deg_low_h/000000",
    "001_rural_1/55deg_mid_h/000001",
    "001_rural_1/90deg_high_v/000002",
    "003_urban_1/45deg_low_h/000001",
    "003_urban_1/55deg_mid_h/000000",
    "003_urban_1/90deg_high_v/000002",
]


@pytest.fixture(scope="module")
def fine_model(claravid_root, tmp_path_factory):
    from claravid import models

    folder = tmp_path_factory.mktemp("fine")
    (folder / "six.txt").write_text("\n".join(FRAMES) + "\n")
    torch.manual_seed(3)
    model = models.build_model("dinov2_vits14", 19, backbone_kwargs=VIT_56, **HEAD).eval()
    with torch.no_grad():  # spread the logits: some pixels peaked, some flat
        model.head.head[-1].weight.mul_(30.0)
    config = {"data": {"root": str(claravid_root), "palette": "claravid"}}
    path = models.save_checkpoint(model, folder / "fine.pt", config=config, epoch=1)
    return {
        "checkpoint": path,
        "model": model,
        "palette": _palette_yaml(folder / "coarse4.yaml"),
        "split": str(folder / "six.txt"),
    }


def _by_hand(model, ds, config=None, naive=None):
    """Per image: the confusion [4,4] and calibration sums [3,15] of the summed-probability
    rule, from the model's fine window logits. ``naive`` (a list) collects, per image, the
    pixels where mapping the fine argmax would give another class."""
    from claravid.eval.inference.windows import WindowConfig, sliding_window_logits

    target = {fine: i for i, (_, fines) in enumerate(COARSE.items()) for fine in fines}
    confusions, calibration = [], []
    for i in range(len(ds)):
        sample = ds[i]
        logits = sliding_window_logits(
            model, sample["image"], config or WindowConfig(size=WINDOW_HW)
        )
        logits = logits.double().numpy()
        p = np.exp(logits - logits.max(0))
        p /= p.sum(0)
        summed = np.zeros((4, *p.shape[1:]))
        for j, name in enumerate(FINE):
            if name in target:  # an ignored fine class adds to no class
                summed[target[name]] += p[j]
        summed[3] = -1.0  # Car: no fine class reaches it, never predicted
        pred, conf = summed.argmax(0), summed.max(0)
        if naive is not None:
            table = np.asarray([target.get(name, -1) for name in FINE])
            naive.append(int((table[logits.argmax(0)] != pred).sum()))
        truth = np.asarray(sample["mask"])
        valid = truth != 255
        c = np.zeros((4, 4), dtype=np.int64)
        np.add.at(c, (truth[valid], pred[valid]), 1)
        confusions.append(c)
        which = np.minimum((conf[valid] * BINS).astype(int), BINS - 1)
        right = (pred[valid] == truth[valid]).astype(float)
        calibration.append(
            np.stack(
                [
                    np.bincount(which, minlength=BINS),
                    np.bincount(which, conf[valid], minlength=BINS),
                    np.bincount(which, right, minlength=BINS),
                ]
            )
        )
    return np.stack(confusions), np.stack(calibration)


class _Colour(torch.nn.Module):
    """Fine logits from each pixel's colour alone (a seeded 1x1 convolution): labels that vary
    from pixel to pixel, unlike an untrained ViT's."""

    def __init__(self):
        super().__init__()
        torch.manual_seed(5)
        self.conv = torch.nn.Conv2d(3, 19, 1)
        with torch.no_grad():
            self.conv.weight.mul_(3.0)
            self.conv.bias[8] += 2.5  # Vegetation, alone in Green against Built's ten classes

    def forward(self, x):
        return self.conv(x)


def test_summed_probabilities_pixel_by_pixel(fine_model, claravid_root):
    """The rule at the level of one image's sums: prediction and calibration of a model whose
    pixels disagree, where the sum rule often differs from mapping the fine argmax."""
    from claravid.data.palette_fold import fine_names, fold_palette
    from claravid.data.palettes import load_palette
    from claravid.data.segmentation import ClaraVidSegmentation
    from claravid.data.transforms import eval_transforms
    from claravid.eval.inference.image_sums import ImageMeasures
    from claravid.eval.inference.run_model import evaluate_model
    from claravid.eval.inference.windows import WindowConfig

    palette = load_palette(fine_model["palette"])
    ds = ClaraVidSegmentation(
        claravid_root, split=fine_model["split"], palette=palette, transforms=eval_transforms()
    )
    model = _Colour().eval()
    config = WindowConfig(size=WINDOW_HW, mean=(0.5, 0.5, 0.5), std=(0.25, 0.25, 0.25))
    scores = evaluate_model(
        model,
        ds,
        4,
        config,
        measures=ImageMeasures(calibration=True),
        fold=fold_palette(fine_names(), palette),
    )
    naive = []
    confusions, calibration = _by_hand(model, ds, config, naive)
    np.testing.assert_array_equal(np.stack([s.confusion for s in scores]), confusions)
    sums = np.stack([s.calibration for s in scores])
    np.testing.assert_array_equal(sums[:, [0, 2]], calibration[:, [0, 2]])
    np.testing.assert_allclose(sums[:, 1], calibration[:, 1], rtol=1e-5)
    assert (confusions.sum((0, 1))[:3] > 0).all()  # Ground, Built and Green predicted
    assert sum(naive) > 0, "the sum rule never differs from the fine argmax: the test is blind"


def test_fine_checkpoint_scored_through_a_palette_sums_probabilities(
    fine_model, claravid_root, tmp_path
):
    from claravid.data.segmentation import ClaraVidSegmentation
    from claravid.data.transforms import eval_transforms

    report = ReportSettings(
        bootstrap=Bootstrap(resamples=0),
        boundary=False,
        consistency=False,
        calibration=True,
        hardest=0,
    )
    done = evaluate(
        tmp_path / "rep",
        checkpoint=fine_model["checkpoint"],
        data=DataChoice(split=fine_model["split"], palette=str(fine_model["palette"])),
        inference=InferenceSettings(window=WINDOW_HW, device="cpu"),
        report=report,
        save_predictions=tmp_path / "maps",
    )
    ds = ClaraVidSegmentation(
        claravid_root,
        split=fine_model["split"],
        palette=str(fine_model["palette"]),
        transforms=eval_transforms(),
    )
    assert done.result.keys == [f.key for f in ds.frames]
    confusions, calibration = _by_hand(fine_model["model"], ds)
    np.testing.assert_array_equal(done.result.confusions, confusions)
    assert confusions[:, :, 3].sum() == 0 and confusions[:, 3].sum() > 0  # Car: a structural 0
    assert (confusions.sum((0, 1))[:2] > 0).all()  # Ground and Built both predicted
    sums = done.result.quality.calibration
    np.testing.assert_array_equal(sums[:, 0], calibration[:, 0])  # pixels per bin
    np.testing.assert_array_equal(sums[:, 2], calibration[:, 2])  # correct per bin
    np.testing.assert_allclose(sums[:, 1], calibration[:, 1], rtol=1e-5)  # summed confidence
    # The report says how the model was scored, and what it cannot predict.
    saved = json.loads((tmp_path / "rep" / "report.json").read_text())
    fold = saved["source"]["fold"]
    assert fold["model_palette"] == "claravid" and fold["palette"] == "coarse4"
    assert fold["table"]["Vehicles"] == "ignore" and fold["table"]["Terrain"] == "Ground"
    assert fold["unreachable"] == ["Car"]
    assert saved["source"]["predictable"] == ["Ground", "Built", "Green"]
    assert saved["overall"]["unpredictable_present"] == ["Car"]
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "scored through palette coarse4" in md and "Classes a ClaraVid model cannot" in md
    # Its saved label maps hold the folded ids and name the palette scored on.
    marker = json.loads((tmp_path / "maps" / "predictions.json").read_text())
    assert marker["palette"] == "coarse4"


def test_fine_label_maps_map_by_the_same_table(fine_model, claravid_root, tmp_path):
    """Label maps of the fine palette (random ids, written here), scored through coarse4: each
    fine id becomes its coarse class; an ignored fine id has no vote, so the argmax falls to
    the lowest predictable class (Ground, 0)."""
    import cv2

    from claravid.data.segmentation import ClaraVidSegmentation

    ds = ClaraVidSegmentation(
        claravid_root, split=fine_model["split"], palette=str(fine_model["palette"])
    )
    rng = np.random.default_rng(0)
    maps = tmp_path / "fine_maps"
    fine_ids = []
    for n, frame in enumerate(ds.frames):
        ids = rng.integers(0, 19, size=ds.read_mask(n).shape, dtype=np.uint8)
        (maps / frame.key).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(maps / f"{frame.key}.png"), ids)
        fine_ids.append(ids)
    (maps / "predictions.json").write_text(
        json.dumps(
            {"format": "claravid-predictions", "palette": "claravid", "classes": FINE, "source": {}}
        )
    )
    quiet = ReportSettings(
        bootstrap=Bootstrap(resamples=0),
        boundary=False,
        consistency=False,
        calibration=False,
        hardest=0,
    )
    done = evaluate(
        tmp_path / "rep",
        predictions=maps,
        data=DataChoice(
            root=claravid_root, split=fine_model["split"], palette=str(fine_model["palette"])
        ),
        report=quiet,
    )
    lut = np.zeros(19, dtype=np.int64)  # ignored -> Ground (0)
    for i, (_, fines) in enumerate(COARSE.items()):
        for fine in fines:
            lut[FINE.index(fine)] = i
    for n, ids in enumerate(fine_ids):
        truth = ds.read_mask(n)
        valid = truth != 255
        expected = np.zeros((4, 4), dtype=np.int64)
        np.add.at(expected, (truth[valid], lut[ids[valid]]), 1)
        np.testing.assert_array_equal(done.result.confusions[n], expected)
    assert done.result.source["fold"]["palette"] == "coarse4"
    # A subset naming a class the palette lacks is refused before anything is read.
    with pytest.raises(UsageError, match="Nope not in the palette's classes"):
        evaluate(tmp_path / "rep3", predictions=maps, data=DataChoice(root=claravid_root,
                 split=fine_model["split"], palette=str(fine_model["palette"])),
                 report=ReportSettings(classes="Ground,Nope"))  # fmt: skip
    assert not (tmp_path / "rep3" / "report.json").exists()
    # Label maps of another palette than the fine one are still refused against --palette.
    (maps / "predictions.json").write_text(
        json.dumps(
            {"format": "claravid-predictions", "palette": "uavid", "classes": list(range(8))}
        )
    )
    with pytest.raises(UsageError, match="contradicts"):
        evaluate(
            tmp_path / "rep2",
            predictions=maps,
            data=DataChoice(
                root=claravid_root, split=fine_model["split"], palette=str(fine_model["palette"])
            ),
            report=quiet,
        )


def test_a_model_of_other_classes_is_refused_in_one_line(model_files, tmp_path):
    """An 8-class (uavid) model scored on udd6: no fold, one line naming the trained palette."""
    with pytest.raises(UsageError) as err:
        evaluate(
            tmp_path / "o",
            checkpoint=model_files["checkpoint"],
            data=DataChoice(split="all", palette="udd6"),
        )
    message = str(err.value)
    assert "predicts 8 classes but palette udd6 has 6" in message
    assert "--palette uavid" in message and "\n" not in message
    assert not (tmp_path / "o" / "report.json").exists()


def test_an_onnx_file_naming_the_19_classes_is_folded():
    """An ONNX file's metadata names its classes (the export's palette record): the 19 fine
    ones fold into udd6 as its YAML maps them (Building -> Roof; Facade reached by none); an
    8-class file is refused in one line. The inference itself is the checkpoint's path."""
    from claravid.data.palettes import load_palette
    from claravid.eval.inference.sources import onnx_defaults
    from claravid.eval.run import model_classes, scoring_fold

    udd6 = load_palette("udd6")
    meta = {"palette": {"name": "claravid", "names": FINE, "colors": [[0, 0, 0]] * 19}}
    defaults = onnx_defaults(meta)
    fold = scoring_fold(model_classes(defaults), 19, udd6, defaults.get("palette"))
    table = fold.describe()["table"]
    assert (table["Building"], table["Terrain"], table["Pedestrian"]) == (
        "Roof",
        "Vegetation",
        "Other",
    )
    assert fold.describe()["unreachable"] == ["Facade"]
    names = ["Clutter", "Building", "Road", "Static car", "Tree", "Low vegetation", "Human", "M"]
    defaults = onnx_defaults(
        {"palette": {"name": "uavid", "names": names, "colors": [[0] * 3] * 8}}
    )
    with pytest.raises(UsageError, match="predicts 8 classes but palette udd6 has 6") as err:
        scoring_fold(model_classes(defaults), 8, udd6, defaults.get("palette"))
    assert "--palette uavid" in str(err.value) and "\n" not in str(err.value)
