"""Damaged JPEGs through the window decoder against OpenCV's full decode: the same pixels, or both
refuse.

Real-encoded files (OpenCV's encoder, sequential, with and without restart markers, 4:2:0 and
4:4:4) are cut short and have single bits flipped at deterministic places. The independent
statement is OpenCV's ``imdecode`` of the whole damaged file: it refuses when it returns nothing
or when libjpeg warns that it made pixels up (data ran out, a bad Huffman code, a marker where
data should be), the warnings it prints; otherwise the window must equal its decode, sliced.
"""

import cv2
import numpy as np
import pytest

from claravid.infra.errors import CorruptFileError, UnsupportedFileError
from claravid.io import jpeg_region
from tests.claravid.io.test_jpeg_region import needs_native, textured

#: libjpeg's warnings that mean pixels were invented (as it words them).
INVENTED = ("Premature end of JPEG file", "premature end of data segment", "bad Huffman code",
            "instead of RST", "Corrupt JPEG data: found marker")  # fmt: skip

SAMPLING = cv2.IMWRITE_JPEG_SAMPLING_FACTOR
#: (name, width, height, imencode parameters): small, sizes no multiple of the MCU.
FILES = [
    ("420", 61, 45, [SAMPLING, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420, cv2.IMWRITE_JPEG_QUALITY, 90]),
    ("444-restart", 37, 29, [SAMPLING, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444,
                             cv2.IMWRITE_JPEG_RST_INTERVAL, 2]),
]  # fmt: skip


def damaged(data: bytes, seed: int):
    """Deterministic damage: 12 truncations (header, scan, the last bytes) and 40 bit flips."""
    rng = np.random.default_rng(seed)
    cuts = {2, 20, len(data) // 3, len(data) - 2, len(data) - 1}
    cuts |= {int(c) for c in rng.integers(2, len(data), 12 - len(cuts))}
    for cut in sorted(cuts):
        yield f"cut at {cut}", data[:cut]
    for position, bit in zip(rng.integers(2, len(data), 40), rng.integers(0, 8, 40), strict=True):
        flipped = bytearray(data)
        flipped[position] ^= 1 << int(bit)
        yield f"bit {bit} of byte {position} flipped", bytes(flipped)


def opencv(data: bytes, capfd):
    """OpenCV's full decode in RGB, or None where it refuses or says it made pixels up."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    warned = capfd.readouterr().err
    if image is None or any(text in warned for text in INVENTED):
        return None
    return image[..., ::-1]


def ours(path, seed: int):
    """A window (a random one inside the header's size) and where it lies, or None on refusal."""
    try:
        photo = jpeg_region.open_photo(path)
        width, height = photo.size
        rng = np.random.default_rng(seed)
        x, y = int(rng.integers(width)), int(rng.integers(height))
        w, h = int(rng.integers(1, width - x + 1)), int(rng.integers(1, height - y + 1))
        return photo.window(x, y, w, h), (x, y, w, h)
    except (CorruptFileError, UnsupportedFileError):
        return None


@needs_native
@pytest.mark.parametrize(("name", "width", "height", "params"), FILES, ids=[f[0] for f in FILES])
def test_a_damaged_jpeg_gives_opencvs_pixels_or_is_refused_by_both(
    tmp_path, capfd, name, width, height, params
):
    data = cv2.imencode(".jpg", textured(height, width, seed=width)[..., ::-1], params)[1]
    agreed = {"same pixels": 0, "both refuse": 0}
    for i, (damage, bytes_) in enumerate(damaged(data.tobytes(), seed=width)):
        path = tmp_path / f"{i}.jpg"
        path.write_bytes(bytes_)
        expected, got = opencv(bytes_, capfd), ours(path, seed=i)
        if got is None:
            assert expected is None, f"{damage}: refused here, decoded by OpenCV"
            agreed["both refuse"] += 1
            continue
        window, (x, y, w, h) = got
        assert expected is not None, f"{damage}: decoded here, refused by OpenCV"
        assert expected.shape[:2] == photo_size(path)[::-1], damage
        np.testing.assert_array_equal(window, expected[y : y + h, x : x + w], err_msg=damage)
        agreed["same pixels"] += 1
    assert min(agreed.values()) > 0, agreed  # the damage exercised both outcomes


def photo_size(path):
    return jpeg_region.open_photo(path).size
