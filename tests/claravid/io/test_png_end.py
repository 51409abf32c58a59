"""Where a PNG ends: its IEND chunk, wherever the file's last byte is. Bytes after IEND (a
tool's trailer, padding) are not a truncation; a file cut before IEND is."""

import numpy as np
import pytest

from claravid.infra.errors import CorruptFileError
from claravid.io import modalities

SIZE = (37, 53)  # height, width: not square


@pytest.fixture
def mask_png(tmp_path):
    """An 8-bit grey PNG (a dynamic mask) written with small IDAT chunks, and its pixels."""
    mask = np.random.default_rng(0).integers(0, 2, SIZE, dtype=np.uint8) * 255
    path = tmp_path / "mask.png"
    modalities.write_dynamic_mask(path, mask)
    return path, mask


@pytest.mark.parametrize("trailer", [b"\x00" * 7, b"trailing text from another tool\n" * 40])
def test_bytes_after_iend_are_accepted(mask_png, trailer):
    path, mask = mask_png
    path.write_bytes(path.read_bytes() + trailer)  # was refused as "truncated PNG"
    np.testing.assert_array_equal(modalities.read_dynamic_mask(path) > 0, mask > 0)


def _chunk_ends(data):
    """Offsets just after each chunk of a PNG (walked by hand from the signature)."""
    ends, position = [], 8
    while position < len(data):
        length = int.from_bytes(data[position : position + 4], "big")
        position += 12 + length
        ends.append(position)
    return ends


def test_a_png_cut_before_iend_is_still_refused(mask_png):
    path, _ = mask_png
    data = path.read_bytes()
    ends = _chunk_ends(data)
    iend = ends[-2]  # where the IEND chunk starts (the file's last 12 bytes)
    assert data[iend + 4 : iend + 8] == b"IEND" and ends[-1] == len(data)
    broken = [
        data[: len(data) // 2],  # cut inside IDAT
        data[:iend],  # cut at a chunk boundary: no IEND
        data[:-1],  # cut inside IEND
        data[:iend] + b"\x00" * 20,  # other bytes where IEND should be
    ]
    for content in broken:
        path.write_bytes(content)
        with pytest.raises(CorruptFileError, match="truncated PNG"):
            modalities.read_dynamic_mask(path)
