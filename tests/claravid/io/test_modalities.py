"""Every modality decodes to known values, and to exactly what the official SDK returns.

The SDK decodes with PIL; ``sdk_*`` below restate its formulas (docs/data.md, "Modalities") on PIL
arrays so our OpenCV path is compared value for value.
"""

import json
import struct

import cv2
import numpy as np
import pytest
from PIL import Image

from claravid.infra.errors import CorruptFileError, UnsupportedFileError
from claravid.io import modalities
from claravid.io.layout import INTRINSICS
from tests.helpers.files import png_claiming


def sdk_depth(path):
    rgb = np.array(Image.open(path).convert("RGB")).astype(np.float32)
    return (rgb[..., 0] + rgb[..., 1] * 256 + rgb[..., 2] * 256 * 256) / (256**3 - 1) * 1000.0


def sdk_pan_seg(path):
    rgb = np.array(Image.open(path).convert("RGB")).astype(np.int32)
    out = np.zeros((*rgb.shape[:2], 2), dtype=np.int32)
    out[..., 0] = rgb[..., 2] * 256 + rgb[..., 1]
    out[..., 1] = rgb[..., 0]
    return out


@pytest.fixture
def rng():
    return np.random.default_rng(7)


def test_depth_known_values_and_bit_exact_with_sdk(tmp_path, rng):
    rgb = rng.integers(0, 256, (9, 13, 3), dtype=np.uint8)
    rgb[0, 0] = (0, 0, 0)
    rgb[0, 1] = (255, 255, 255)
    rgb[0, 2] = (1, 2, 3)
    Image.fromarray(rgb).save(tmp_path / "d.png")
    depth = modalities.read_depth(tmp_path / "d.png")
    assert depth.dtype == np.float32 and depth.shape == (9, 13)
    assert depth[0, 0] == 0.0
    assert depth[0, 1] == pytest.approx(1000.0)
    assert depth[0, 2] == pytest.approx((1 + 2 * 256 + 3 * 65536) / (2**24 - 1) * 1000, rel=1e-6)
    np.testing.assert_array_equal(depth, sdk_depth(tmp_path / "d.png"))


def test_depth_round_trip(tmp_path, rng):
    metres = rng.uniform(0, 1000, (6, 5))
    modalities.write_depth(tmp_path / "d.png", metres)
    np.testing.assert_allclose(modalities.read_depth(tmp_path / "d.png"), metres, atol=1e-3)


def test_pan_seg_channels_and_sdk_equality(tmp_path, rng):
    semantic = rng.choice([0, 3, 9, 22, 255], (7, 8)).astype(np.uint8)
    instance = rng.integers(0, 70000 // 2, (7, 8))
    instance[0, 0] = 0x1234
    modalities.write_pan_seg(tmp_path / "p.png", semantic, instance)
    pan = modalities.read_pan_seg(tmp_path / "p.png")
    assert pan.dtype == np.int32 and pan.shape == (7, 8, 2)
    assert pan[0, 0, 0] == 0x1234
    np.testing.assert_array_equal(pan[..., 0], instance)
    np.testing.assert_array_equal(pan[..., 1], semantic)
    np.testing.assert_array_equal(pan, sdk_pan_seg(tmp_path / "p.png"))
    np.testing.assert_array_equal(modalities.read_semantic(tmp_path / "p.png"), semantic)


def test_rgb_png_exact_and_jpeg_close_to_pil(tmp_path, rng):
    rgb = rng.integers(0, 256, (16, 24, 3), dtype=np.uint8)
    Image.fromarray(rgb).save(tmp_path / "x.png")
    got = modalities.read_rgb(tmp_path / "x.png")
    np.testing.assert_array_equal(got, rgb)  # RGB order, not BGR
    smooth = np.repeat(np.linspace(0, 255, 64, dtype=np.uint8)[None, :, None], 48, 0)
    smooth = np.concatenate([smooth, smooth[:, ::-1], np.full_like(smooth, 90)], -1)
    modalities.write_rgb(tmp_path / "x.jpg", smooth)
    ours = modalities.read_rgb(tmp_path / "x.jpg").astype(int)
    pil = np.array(Image.open(tmp_path / "x.jpg").convert("RGB")).astype(int)
    assert np.abs(ours - pil).max() <= 2  # decoder rounding only
    assert np.abs(ours - smooth).mean() < 3


def test_seg_color_is_rgb_order(tmp_path):
    colors = np.zeros((4, 4, 3), np.uint8)
    colors[..., 2] = 142  # Vehicles (0, 0, 142)
    modalities.write_seg_color(tmp_path / "s.png", colors)
    assert modalities.read_seg_color(tmp_path / "s.png")[0, 0].tolist() == [0, 0, 142]


def test_dynamic_mask_grey_and_colour_like_pil(tmp_path, rng):
    mask = np.where(rng.random((5, 6)) < 0.3, 0, 255).astype(np.uint8)
    modalities.write_dynamic_mask(tmp_path / "m.png", mask)
    got = modalities.read_dynamic_mask(tmp_path / "m.png")
    assert got.dtype == np.uint8 and got.shape == (5, 6)
    np.testing.assert_array_equal(got, mask)
    colour = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    Image.fromarray(colour).save(tmp_path / "c.png")
    pil = np.array(Image.open(tmp_path / "c.png").convert("L"))
    np.testing.assert_array_equal(modalities.read_dynamic_mask(tmp_path / "c.png"), pil)


def _rotation(yaw: float, pitch: float) -> np.ndarray:
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    return np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array(
        [[1, 0, 0], [0, cp, -sp], [0, sp, cp]]
    )


def test_extrinsics_and_intrinsics(tmp_path):
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = _rotation(0.3, 0.8), (187.25, -41.5, 52.125)
    modalities.write_extrinsics(tmp_path / "e.json", pose)
    got = modalities.read_extrinsics(tmp_path / "e.json")
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, pose.astype(np.float32))
    k = modalities.read_intrinsics()
    assert k.dtype == np.float32 and k[0, 0] == np.float32(2627.3023516478706)
    assert k[0, 2] == 2016 and k[1, 2] == 1512
    k[0, 0] = 0  # a copy: the constant stays intact
    assert INTRINSICS[0, 0] != 0


def test_extrinsics_wrong_shape(tmp_path):
    (tmp_path / "e.json").write_text(json.dumps([[1, 2], [3, 4]]))
    with pytest.raises(CorruptFileError, match=r"e\.json.*4×4"):
        modalities.read_extrinsics(tmp_path / "e.json")


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_truncated_image_names_the_file(tmp_path, rng, suffix):
    path = tmp_path / f"t{suffix}"
    modalities._write_image(path, rng.integers(0, 256, (64, 64, 3), dtype=np.uint8))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(CorruptFileError, match=rf"t\{suffix}.*truncated"):
        modalities.read_rgb(path)


def test_garbage_and_empty_and_missing_files(tmp_path):
    (tmp_path / "g.jpg").write_bytes(b"not an image at all")
    with pytest.raises(CorruptFileError, match=r"g\.jpg.*could not decode"):
        modalities.read_rgb(tmp_path / "g.jpg")
    (tmp_path / "e.jpg").write_bytes(b"")
    with pytest.raises(CorruptFileError, match=r"e\.jpg.*empty"):
        modalities.read_rgb(tmp_path / "e.jpg")
    with pytest.raises(FileNotFoundError, match=r"nope\.png"):
        modalities.read_depth(tmp_path / "nope.png")


def test_garbage_label_files_name_what_they_are(tmp_path):
    (tmp_path / "g.png").write_bytes(b"not an image at all")
    with pytest.raises(CorruptFileError, match=r"g\.png: expected an 8-bit RGB PNG.*no PNG data"):
        modalities.read_pan_seg(tmp_path / "g.png")


def _labels(rng):
    return rng.integers(0, 23, (12, 16), dtype=np.uint8)


def _write_16bit(path, s):
    cv2.imwrite(str(path), np.dstack([s, s, s]).astype(np.uint16) * 257)


def _write_jpeg_bytes(path, s):
    path.write_bytes(cv2.imencode(".jpg", np.dstack([s] * 3))[1].tobytes())


@pytest.mark.parametrize(
    ("write", "found"),
    [
        # 16-bit: OpenCV would scale every class id to 0 (all Building) without the check.
        (_write_16bit, r"a 16-bit RGB PNG"),
        (lambda p, s: cv2.imwrite(str(p), s), r"an 8-bit grey PNG"),
        (lambda p, s: Image.fromarray(s, "P").save(p), r"an? \d-bit palette PNG"),
        (_write_jpeg_bytes, r"JPEG data"),
    ],
    ids=["16bit", "grey", "palette", "jpeg"],
)
def test_panoptic_png_of_the_wrong_kind_is_an_error(tmp_path, rng, write, found):
    path = tmp_path / "000001.png"
    write(path, _labels(rng))
    expected = rf"000001\.png: expected an 8-bit RGB PNG \(R class id.*found {found}"
    for reader in (modalities.read_pan_seg, modalities.read_semantic):
        with pytest.raises(CorruptFileError, match=expected):
            reader(path)
    with pytest.raises(CorruptFileError, match=r"000001\.png: expected an 8-bit RGB PNG \(24-bit"):
        modalities.read_depth(path)


def test_rgba_panoptic_reads_like_rgb(tmp_path, rng):
    semantic, instance = _labels(rng), rng.integers(0, 600, (12, 16))
    modalities.write_pan_seg(tmp_path / "rgb.png", semantic, instance)
    bgr = cv2.imread(str(tmp_path / "rgb.png"), cv2.IMREAD_COLOR)
    cv2.imwrite(str(tmp_path / "rgba.png"), np.dstack([bgr, np.full((12, 16), 255, np.uint8)]))
    pan = modalities.read_pan_seg(tmp_path / "rgba.png")
    np.testing.assert_array_equal(pan[..., 1], semantic)
    np.testing.assert_array_equal(pan[..., 0], instance)


def test_dynamic_mask_must_be_an_8bit_png(tmp_path):
    mask = np.full((8, 8), 255, np.uint8)
    mask[2:4] = 0
    cv2.imwrite(str(tmp_path / "d16.png"), mask.astype(np.uint16) * 257)
    with pytest.raises(CorruptFileError, match=r"d16\.png: expected an 8-bit PNG mask.*16-bit"):
        modalities.read_dynamic_mask(tmp_path / "d16.png")
    (tmp_path / "dj.png").write_bytes(cv2.imencode(".jpg", mask)[1].tobytes())
    with pytest.raises(CorruptFileError, match=r"dj\.png: expected an 8-bit PNG mask.*JPEG data"):
        modalities.read_dynamic_mask(tmp_path / "dj.png")


_SHEAR = np.eye(4)
_SHEAR[0, 1] = 0.05
_PROJECTIVE = np.eye(4)
_PROJECTIVE[3] = (0, 0, 1, 0)  # moves the pose's third row into its last one


@pytest.mark.parametrize(
    ("change", "match"),
    [
        (np.diag([1.01, 1.01, 1.01, 1]), r"not orthonormal .*column lengths \[1\.01, 1\.01"),
        (np.diag([1, -1, 1, 1]), r"reflection \(determinant −1\): one camera axis is flipped"),
        (_SHEAR, r"not orthonormal"),
        (_PROJECTIVE, r"last row is \[0\.0, -?0\.\d+, 0\.\d+, 55\.0\], not \[0, 0, 0, 1\]"),
    ],
    ids=["scale", "mirror", "shear", "projective"],
)
def test_extrinsics_that_are_not_a_rigid_pose_are_refused_naming_the_file(tmp_path, change, match):
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = _rotation(-1.2, 0.4), (10.0, 20.0, 55.0)
    modalities.read_extrinsics(_written(tmp_path / "ok.json", pose))  # rigid: fine
    with pytest.raises(CorruptFileError, match=r"bad\.json: not a camera pose: .*" + match):
        modalities.read_extrinsics(_written(tmp_path / "bad.json", change @ pose))


def _written(path, pose):
    modalities.write_extrinsics(path, pose)
    return path


def test_rounding_in_a_pose_file_is_accepted(tmp_path):
    """Poses written with 6 decimals, as JSON exporters often do, are still rigid enough."""
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = _rotation(2.0, 0.9), (1.0, 2.0, 3.0)
    (tmp_path / "e.json").write_text(json.dumps(np.round(pose, 6).tolist()))
    np.testing.assert_allclose(modalities.read_extrinsics(tmp_path / "e.json"), pose, atol=1e-6)


@pytest.mark.parametrize("bad", ["NaN", "Infinity", "1e300"])
def test_extrinsics_with_nan_or_inf_name_the_file(tmp_path, bad):
    rows = [[1, 0, 0, 5], [0, 1, 0, 6], [0, 0, 1, 7], [0, 0, 0, 1]]
    text = json.dumps(rows).replace("5", bad, 1)
    (tmp_path / "pose.json").write_text(text)
    with pytest.raises(CorruptFileError, match=r"pose\.json: the 4×4 pose holds NaN or infinite"):
        modalities.read_extrinsics(tmp_path / "pose.json")


# ------------------------------------------------------------------------------------------
# Headers that claim too much (issue 24): refused before decoding, naming the file and limit.


LABEL_READERS = {
    "pan_seg": (modalities.read_pan_seg, 2),
    "semantic": (modalities.read_semantic, 2),
    "depth": (modalities.read_depth, 2),
    "dynamic_mask": (modalities.read_dynamic_mask, 0),
    "seg_color": (modalities.read_seg_color, 2),
}


@pytest.mark.parametrize("reader", LABEL_READERS)
def test_a_png_claiming_more_than_2_30_pixels_is_refused_by_every_reader(tmp_path, reader):
    # OpenCV raised cv2.error here, which nothing mapped: a traceback from claravid-cache.
    read, color_type = LABEL_READERS[reader]
    path = tmp_path / "big.png"
    path.write_bytes(png_claiming(40000, 30000, color_type))
    with pytest.raises(UnsupportedFileError) as caught:
        read(path)
    assert str(caught.value) == (
        f"cannot read {path}: its header claims 40000×30000 = 1,200,000,000 pixels, more than "
        "the 1,073,741,824 (2^30) the readers decode; a corrupt header, or an image to cut into "
        "tiles first"
    )
    path.write_bytes(png_claiming(32768, 32768, color_type))  # 2^30 exactly: not too large
    with pytest.raises(CorruptFileError, match="fewer than the") as caught:
        read(path)
    assert not isinstance(caught.value, UnsupportedFileError)


def test_a_png_too_short_for_its_size_is_refused_before_decoding(tmp_path):
    # 9000×7000 RGB is 189 MB of pixels; deflate shrinks at most 1032 times: at least 183,139 B.
    path = tmp_path / "lie.png"
    path.write_bytes(png_claiming(9000, 7000))
    with pytest.raises(
        CorruptFileError,
        match=r"lie\.png: its header claims 9000×7000 pixels, "
        r"but the file holds 69 bytes, fewer than the 183,139 any PNG",
    ):
        modalities.read_pan_seg(path)


def test_opencv_errors_of_other_formats_name_the_file(tmp_path):
    # A BMP header claiming 40000×40000 pixels: no header of ours, OpenCV raises cv2.error.
    dib = struct.pack("<IiiHHIIiiII", 40, 40000, 40000, 1, 24, 0, 0, 2835, 2835, 0, 0)
    path = tmp_path / "big.bmp"
    path.write_bytes(b"BM" + struct.pack("<IHHI", 118, 0, 0, 54) + dib + bytes(64))
    with pytest.raises(CorruptFileError, match=r"big\.bmp: OpenCV refused it \(.*MAX_IMAGE_PIXELS"):
        modalities.read_rgb(path)
    with pytest.raises(CorruptFileError, match=r"big\.bmp: OpenCV refused it"):
        modalities.decode_bytes(np.fromfile(path, np.uint8), path, cv2.IMREAD_COLOR)
