"""The memory check before a backbone is built: what it counts, and what it reads."""

import pytest

from claravid.infra import memory
from claravid.models import build_backbone
from claravid.models.backbones.memory import NotEnoughMemoryError

TINY = {"embed_dim": 8, "depth": 1, "num_heads": 2}
GIB = 1 << 30


def test_the_weights_file_counts_when_memory_is_short(tmp_path, monkeypatch):
    # The parameters of the tiny model fit easily in 2 GiB; with its weights file (read whole
    # before the state dict is copied in) they do not: a sparse 3 GiB file takes no disk.
    path = tmp_path / "dinov3_vits16.pth"
    with open(path, "wb") as f:
        f.truncate(3 * GIB)
    monkeypatch.setattr(memory, "_read_meminfo", lambda: f"MemAvailable: {2 * GIB // 1024} kB\n")
    with pytest.raises(NotEnoughMemoryError) as err:
        build_backbone("dinov3_vits16", weights=path, **TINY)
    params = sum(t.numel() for t in build_backbone("dinov3_vits16", **TINY).state_dict().values())
    message = str(err.value)
    assert f"needs {(3 * GIB + 4 * params) / GIB:.1f} GiB" in message  # 3.0 GiB
    assert "plus its weights file" in message and "only 2.0 GiB are available" in message
    # Without the file the same model fits.
    assert build_backbone("dinov3_vits16", **TINY).patch_size == 16


def test_no_file_no_file_bytes(monkeypatch):
    monkeypatch.setattr(memory, "_read_meminfo", lambda: "MemAvailable: 1 kB\n")
    with pytest.raises(NotEnoughMemoryError, match=r"\(float32\) needs") as err:
        build_backbone("dinov3_vits16", **TINY)
    assert "weights file" not in str(err.value)
