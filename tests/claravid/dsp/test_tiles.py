"""Tiles (boundaries by hand, values against the official recipe on the cropped pixels) and
several measures from one decode."""

import cv2
import numpy as np
import pytest

from claravid.dsp import collection as collection_module
from claravid.dsp import compute_complexities, compute_measures, tile_bounds, tile_complexities
from claravid.dsp.tiles import tile_grid
from tests.claravid.dsp.reference import (
    official_delentropy,
    official_glcm_entropy,
    official_image_complexity,
    official_pixel_entropy,
    textured,
)


@pytest.mark.parametrize(
    ("length", "size", "expected"),
    [
        (10, 4, [0, 5, 10]),  # 10/4 = 2.5 -> 2 tiles (halves to even)
        (11, 4, [0, 4, 7, 11]),  # 2.75 -> 3; 11/3 = 3.67 -> 4, 22/3 = 7.33 -> 7
        (7, 2, [0, 2, 4, 5, 7]),  # 3.5 -> 4; 1.75 -> 2, 3.5 -> 4, 5.25 -> 5
        (5, 630, [0, 5]),  # shorter than a tile: one tile
        (3024, 630, [0, 605, 1210, 1814, 2419, 3024]),  # 4.8 -> 5; 604.8, 1209.6, 1814.4, ...
        (4032, 630, [0, 672, 1344, 2016, 2688, 3360, 4032]),  # 6.4 -> 6
    ],
)
def test_tile_bounds_by_hand(length, size, expected):
    assert tile_bounds(length, size).tolist() == expected


@pytest.mark.parametrize("length", [1, 2, 3, 17, 629, 630, 631, 945, 1000, 1575])
def test_every_pixel_in_exactly_one_tile(length):
    b = tile_bounds(length, 630)
    assert b[0] == 0 and b[-1] == length and np.all(np.diff(b) > 0)
    assert len(b) - 1 == max(1, round(length / 630))
    owner = np.searchsorted(b, np.arange(length), side="right") - 1
    assert np.bincount(owner).sum() == length and owner.min() == 0 and owner.max() == len(b) - 2


@pytest.mark.parametrize("size", [0, 1, -5, 2.5, True])
def test_bad_tile_size(size):
    with pytest.raises(ValueError, match="tile size"):
        tile_bounds(100, size)


def test_tile_values_equal_the_official_recipe_on_the_cropped_pixels():
    gray = textured(np.random.default_rng(3), 75, 101)
    values = tile_complexities(gray, 32)
    ys, xs = [0, 38, 75], [0, 34, 67, 101]  # 75/32 = 2.34 -> 2, 101/32 = 3.16 -> 3
    assert values.shape == (2, 3)
    for r in range(2):
        for c in range(3):
            crop = np.ascontiguousarray(gray[ys[r] : ys[r + 1], xs[c] : xs[c + 1]])
            blurred = cv2.GaussianBlur(crop, (3, 3), 1.0)
            assert values[r, c] == pytest.approx(official_delentropy(blurred), abs=1e-9)
    # Not the whole image's blur cropped: tiles see their own borders.
    whole = cv2.GaussianBlur(gray, (3, 3), 1.0)
    assert values[0, 0] != pytest.approx(official_delentropy(whole[:38, :34].copy()), abs=1e-9)


def test_grid_of_an_image():
    ys, xs = tile_grid((3024, 4032, 3), 630)
    assert (len(ys) - 1, len(xs) - 1) == (5, 6)


@pytest.fixture
def images(tmp_path):
    rng = np.random.default_rng(0)
    paths = []
    for i in range(3):
        path = tmp_path / f"img{i}.png"
        cv2.imwrite(str(path), cv2.merge([textured(rng, 64, 90)] * 3))
        paths.append(str(path))
    return paths


def test_measures_from_one_decode_equal_the_official_values(images, monkeypatch):
    decodes = []
    real = collection_module.read_gray_views
    monkeypatch.setattr(
        collection_module, "read_gray_views", lambda p, stored: decodes.append(p) or real(p, stored)
    )
    results, errors = compute_measures(
        images, ["delent", "glcment", "pixent"], tile_size=32, cache=False
    )
    assert errors == [] and sorted(decodes) == sorted(images)  # each image once
    for path, result in zip(images, results, strict=True):
        assert (result.height, result.width) == (64, 90)
        for metric in ("delent", "glcment", "pixent"):
            expected = official_image_complexity(path, metric)
            assert result.values[metric] == pytest.approx(expected, abs=1e-9)
        gray = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        assert result.tiles.shape == (2, 3)  # 64/32 = 2, 90/32 = 2.8 -> 3 (bounds 0, 30, 60, 90)
        assert result.tiles[1, 1] == pytest.approx(
            official_delentropy(cv2.GaussianBlur(np.ascontiguousarray(gray[32:, 30:60]),
                                                 (3, 3), 1.0)), abs=1e-9)  # fmt: skip
    # The reference functions themselves agree on the values (official recipe, one metric each).
    gray = cv2.GaussianBlur(cv2.imread(images[0], cv2.IMREAD_GRAYSCALE), (3, 3), 1.0)
    assert results[0].values["glcment"] == pytest.approx(official_glcm_entropy(gray), abs=1e-9)
    assert results[0].values["pixent"] == pytest.approx(official_pixel_entropy(gray), abs=1e-9)


def test_cached_measures_are_not_decoded_again_but_tiles_are(images, tmp_path, monkeypatch):
    from claravid.dsp import ComplexityCache

    cache = ComplexityCache(tmp_path / "dsp.sqlite3")
    first, _ = compute_complexities(images, "delent", cache=cache)
    decodes = []
    real = collection_module.read_gray_views
    monkeypatch.setattr(
        collection_module, "read_gray_views", lambda p, stored: decodes.append(p) or real(p, stored)
    )
    again, _ = compute_measures(images, ["delent"], cache=cache)
    assert decodes == [] and [r.values["delent"] for r in again] == [r.complexity for r in first]
    tiled, _ = compute_measures(images, ["delent"], tile_size=32, cache=cache)
    assert sorted(decodes) == sorted(images) and all(r.tiles is not None for r in tiled)
    more, _ = compute_measures(images, ["delent", "pixent"], cache=cache)
    assert [r.values["delent"] for r in more] == [r.complexity for r in first]


def test_an_unreadable_image_is_an_error_for_every_measure(images, tmp_path):
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"\x89PNG\r\n\x1a\n" + b"0" * 20)
    results, errors = compute_measures([images[0], str(broken)], ["delent", "pixent"], cache=False)
    assert [r.image_path for r in results] == [images[0]]
    assert [e.image_path for e in errors] == [str(broken)] and errors[0].error


def test_tiles_follow_the_stored_pixels_of_an_exif_rotated_photo(tmp_path):
    """The labels (and the model) see a photo's pixels as stored; the official whole-image value
    reads it as cv2.imread does, rotated by its EXIF orientation. Tiles must line up with the
    labels: they are cut from the stored pixels."""
    from PIL import Image

    stored = textured(np.random.default_rng(5), 64, 90)
    path = tmp_path / "photo.jpg"
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 90° clockwise to display
    Image.fromarray(stored).save(path, exif=exif, quality=95)
    as_stored = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
    assert as_stored.shape == (64, 90)
    (result,), errors = compute_measures([path], ["delent"], tile_size=32, cache=False)
    assert errors == []
    assert (result.height, result.width) == (90, 64)  # the official read is rotated
    assert result.values["delent"] == pytest.approx(official_image_complexity(path), abs=1e-9)
    assert result.tiles.shape == (2, 3)  # 64/32 = 2 rows, 90/32 = 2.8 -> 3 columns (0, 30, 60, 90)
    crop = cv2.GaussianBlur(np.ascontiguousarray(as_stored[:32, 30:60]), (3, 3), 1.0)
    assert result.tiles[0, 1] == pytest.approx(official_delentropy(crop), abs=1e-9)


def test_a_tile_too_small_to_measure_is_refused():
    # Before: --tiles 2 measured every tile as delentropy -0.0 and took 1.1 GB.
    gray = textured(np.random.default_rng(3), 75, 101)
    for size in (2, 31):
        with pytest.raises(ValueError, match=r"at least 32 pixels.*got " + str(size)):
            tile_complexities(gray, size)
    assert tile_complexities(gray, 32).shape == (2, 3)
    big = np.zeros((3024, 4032), np.uint8)
    with pytest.raises(ValueError, match=r"cut an image of 4032x3024 into 11844 tiles, more "
                       r"than 1024: use tiles of 110 px or more"):  # fmt: skip
        tile_complexities(big, 32)


def test_a_flat_tile_is_zero_not_minus_zero():
    values = tile_complexities(np.full((64, 64), 7, np.uint8), 32)
    assert values.tolist() == [[0.0, 0.0], [0.0, 0.0]]
    assert not np.signbit(values).any()
