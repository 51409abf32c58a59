"""Files written by hand for the tests: label maps of another program, headers that lie, weights
files that cannot be read."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path


def write_noisy_predictions(ds, folder: Path, share: float, seed: int, num_classes: int = 8):
    """Label maps of ``ds`` (uavid ids) with a ``share`` of pixels wrong, seeded, under
    ``folder/<frame key>.png``, without ``predictions.json`` (another program's maps)."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    for i, frame in enumerate(ds.frames):
        truth = ds.read_mask(i)
        valid = np.where(truth == 255, 0, truth).astype(np.uint8)
        wrong = rng.random(valid.shape) < share
        pred = np.where(wrong, (valid + 1) % num_classes, valid).astype(np.uint8)
        (folder / frame.key).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(folder / f"{frame.key}.png"), pred)


def png_claiming(width: int, height: int, color_type: int = 2, bit_depth: int = 8) -> bytes:
    """A PNG whose IHDR claims ``width``×``height``, with one tiny IDAT (never decoded)."""

    def chunk(kind, body):
        crc = zlib.crc32(kind + body).to_bytes(4, "big")
        return len(body).to_bytes(4, "big") + kind + body + crc

    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, color_type, 0, 0, 0)
    idat = zlib.compress(b"\x00" * 64)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def unreadable_files(folder: Path) -> dict[Path, str]:
    """(file, what its message must say): every way a weights/checkpoint file can be unusable."""
    import torch

    torch.save({"w": torch.zeros(3)}, folder / "good.pt")
    whole = (folder / "good.pt").read_bytes()
    cases = {
        "junk.pth": (b"not a checkpoint", "not a PyTorch tensor file"),
        "empty.pth": (b"", "is empty"),
        "truncated.pth": (whole[: len(whole) // 2], "truncated or corrupt"),
        "garbage.safetensors": (b"\x10\x00\x00\x00\x00\x00\x00\x00{bad json", "safetensors"),
        "pth_named.safetensors": (whole, "as safetensors"),
    }
    for name, (data, _) in cases.items():
        (folder / name).write_bytes(data)
    torch.save(torch.nn.Linear(2, 2), folder / "module.pth")  # pickled code, not tensors
    cases["module.pth"] = (None, "pickled Python objects")
    return {folder / name: match for name, (_, match) in cases.items()}


def sha256(data: bytes | Path) -> str:
    """The SHA-256 of bytes or of a file's content: compare large contents by this, never with
    ``==`` on the bytes (a failing comparison renders their whole difference)."""
    import hashlib

    return hashlib.sha256(data if isinstance(data, bytes) else Path(data).read_bytes()).hexdigest()


def use_hub_cache(monkeypatch, folder: Path) -> Path:
    """Point the Hugging Face hub cache at ``folder`` for one test: the variable, and the
    constant ``huggingface_hub`` read from it at import (which the toolkit reads)."""
    monkeypatch.setenv("HF_HUB_CACHE", str(folder))
    try:
        from huggingface_hub import constants
    except ImportError:
        return folder
    monkeypatch.setattr(constants, "HF_HUB_CACHE", str(folder))
    return folder
