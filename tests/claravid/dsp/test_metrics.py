"""Kernels against hand-computed values and against the official np.histogram2d formulation."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest

from claravid.dsp import (
    ImageReadError,
    deldensity_counts,
    delentropy,
    glcm_entropy,
    image_complexity,
    metrics,
    pixel_entropy,
    read_gray,
)
from claravid.dsp.metrics import BIN_LUT
from claravid.infra.errors import CorruptFileError

from .reference import OFFICIAL, official_deldensity, official_image_complexity, textured

TOL = 1e-9


def test_bin_lut_matches_histogram2d_for_every_integer_gradient():
    grads = np.arange(-1020, 1021)
    hist, _, _ = np.histogram2d(grads, np.zeros_like(grads), bins=511, range=[[-256, 256]] * 2)
    per_bin = hist.sum(axis=1)
    kept = BIN_LUT[BIN_LUT < 511]
    assert np.array_equal(np.bincount(kept, minlength=511), per_bin)
    assert np.all(np.diff(kept) >= 0)  # monotone, so equal counts per bin mean equal assignment
    assert (BIN_LUT == 511).sum() == grads.size - per_bin.sum()  # outside [-256, 256]: dropped
    for g in (-257, -256, -255, -1, 0, 1, 255, 256, 257, 1020):
        one, _, _ = np.histogram2d([g], [0], bins=511, range=[[-256, 256]] * 2)
        nz = np.flatnonzero(one.sum(axis=1))
        assert BIN_LUT[g + 1020] == (nz[0] if nz.size else 511), g


def fallback_counts(img: np.ndarray) -> np.ndarray:
    return metrics._counts_opencv(*cv2.spatialGradient(np.ascontiguousarray(img), ksize=3))


def test_native_module_is_built_and_counts_any_int16_exactly():
    # `make test` installs with a C compiler, so the fast path must be there (and tested).
    native = metrics._native
    assert native is not None, "claravid.dsp._deldensity was not built; reinstall with a compiler"
    rng = np.random.default_rng(0)
    gx = rng.integers(-32768, 32768, 5000).astype(np.int16)
    gy = rng.integers(-300, 300, 5000).astype(np.int16)
    gx[:10] = [-32768, 32767, -1021, 1021, -257, 257, -256, 256, 0, -1]
    counts = np.zeros((512, 512), np.uint32)
    native.count(gx, gy, metrics._BIN_LUT_U16, counts)
    expected, _, _ = np.histogram2d(
        gx.astype(int), gy.astype(int), bins=511, range=[[-256, 256]] * 2
    )
    assert np.array_equal(counts[:511, :511], expected)
    with pytest.raises(ValueError, match="equal length"):
        native.count(gx, gy[:-1], metrics._BIN_LUT_U16, counts)
    with pytest.raises(ValueError, match="512 x 512 uint32"):
        native.count(gx, gy, metrics._BIN_LUT_U16, np.zeros((512, 512), np.int64))
    with pytest.raises(ValueError, match="65536"):
        native.count(gx, gy, BIN_LUT, counts)


def test_hand_computed_values():
    const = np.full((5, 7), 77, np.uint8)
    assert delentropy(const) == 0.0
    assert pixel_entropy(const) == 0.0
    assert glcm_entropy(const) == 0.0
    # Columns 0,0,10,10: Sobel x is 0 on the outer columns (reflect-101) and 4*10 inside; gy = 0.
    step = np.tile(np.array([0, 0, 10, 10], np.uint8), (4, 1))
    assert delentropy(step) == pytest.approx(0.5, abs=1e-15)
    assert pixel_entropy(np.array([[0, 1], [2, 3]], np.uint8)) == pytest.approx(2.0)
    assert glcm_entropy(np.array([[0, 1], [0, 1]], np.uint8)) == pytest.approx(1.0)
    assert glcm_entropy(np.array([[0, 1, 2]], np.uint8)) == pytest.approx(2.0)
    assert glcm_entropy(np.array([[5], [9]], np.uint8)) == 0.0  # no horizontal pair


def _cases():
    rng = np.random.default_rng(7)
    shapes = [(1, 1), (1, 9), (9, 1), (2, 2), (3, 3), (17, 31), (120, 160)]
    for shape in shapes:
        yield f"uniform{shape}", rng.integers(0, 256, shape, dtype=np.uint8)
        # 0/255 noise: most Sobel responses far outside [-256, 256], up to +-1020.
        yield f"binary{shape}", (rng.integers(0, 2, shape) * 255).astype(np.uint8)
    yield "textured", textured(rng, 240, 320)
    yield "textured_blur", cv2.GaussianBlur(textured(rng, 200, 150), (3, 3), 1.0)
    stripes = np.zeros((64, 64), np.uint8)
    stripes[:, ::2] = 255
    yield "stripes", stripes
    yield "checker", (np.indices((40, 40)).sum(0) % 2 * 255).astype(np.uint8)
    yield "edge_256", np.tile(np.repeat(np.array([0, 64], np.uint8), 8), (8, 1))
    yield "ramp", np.tile(np.arange(256, dtype=np.uint8), (16, 1))


@pytest.mark.parametrize("name,img", list(_cases()), ids=[n for n, _ in _cases()])
def test_equal_to_official_formulation(name, img):
    assert np.array_equal(deldensity_counts(img), official_deldensity(img))
    # The OpenCV + numpy path, used where the C module is not built, equals it too.
    assert np.array_equal(fallback_counts(img), official_deldensity(img))
    assert abs(delentropy(img) - OFFICIAL["delent"](img)) <= TOL
    assert abs(glcm_entropy(img) - OFFICIAL["glcment"](img)) <= TOL
    assert abs(pixel_entropy(img) - OFFICIAL["pixent"](img)) <= TOL


def test_non_contiguous_input_equals_contiguous():
    img = textured(np.random.default_rng(3), 90, 120)
    view = img[::2, 1::3]
    assert delentropy(view) == delentropy(np.ascontiguousarray(view))


def test_counts_stay_exact_beyond_float32_range():
    # OpenCV histograms are float32 (exact below 2**24); 4097**2 is odd and above it.
    img = np.zeros((4097, 4097), np.uint8)
    img[0, 0] = 1
    for counts in (deldensity_counts(img), fallback_counts(img)):
        assert counts.sum() == 4097 * 4097
        # Only (0, 1), (1, 0) and (1, 1) see the corner pixel (reflect-101 cancels it at (0, 0)).
        assert counts[255, 255] == 4097 * 4097 - 3
    assert pixel_entropy(img) == pytest.approx(OFFICIAL["pixent"](img), abs=TOL)


@pytest.mark.parametrize("ext", ["png", "jpg"])
@pytest.mark.parametrize("blur,ksize", [(True, 3), (True, 5), (False, 3)])
@pytest.mark.parametrize("metric", ["delent", "glcment", "pixent"])
def test_image_complexity_equals_official_pipeline(tmp_path, ext, blur, ksize, metric):
    rng = np.random.default_rng(11)
    colour = np.dstack([textured(rng, 96, 128) for _ in range(3)])
    path = tmp_path / f"img.{ext}"
    cv2.imwrite(str(path), colour)
    ours = image_complexity(path, metric, blur=blur, ksize=ksize)
    assert abs(ours - official_image_complexity(path, metric, blur, ksize)) <= TOL


def test_read_gray_matches_imread_for_16bit_and_rgba_png(tmp_path):
    rng = np.random.default_rng(5)
    p16 = tmp_path / "deep.png"
    cv2.imwrite(str(p16), rng.integers(0, 65536, (20, 30), dtype=np.uint16))
    rgba = tmp_path / "rgba.png"
    cv2.imwrite(str(rgba), rng.integers(0, 256, (20, 30, 4), dtype=np.uint8))
    for p in (p16, rgba):
        assert np.array_equal(read_gray(p), cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))


def test_bad_arrays_say_what_is_wrong():
    with pytest.raises(ValueError, match="2-D greyscale"):
        delentropy(np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(ValueError, match="8-bit"):
        glcm_entropy(np.zeros((4, 4), np.float32))
    with pytest.raises(ValueError, match="empty"):
        pixel_entropy(np.zeros((0, 4), np.uint8))


def test_bad_settings_say_what_is_wrong(tmp_path):
    path = tmp_path / "a.png"
    cv2.imwrite(str(path), np.zeros((8, 8), np.uint8))
    with pytest.raises(ValueError, match="unknown metric 'delentropy'; choose one of delent"):
        image_complexity(path, "delentropy")
    with pytest.raises(ValueError, match="must be odd"):
        image_complexity(path, blur=True, ksize=4)
    with pytest.raises(ValueError, match="odd integer"):
        image_complexity(path, blur=True, ksize=True)
    assert image_complexity(path, blur=False, ksize=4) == 0.0  # ksize unused without blur


def test_unreadable_files_say_why(tmp_path):
    with pytest.raises(ImageReadError, match="no such file"):
        image_complexity(tmp_path / "missing.jpg")
    with pytest.raises(ImageReadError, match="not a regular file"):
        image_complexity(tmp_path)
    (tmp_path / "empty.png").write_bytes(b"")
    with pytest.raises(ImageReadError, match="empty"):
        image_complexity(tmp_path / "empty.png")
    (tmp_path / "junk.jpg").write_bytes(b"this is not an image")
    with pytest.raises(ImageReadError, match="could not decode"):
        image_complexity(tmp_path / "junk.jpg")
    ok = tmp_path / "ok.jpg"
    cv2.imwrite(str(ok), textured(np.random.default_rng(1), 64, 64))
    (tmp_path / "cut.jpg").write_bytes(ok.read_bytes()[:-200])
    with pytest.raises(ImageReadError, match="truncated JPEG"):
        image_complexity(tmp_path / "cut.jpg")
    # One family of "unreadable file" errors: the data layer's CorruptFileError catches it.
    with pytest.raises(CorruptFileError, match=r"cannot read .*junk\.jpg: OpenCV could not"):
        image_complexity(tmp_path / "junk.jpg")


def test_import_does_not_pull_torch():
    code = "import sys, claravid.dsp; sys.exit('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0
