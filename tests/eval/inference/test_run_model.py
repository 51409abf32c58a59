"""The evaluation loop over a real (generated) ClaraVid split."""

import numpy as np
import torch

from claravid.data.segmentation import ClaraVidSegmentation
from claravid.data.transforms import eval_transforms
from claravid.eval.inference.run_model import evaluate_model
from claravid.eval.inference.windows import WindowConfig


def test_per_image_confusions_match_a_direct_count(claravid_root):
    # normalize=True: float frames, for a model of one's own that does not normalise itself.
    dataset = ClaraVidSegmentation(
        claravid_root, split="all", palette="uavid", transforms=eval_transforms(normalize=True)
    )
    weight = torch.randn(8, 3, generator=torch.Generator().manual_seed(0))

    def model(x):  # pointwise: windows cannot change its answer
        return torch.einsum("kc,bchw->bkhw", weight, x)

    saved = {}
    scores = evaluate_model(
        model, dataset, 8, WindowConfig(size=(28, 28)), indices=[0, 5],
        on_score=lambda s, p, _: saved.setdefault(s["key"], p.numpy()),
    )  # fmt: skip
    assert [s.path for s in scores] == [str(dataset.frames[i].paths["rgb"]) for i in (0, 5)]
    assert len(saved) == 2
    for index, score in zip((0, 5), scores, strict=True):
        sample = dataset[index]
        pred = model(sample["image"][None])[0].argmax(0).numpy()
        mask = sample["mask"].numpy()
        valid = mask != 255
        expected = np.zeros((8, 8), dtype=np.int64)
        np.add.at(expected, (mask[valid], pred[valid]), 1)
        np.testing.assert_array_equal(score.confusion, expected)
        np.testing.assert_array_equal(saved[score.key], pred)
        assert score.key == sample["key"]


def test_evaluation_samples_travel_as_uint8(claravid_root):
    # The frame and its labels stay uint8 until the model's device (an int64 12-Mpixel mask
    # is 96 MB); the values are the training dataset's int64 ones.
    from claravid.eval import open_data

    data = open_data(claravid_root, split="all", palette="uavid")
    sample = data.dataset[3]
    assert sample["image"].dtype == torch.uint8 and sample["mask"].dtype == torch.uint8
    reference = ClaraVidSegmentation(claravid_root, split="all", palette="uavid")[3]
    assert reference["mask"].dtype == torch.int64
    assert torch.equal(sample["mask"].long(), reference["mask"])
    assert torch.equal(sample["image"], reference["image"])
