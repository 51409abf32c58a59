"""A decoded window equals the same window of a full decode, pixel for pixel, for any JPEG.

The expected pixels never come from the code under test: ``cv2.imread`` of the whole file (EXIF
orientation ignored, as the datasets read photos), flipped to RGB, then sliced. The JPEGs are
written by encoders we do not control (OpenCV's and Pillow's libjpeg), in every chroma sampling,
baseline and progressive, with restart markers, in greyscale, at sizes that are no multiple of
the 8- or 16-pixel MCU. Every test runs on the libjpeg window decoder ("region") and on the
fallback that cuts the window from a full decode ("fallback").
"""

import io
import os
import threading

import cv2
import numpy as np
import pytest
from PIL import Image

from claravid.infra.errors import CorruptFileError, UnsupportedFileError
from claravid.io import jpeg_region, modalities
from claravid.io.modalities import read_rgb
from tests.claravid.io.jpeg_samples import (
    incomplete_progressive,
    lossless_jpeg,
    scan_starts,
    twelve_bit_jpeg,
)

NATIVE = jpeg_region._native
needs_native = pytest.mark.skipif(
    NATIVE is None, reason="claravid.io._jpeg_region not built (no C compiler or libjpeg headers)"
)


def textured(height, width, seed=0):
    """Gradients plus strong noise: chroma changes every pixel, so upsampling errors show."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width]
    base = np.stack([xx * 255 / max(width - 1, 1), yy * 255 / max(height - 1, 1), (xx + yy) % 256])
    noisy = base.transpose(1, 2, 0) + rng.normal(0, 40, (height, width, 3))
    return np.clip(noisy, 0, 255).astype(np.uint8)


def _cv2(*params):
    return lambda rgb: cv2.imencode(".jpg", rgb[..., ::-1], [*params])[1].tobytes()


def _pil(mode="RGB", **options):
    def encode(rgb):
        buffer = io.BytesIO()
        Image.fromarray(rgb).convert(mode).save(buffer, "JPEG", **options)
        return buffer.getvalue()

    return encode


SAMPLING = cv2.IMWRITE_JPEG_SAMPLING_FACTOR
ENCODERS = {
    "cv2-420": _cv2(SAMPLING, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420, cv2.IMWRITE_JPEG_QUALITY, 95),
    "cv2-422": _cv2(SAMPLING, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422),
    "cv2-444": _cv2(SAMPLING, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444),
    "cv2-411": _cv2(SAMPLING, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_411),
    "cv2-440": _cv2(SAMPLING, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_440),
    "cv2-420-progressive": _cv2(cv2.IMWRITE_JPEG_PROGRESSIVE, 1),
    "cv2-422-progressive": _cv2(
        SAMPLING, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422, cv2.IMWRITE_JPEG_PROGRESSIVE, 1
    ),
    "cv2-420-restart": _cv2(cv2.IMWRITE_JPEG_RST_INTERVAL, 3),
    "cv2-grey": lambda rgb: cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))[1],
    "pil-444": _pil(subsampling=0, quality=90),
    "pil-422": _pil(subsampling=1, quality=90),
    "pil-420": _pil(subsampling=2, quality=90),
    "pil-420-progressive": _pil(subsampling=2, progressive=True),
    "pil-444-progressive": _pil(subsampling=0, progressive=True),
    "pil-grey": _pil("L"),
}
SIZES = [(203, 141), (17, 9), (1, 1), (33, 47)]  # (width, height)


def expected(path):
    """The independent statement: OpenCV's full decode, pixels as stored, in RGB order."""
    return cv2.imread(str(path), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)[..., ::-1]


def windows(width, height, seed=0, count=25):
    """The full frame, every border and corner, 1-pixel windows, MCU edges, random windows."""
    right, bottom = width - 1, height - 1
    found = {(0, 0, width, height), (0, 0, 1, 1), (right, 0, 1, 1), (0, bottom, 1, 1)}
    found |= {(right, bottom, 1, 1), (0, 0, width, 1), (0, bottom, width, 1)}
    found |= {(0, 0, 1, height), (right, 0, 1, height)}
    for edge in (7, 8, 9, 15, 16, 17, 31, 32, 33):  # on, before and after MCU boundaries
        if edge < width and edge < height:
            found |= {(edge, 0, width - edge, height), (0, edge, width, height - edge)}
            found |= {(edge, edge, 1, 1), (0, 0, edge, edge)}
    rng = np.random.default_rng(seed)
    for _ in range(count):
        x, y = int(rng.integers(width)), int(rng.integers(height))
        found.add((x, y, int(rng.integers(1, width - x + 1)), int(rng.integers(1, height - y + 1))))
    return sorted(found)


@pytest.fixture(params=["region", "fallback"])
def decode(request, monkeypatch):
    """read_rgb_window on the libjpeg window decoder, or on the full-decode fallback."""
    if request.param == "region" and NATIVE is None:
        pytest.skip("claravid.io._jpeg_region not built (no C compiler or libjpeg headers)")
    if request.param == "fallback":
        monkeypatch.setattr(jpeg_region, "_native", None)
    return jpeg_region.read_rgb_window


def write_jpeg(path, encoder, width, height, seed=0):
    path.write_bytes(bytes(ENCODERS[encoder](textured(height, width, seed))))
    return path


def test_the_window_decoder_is_built_on_ci():
    # CI installs with a C compiler and libjpeg-dev: there the fast path must exist (and so be
    # tested), not silently fall back.
    if NATIVE is None and not os.environ.get("CI"):
        pytest.skip("claravid.io._jpeg_region not built; set CI=1 to make this a failure")
    assert NATIVE is not None, "claravid.io._jpeg_region was not built; install libjpeg-dev + gcc"
    assert jpeg_region.decoder() == jpeg_region.REGION_DECODE == "libjpeg region decode"


def test_decoder_names_the_fallback(monkeypatch):
    monkeypatch.setattr(jpeg_region, "_native", None)
    said = jpeg_region.decoder()
    assert said.startswith("full decode (C extension not built): a 630×630 crop of a 4032×3024 ")
    assert "about 8× as long; install a C compiler and libjpeg-dev" in said and "\n" not in said


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
@pytest.mark.parametrize("encoder", ENCODERS)
def test_every_window_equals_the_full_decode(tmp_path, decode, encoder, size):
    path = write_jpeg(tmp_path / "f.jpg", encoder, *size)
    full = expected(path)
    assert jpeg_region.jpeg_size(path) == size == (full.shape[1], full.shape[0])
    for x, y, w, h in windows(*size):
        window = decode(path, x, y, w, h)
        assert window.dtype == np.uint8 and window.shape == (h, w, 3)
        assert window.flags.c_contiguous
        np.testing.assert_array_equal(window, full[y : y + h, x : x + w], err_msg=f"{x, y, w, h}")


@pytest.mark.parametrize("encoder", ["cv2-420", "cv2-422", "pil-420-progressive"])
def test_large_windows_of_a_larger_frame(tmp_path, decode, encoder):
    path = write_jpeg(tmp_path / "f.jpg", encoder, 700, 530, seed=3)
    full = expected(path)
    np.testing.assert_array_equal(full, read_rgb(path))  # the expectation is read_rgb's pixels
    for x, y, w, h in [*windows(700, 530, seed=4, count=12), (37, 51, 630, 470)]:
        np.testing.assert_array_equal(decode(path, x, y, w, h), full[y : y + h, x : x + w])


def _margin_failures(path, size, margins):
    data, full = path.read_bytes(), expected(path)
    failures = dict.fromkeys(margins, 0)
    for x, y, w, h in windows(*size, count=60):
        for margin_x, margin_y in margins:
            out = np.empty((h, w, 3), np.uint8)
            NATIVE.decode_window(data, x, y, w, h, out, margin_x=margin_x, margin_y=margin_y)
            failures[margin_x, margin_y] += not np.array_equal(out, full[y : y + h, x : x + w])
    return failures


@needs_native
@pytest.mark.parametrize("encoder", ["cv2-420", "cv2-422", "pil-420", "cv2-440"])
def test_each_margin_is_measured(tmp_path, encoder):
    # Smooth chroma upsampling reads chroma beyond the window. The margins are the module's
    # internal knobs, one per axis; each is removed alone (the C file's comment says what this
    # measured). Horizontal: jpeg_crop_scanline makes the crop's sides image edges, so 4:2:0 and
    # 4:2:2 windows differ without it. Vertical: libjpeg-turbo 2.1's jpeg_skip_scanlines decodes
    # the context rows itself, so no window differs without it there (it is kept for older ones).
    path = write_jpeg(tmp_path / "f.jpg", encoder, 203, 141)
    failures = _margin_failures(path, (203, 141), [(1, 1), (0, 1), (1, 0)])
    assert failures[1, 1] == 0, failures
    if encoder != "cv2-440":  # 4:4:0 is subsampled vertically only
        assert failures[0, 1] > 0, failures
    else:
        assert failures[0, 1] == 0, failures
    if NATIVE.LIBJPEG_TURBO_VERSION // 1000 == 2001:
        assert failures[1, 0] == 0, failures


@needs_native
def test_the_c_decoder_checks_its_arguments(tmp_path):
    # The Python wrapper checks too, but the C function must not trust its caller: a coordinate
    # beyond 32 bits must not wrap (2**32 + 5 is not 5), nor a negative one, and only a uint8
    # C-contiguous (h, w, 3) array may be filled.
    data = write_jpeg(tmp_path / "f.jpg", "cv2-420", 40, 30).read_bytes()
    full = expected(tmp_path / "f.jpg")
    out = np.zeros((4, 6, 3), np.uint8)
    NATIVE.decode_window(data, 5, 2, 6, 4, out)
    np.testing.assert_array_equal(out, full[2:6, 5:11])
    for name, args in [
        ("x", (2**32 + 5, 2, 6, 4)),
        ("y", (5, 2**32 + 2, 6, 4)),
        ("x", (-1, 2, 6, 4)),
        ("y", (5, -3, 6, 4)),
        ("x", (2**64, 2, 6, 4)),
        ("w", (5, 2, 0, 4)),
        ("h", (5, 2, 6, 0)),
        ("w", (5, 2, 2**32 + 6, 4)),
    ]:
        before = out.copy()
        with pytest.raises(ValueError, match=rf"^{name} = -?\d+ is out of range"):
            NATIVE.decode_window(data, *args, out)
        np.testing.assert_array_equal(out, before)  # nothing written
    with pytest.raises(ValueError, match=r"outside the 40x30 image"):
        NATIVE.decode_window(data, 35, 2, 6, 4, out)
    with pytest.raises(TypeError, match="x must be an integer, got float"):
        NATIVE.decode_window(data, 5.0, 2, 6, 4, out)
    with pytest.raises(ValueError, match="margin_y = -1 is out of range"):
        NATIVE.decode_window(data, 5, 2, 6, 4, out, margin_y=-1)
    bad_outs = [
        (np.zeros((4, 6, 3), np.float32), TypeError),  # the right byte count in 4-byte items
        (np.zeros(4 * 6 * 3, np.uint8), ValueError),  # flat: the right byte count
        (np.zeros((6, 4, 3), np.uint8), ValueError),  # width and height swapped
        (np.zeros((4, 6, 4), np.uint8), ValueError),
        (np.zeros((4, 12, 3), np.uint8)[:, ::2], (BufferError, ValueError)),  # not contiguous
        (bytearray(4 * 6 * 3), ValueError),
        (bytes(4 * 6 * 3), (BufferError, TypeError)),  # read-only
    ]
    for bad, error in bad_outs:
        before = bytes(memoryview(bad).cast("B")) if memoryview(bad).c_contiguous else None
        with pytest.raises(error):
            NATIVE.decode_window(data, 5, 2, 6, 4, bad)
        if before is not None:
            assert bytes(memoryview(bad).cast("B")) == before


def test_exif_orientation_is_ignored(tmp_path, decode):
    rgb = textured(30, 50)
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90° clockwise to display": the datasets keep stored pixels
    Image.fromarray(rgb).save(tmp_path / "r.jpg", exif=exif, quality=95)
    full = expected(tmp_path / "r.jpg")
    assert full.shape == (30, 50, 3) and jpeg_region.jpeg_size(tmp_path / "r.jpg") == (50, 30)
    np.testing.assert_array_equal(decode(tmp_path / "r.jpg", 3, 4, 40, 20), full[4:24, 3:43])
    np.testing.assert_array_equal(read_rgb(tmp_path / "r.jpg")[4:24, 3:43], full[4:24, 3:43])


@pytest.mark.parametrize("suffix", [".png", ".tiff", ".webp"])
def test_other_formats_are_decoded_whole_and_sliced(tmp_path, decode, suffix):
    path = tmp_path / f"f{suffix}"
    cv2.imwrite(str(path), textured(41, 37)[..., ::-1])
    np.testing.assert_array_equal(decode(path, 5, 6, 30, 20), read_rgb(path)[6:26, 5:35])
    assert jpeg_region.image_size(path) == (37, 41)


def test_png_bytes_named_jpg_are_decoded_as_png(tmp_path, decode):
    path = tmp_path / "f.jpg"
    path.write_bytes(cv2.imencode(".png", textured(20, 30))[1].tobytes())
    np.testing.assert_array_equal(decode(path, 1, 2, 10, 5), read_rgb(path)[2:7, 1:11])


def test_cmyk_jpeg_falls_back_to_a_full_decode(tmp_path, decode):
    Image.fromarray(textured(20, 30)).convert("CMYK").save(tmp_path / "c.jpg")
    full = expected(tmp_path / "c.jpg")
    np.testing.assert_array_equal(decode(tmp_path / "c.jpg", 2, 3, 20, 10), full[3:13, 2:22])


def test_image_size_of_a_jpeg_reads_only_the_header(tmp_path):
    path = write_jpeg(tmp_path / "f.jpg", "pil-420", 203, 141)
    data = path.read_bytes()
    assert jpeg_region.image_size(path) == jpeg_region.jpeg_size(data) == (203, 141)
    head = data[: data.index(b"\xff\xda")]  # everything before the image data
    assert jpeg_region.jpeg_size(np.frombuffer(head, np.uint8)) == (203, 141)


def test_threads_decode_concurrently_to_the_same_pixels(tmp_path):
    path = write_jpeg(tmp_path / "f.jpg", "cv2-420", 300, 200)
    full, results = expected(path), {}

    def work(i):
        results[i] = jpeg_region.read_rgb_window(path, i, 2 * i, 150, 100)

    threads = [threading.Thread(target=work, args=(i,)) for i in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for i, window in results.items():
        np.testing.assert_array_equal(window, full[2 * i : 2 * i + 100, i : i + 150])
    assert len(results) == 8


# ------------------------------------------------------------------------------------------
# Bad input: errors that name the file, never a crash and never invented pixels.


def test_window_outside_the_frame_is_refused(tmp_path, decode):
    path = write_jpeg(tmp_path / "f.jpg", "cv2-420", 40, 30)
    for window in [(0, 0, 41, 30), (0, 0, 40, 31), (39, 0, 2, 1), (0, 29, 1, 2), (40, 0, 1, 1)]:
        with pytest.raises(ValueError, match=r"does not fit in the 40×30 frame of .*f\.jpg") as e:
            decode(path, *window)
        assert not isinstance(e.value, CorruptFileError)
    for window in [(-1, 0, 5, 5), (0, -1, 5, 5), (0, 0, 0, 5), (0, 0, 5, 0)]:
        with pytest.raises(ValueError, match="need x, y >= 0, sizes >= 1"):
            decode(path, *window)
    with pytest.raises(TypeError, match="x must be an integer"):
        decode(path, 1.5, 0, 5, 5)


def test_missing_empty_and_truncated_files_name_the_file(tmp_path, decode):
    with pytest.raises(FileNotFoundError, match=r"nope\.jpg"):
        decode(tmp_path / "nope.jpg", 0, 0, 1, 1)
    (tmp_path / "e.jpg").write_bytes(b"")
    with pytest.raises(CorruptFileError, match=r"e\.jpg.*empty"):
        decode(tmp_path / "e.jpg", 0, 0, 1, 1)
    data = write_jpeg(tmp_path / "f.jpg", "cv2-420", 203, 141).read_bytes()
    (tmp_path / "t.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptFileError, match=r"t\.jpg: truncated JPEG"):
        decode(tmp_path / "t.jpg", 0, 0, 5, 5)  # even a window whose data is all there


def test_non_jpeg_bytes_named_jpg(tmp_path, decode):
    (tmp_path / "g.jpg").write_bytes(b"this is not an image at all" * 10)
    with pytest.raises(CorruptFileError, match=r"g\.jpg.*could not decode"):
        decode(tmp_path / "g.jpg", 0, 0, 1, 1)
    with pytest.raises(CorruptFileError, match=r"g\.jpg: not a JPEG file"):
        jpeg_region.jpeg_size(tmp_path / "g.jpg")


def test_truncated_header_names_the_file(tmp_path):
    data = write_jpeg(tmp_path / "f.jpg", "cv2-420", 20, 10).read_bytes()
    (tmp_path / "h.jpg").write_bytes(data[:30])
    with pytest.raises(CorruptFileError, match=r"h\.jpg: truncated JPEG header"):
        jpeg_region.jpeg_size(tmp_path / "h.jpg")
    with pytest.raises(CorruptFileError, match=r"<bytes>: truncated JPEG header"):
        jpeg_region.jpeg_size(data[:30])


def _lying_header(data, height):
    """The file with its frame height replaced: the header promises rows the data lacks."""
    sof = data.index(b"\xff\xc0")
    return data[: sof + 5] + height.to_bytes(2, "big") + data[sof + 7 :]


def test_a_header_that_lies_about_the_size(tmp_path, decode):
    data = write_jpeg(tmp_path / "f.jpg", "cv2-420", 203, 141).read_bytes()
    lie = _lying_header(data, 3024)
    (tmp_path / "short.jpg").write_bytes(lie[: len(lie) * 3 // 4])  # and truncated: no EOI
    assert jpeg_region.jpeg_size(tmp_path / "short.jpg") == (203, 3024)
    with pytest.raises(CorruptFileError, match=r"short\.jpg: truncated JPEG"):
        decode(tmp_path / "short.jpg", 0, 2000, 50, 50)


@needs_native
def test_rows_missing_from_the_data_are_an_error_not_grey(tmp_path):
    # The header promises 3024 rows, the data (which ends properly) holds 141: libjpeg alone
    # would fill the missing rows with grey; the window decoder refuses them, naming the file,
    # and so does read_rgb, the full decode (it returned grey rows). (Without the C module
    # nothing can tell: OpenCV returns the grey rows.)
    data = write_jpeg(tmp_path / "f.jpg", "cv2-420", 203, 141).read_bytes()
    (tmp_path / "lie.jpg").write_bytes(_lying_header(data, 3024))
    with pytest.raises(CorruptFileError, match=r"lie\.jpg: libjpeg: .*premature end"):
        jpeg_region.read_rgb_window(tmp_path / "lie.jpg", 0, 2000, 50, 50)
    with pytest.raises(CorruptFileError, match=r"lie\.jpg: libjpeg: .*premature end"):
        read_rgb(tmp_path / "lie.jpg")
    with pytest.raises(CorruptFileError, match=r"lie\.jpg: libjpeg: .*premature end"):
        modalities.read_seg_color(tmp_path / "lie.jpg")
    # Rows the data does hold decode as in the honest file.
    top = jpeg_region.read_rgb_window(tmp_path / "lie.jpg", 3, 5, 100, 60)
    np.testing.assert_array_equal(top, expected(tmp_path / "f.jpg")[5:65, 3:103])


@needs_native
def test_corrupt_data_raises_or_decodes_but_never_crashes(tmp_path):
    data = bytearray(write_jpeg(tmp_path / "f.jpg", "cv2-420", 203, 141).read_bytes())
    start = data.index(b"\xff\xda") + 20
    rng = np.random.default_rng(5)
    errors = 0
    for i in range(40):
        damaged = bytearray(data)
        for where in rng.integers(start, len(data) - 2, 8):
            damaged[where] = int(rng.integers(256))
        path = tmp_path / f"d{i}.jpg"
        path.write_bytes(bytes(damaged))
        try:
            window = jpeg_region.read_rgb_window(path, 0, 0, 203, 141)
        except CorruptFileError as error:
            assert f"d{i}.jpg" in str(error)
            errors += 1
        else:
            assert window.shape == (141, 203, 3)
    assert errors > 0  # bad Huffman codes are reported, not painted over


# ------------------------------------------------------------------------------------------
# Files the window decoder must not read by window, and files no reader takes (issue 24).


def _pil_progressive(width=203, height=141, seed=0):
    buffer = io.BytesIO()
    Image.fromarray(textured(height, width, seed)).save(buffer, "JPEG", progressive=True)
    return buffer.getvalue()


@pytest.mark.parametrize("scans", [1, 2, 4, 7])
def test_windows_of_an_incomplete_progressive_jpeg_equal_the_full_decode(tmp_path, decode, scans):
    # A legal file: its last scans are missing, it ends with EOI. Block smoothing of such a file
    # reads two blocks around each block, and OpenCV's libjpeg-turbo 3 smooths differently from
    # the system's 2.1: windows are cut from the full decode.
    data = _pil_progressive()
    assert len(scan_starts(data)) == 10  # Pillow's default progressive script
    path = tmp_path / "p.jpg"
    path.write_bytes(incomplete_progressive(data, scans))
    full = expected(path)
    assert not np.array_equal(full, expected_bytes(data))  # the missing scans show
    np.testing.assert_array_equal(read_rgb(path), full)
    for x, y, w, h in windows(203, 141, seed=scans):
        np.testing.assert_array_equal(decode(path, x, y, w, h), full[y : y + h, x : x + w])


@needs_native
def test_a_progressive_jpeg_cut_inside_a_scan_is_refused(tmp_path):
    # Cut inside the first (DC) scan and closed with EOI: the rest of the image would be grey.
    data = _pil_progressive()
    starts = scan_starts(data)
    cut = data[: (starts[0] + starts[1]) // 2] + b"\xff\xd9"
    (tmp_path / "cut.jpg").write_bytes(cut)
    for read in (read_rgb, lambda p: jpeg_region.read_rgb_window(p, 100, 50, 20, 20)):
        with pytest.raises(CorruptFileError, match=r"cut\.jpg: libjpeg: .*premature end"):
            read(tmp_path / "cut.jpg")


def expected_bytes(data):
    array = np.frombuffer(data, np.uint8)
    return cv2.imdecode(array, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)[..., ::-1]


@pytest.mark.parametrize("channels", [1, 3])
def test_a_lossless_jpeg_is_decoded_whole_and_equals_its_pixels(tmp_path, decode, channels):
    # libjpeg-turbo 2.1 (the window decoder's) cannot read lossless JPEGs; OpenCV's 3.x can.
    rgb = textured(23, 37)
    if channels == 1:
        rgb = np.repeat(rgb[..., 1:2], 3, axis=2)  # grey: the reader expands it to RGB
    path = tmp_path / "lossless.jpg"
    path.write_bytes(lossless_jpeg(rgb[..., 1] if channels == 1 else rgb))
    if channels == 3:  # lossless: the pixels themselves, also for OpenCV
        np.testing.assert_array_equal(expected(path), rgb)
    np.testing.assert_array_equal(read_rgb(path), rgb)
    for x, y, w, h in windows(37, 23, count=8):
        np.testing.assert_array_equal(decode(path, x, y, w, h), rgb[y : y + h, x : x + w])
    assert jpeg_region.image_size(path) == (37, 23)


def _refused(path, decode, error, pattern):
    for read in (read_rgb, lambda p: decode(p, 0, 0, 8, 8), jpeg_region.image_size):
        with pytest.raises(error, match=pattern) as caught:
            read(path)
        assert "re-copy" not in str(caught.value)


def test_a_12_bit_jpeg_is_unsupported_not_corrupt(tmp_path, decode):
    path = tmp_path / "deep.jpg"
    path.write_bytes(twelve_bit_jpeg(np.arange(15).reshape(3, 5) * 273))
    assert cv2.imread(str(path)) is None  # OpenCV decodes no 12-bit JPEG either
    pattern = r"deep\.jpg: 12-bit JPEG: the readers decode 8-bit JPEGs only; convert it"
    _refused(path, decode, UnsupportedFileError, pattern)


def test_an_arithmetic_coded_jpeg_is_refused(tmp_path, decode):
    # Arithmetic decoders feed zeros past the end of the data, which a complete file may also
    # leave out: a cut file cannot be told from a whole one, so none is read. (The start of frame
    # says SOF9; the data need not be arithmetic-coded for the header to be refused.)
    data = write_jpeg(tmp_path / "f.jpg", "cv2-420", 40, 30).read_bytes()
    sof = data.index(b"\xff\xc0")
    (tmp_path / "arith.jpg").write_bytes(data[: sof + 1] + b"\xc9" + data[sof + 2 :])
    _refused(tmp_path / "arith.jpg", decode, UnsupportedFileError, r"arith\.jpg: arithmetic")


def test_a_header_claiming_more_than_2_30_pixels_is_refused(tmp_path, decode):
    data = write_jpeg(tmp_path / "f.jpg", "cv2-420", 40, 30).read_bytes()
    sof = data.index(b"\xff\xc0")
    huge = data[: sof + 5] + (65500).to_bytes(2, "big") * 2 + data[sof + 9 :]
    (tmp_path / "huge.jpg").write_bytes(huge)
    pattern = r"huge\.jpg: its header claims 65500×65500 = 4,290,250,000 pixels, more than the "
    _refused(tmp_path / "huge.jpg", decode, UnsupportedFileError, pattern + r"1,073,741,824")


def test_a_tiny_cmyk_file_claiming_30000x30000_is_refused_at_once(tmp_path, decode):
    # 3 kB cannot code 14 million blocks per component (one bit each at least); decoding it
    # took 27 s and 5.2 GB to return grey.
    Image.fromarray(textured(40, 48)).convert("CMYK").save(tmp_path / "c.jpg")
    data = (tmp_path / "c.jpg").read_bytes()
    sof = data.index(b"\xff\xc0")
    lie = data[: sof + 5] + (30000).to_bytes(2, "big") * 2 + data[sof + 9 :]
    (tmp_path / "lie.jpg").write_bytes(lie)
    assert len(lie) < 4000
    pattern = r"lie\.jpg: its header claims 30000×30000 pixels, but the file holds [\d,]+ bytes, "
    for read in (read_rgb, lambda p: decode(p, 0, 0, 8, 8), jpeg_region.image_size):
        with pytest.raises(CorruptFileError, match=pattern + r"fewer than the 1,757,812 any JPEG"):
            read(tmp_path / "lie.jpg")


def test_trailer_data_after_the_end_marker_is_accepted(tmp_path, decode):
    # Motion photos append a video, cameras maker data: more than 4 KiB after the end marker.
    data = write_jpeg(tmp_path / "f.jpg", "cv2-420", 203, 141).read_bytes()
    full = expected(tmp_path / "f.jpg")
    trailer = np.random.default_rng(2).integers(0, 256, 20000, dtype=np.uint8).tobytes()
    (tmp_path / "motion.jpg").write_bytes(data + trailer.replace(b"\xff\xd9", b"\xff\x00"))
    np.testing.assert_array_equal(read_rgb(tmp_path / "motion.jpg"), full)
    np.testing.assert_array_equal(decode(tmp_path / "motion.jpg", 7, 9, 50, 40), full[9:49, 7:57])


def test_a_thumbnail_s_end_marker_does_not_make_a_cut_file_whole(tmp_path, decode):
    # An EXIF thumbnail is a whole JPEG inside an APP1 segment, with its own end marker: the cut
    # main image is still truncated.
    # Small files: the thumbnail's end marker lies within the last 4 KiB of the cut file too.
    thumb = write_jpeg(tmp_path / "t.jpg", "cv2-420", 16, 12).read_bytes()
    data = write_jpeg(tmp_path / "f.jpg", "cv2-420", 40, 24).read_bytes()
    app1 = b"\xff\xe1" + (len(thumb) + 8).to_bytes(2, "big") + b"Exif\x00\x00" + thumb
    with_thumb = data[:2] + app1 + data[2:]
    (tmp_path / "whole.jpg").write_bytes(with_thumb)
    np.testing.assert_array_equal(read_rgb(tmp_path / "whole.jpg"), expected(tmp_path / "f.jpg"))
    cut = with_thumb[: len(with_thumb) - 300]
    assert len(cut) < 4096 and cut.rindex(b"\xff\xd9") < cut.rindex(b"\xff\xda")
    (tmp_path / "cut.jpg").write_bytes(cut)
    for read in (read_rgb, lambda p: decode(p, 0, 0, 8, 8)):
        with pytest.raises(CorruptFileError, match=r"cut\.jpg: truncated JPEG"):
            read(tmp_path / "cut.jpg")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_named_jpg_is_refused_without_blocking(tmp_path, decode):
    os.mkfifo(tmp_path / "pipe.jpg")
    pattern = r"pipe\.jpg: not a regular file"
    _refused(tmp_path / "pipe.jpg", decode, UnsupportedFileError, pattern)
    with pytest.raises(UnsupportedFileError, match=pattern):
        jpeg_region.jpeg_size(tmp_path / "pipe.jpg")
