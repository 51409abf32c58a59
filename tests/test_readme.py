"""The README's Python snippet runs as written, on a generated tree in place of /data/claravid.

Only sizes change so that it fits a test: ViT-S/14 instead of ViT-L/14 (the same code path; the
"official" weights are a random-init file in the official format, put where the torch hub cache
keeps the download), a batch of 2 and no worker processes.
"""

import re
from pathlib import Path

import pytest
import torch

from claravid.synth import synthesize

ROOT = Path(__file__).resolve().parents[1]


def readme_snippet() -> str:
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert len(blocks) == 1, "the README shows one Python snippet"
    return blocks[0]


@pytest.mark.slow
def test_readme_snippet_runs(tmp_path, monkeypatch):
    from claravid.models import build_backbone
    from claravid.models.weights.loader import official_checkpoint_path

    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))  # this test's own hub cache
    data = tmp_path / "claravid"
    synthesize(data, seed=3, frames_per_viewpoint=2, size=(704, 660), missions=["urban_1"])
    weights = official_checkpoint_path("dinov2_vits14")
    weights.parent.mkdir(parents=True)
    torch.save(build_backbone("dinov2_vits14").state_dict(), weights)

    code = readme_snippet()
    for old, new in [
        ('"/data/claravid"', repr(str(data))),
        ('"dinov2_vitl14"', '"dinov2_vits14"'),
        ("batch_size=8", "batch_size=2"),
        ("num_workers=8", "num_workers=0"),
    ]:
        assert old in code, f"the README snippet no longer says {old}"
        code = code.replace(old, new)
    scope: dict = {}
    with torch.no_grad():
        exec(compile(code, "README.md", "exec"), scope)

    assert scope["logits"].shape == (2, 8, 630, 630)  # the snippet's comment, at batch 2
    assert Path(scope["batch"]["path"][0]).is_relative_to(data)
    assert scope["batch"]["image"].shape == (2, 3, 630, 630)
