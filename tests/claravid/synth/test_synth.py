"""The synthetic ClaraVid generator: layout, per-frame consistency, determinism, CLI, errors."""

from __future__ import annotations

import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest

from claravid.io import modalities
from claravid.io.layout import (
    ALTITUDES,
    CLASS_BY_NAME,
    CLASSES,
    DEPTH_MAX_M,
    DIRECTIONS,
    INTRINSICS,
    MISSIONS,
    MODALITIES,
    UNLABELED_ID,
    viewpoint_folder,
)
from claravid.synth import MARKER, main, synthesize
from tests.helpers.files import sha256

TINY = (64, 48)
INSTANCE_CLASSES = {c.id for c in CLASSES if c.has_instances}
DYNAMIC_CLASSES = {CLASS_BY_NAME["Vehicles"].id, CLASS_BY_NAME["Pedestrian"].id}
GROUND_CLASSES = {CLASS_BY_NAME[n].id for n in ("Road", "RoadLine", "SideWalk", "Terrain", "Water")}
HEIGHTS = {"low": (45, 55), "mid": (55, 65), "high": (65, 75)}
PITCH = {"low": 45, "mid": 55, "high": 90}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "tiny"
    return synthesize(
        out, seed=3, frames_per_viewpoint=2, size=TINY, missions=["rural_1", "urban_high_1"]
    )


@pytest.fixture(scope="module")
def urban(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("synth") / "urban"
    return synthesize(
        out, seed=1, frames_per_viewpoint=3, size=(160, 120), missions=["urban_high_1"]
    )


def _frames(root: Path):
    """(mission folder, altitude, direction, stem) of every frame under ``root``."""
    for mission in sorted(p.name for p in root.iterdir() if p.is_dir()):
        for alt, d in itertools.product(ALTITUDES, DIRECTIONS):
            folder = root / mission / "extrinsics" / viewpoint_folder(alt, d)
            for f in sorted(folder.glob("*.json")):
                yield mission, alt, d, f.stem


def _read(root: Path, mission: str, alt: str, d: str, stem: str) -> dict[str, np.ndarray]:
    out = {}
    for key, modality in MODALITIES.items():
        if modality.folder is None:
            continue
        path = (
            root / mission / modality.folder / viewpoint_folder(alt, d) / f"{stem}.{modality.ext}"
        )
        out[key] = modalities.READERS[key](path)
    return out


def test_tree_layout_and_stems(tiny):
    expected = {
        f"{MISSIONS[m]}/{mod.folder}/{viewpoint_folder(a, d)}/{i:06d}.{mod.ext}"
        for m in ("rural_1", "urban_high_1")
        for mod in MODALITIES.values()
        if mod.folder
        for a, d in itertools.product(ALTITUDES, DIRECTIONS)
        for i in range(2)
    } | {MARKER}
    found = {str(p.relative_to(tiny)) for p in tiny.rglob("*") if p.is_file()}
    assert found == expected
    assert len(expected) == 2 * 6 * 6 * 2 + 1


def test_every_frame_is_consistent(tiny):
    palette = np.zeros((256, 3), np.uint8)
    for c in CLASSES:
        palette[c.id] = c.color
    # Pixel centres at integer + 0.5; camera axes x right, y up, looking along -z (OpenGL).
    fx, fy = INTRINSICS[0, 0] * TINY[0] / 4032, INTRINSICS[1, 1] * TINY[1] / 3024
    u, v = np.meshgrid(np.arange(TINY[0]) + 0.5, np.arange(TINY[1]) + 0.5)
    rays = np.stack([(u - TINY[0] / 2) / fx, -(v - TINY[1] / 2) / fy, -np.ones(u.shape)], -1)
    instance_class: dict[tuple[str, int], int] = {}
    frames = list(_frames(tiny))
    assert len(frames) == 2 * 6 * 2  # missions x viewpoints x frames: the loop below checks all
    for mission, alt, d, stem in frames:
        f = _read(tiny, mission, alt, d, stem)
        instance, semantic = f["pan_seg"][..., 0], f["pan_seg"][..., 1]
        assert f["rgb"].shape == (TINY[1], TINY[0], 3)
        assert set(np.unique(semantic)) <= {c.id for c in CLASSES}
        np.testing.assert_array_equal(f["seg_color"], palette[semantic])
        has_instance_class = np.isin(semantic, list(INSTANCE_CLASSES))
        np.testing.assert_array_equal(instance > 0, has_instance_class)
        for i in np.unique(instance[instance > 0]):  # one class per object, in every frame
            assert len(np.unique(semantic[instance == i])) == 1
            assert (
                instance_class.setdefault((mission, i), semantic[instance == i][0])
                == semantic[instance == i][0]
            )
        assert set(np.unique(f["dynamic_mask"])) <= {0, 255}
        assert set(np.unique(semantic[f["dynamic_mask"] == 0])) <= DYNAMIC_CLASSES
        depth, pose = f["depth"], f["extrinsics"].astype(np.float64)
        assert depth.min() > 0 and depth.max() <= DEPTH_MAX_M
        # Camera: a rotation, at the altitude's height, pitched as the folder name says: the
        # optical axis (-z, OpenGL axes) points down, the image's up (+y) points up or ahead.
        rot, centre = pose[:3, :3], pose[:3, 3]
        np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-6)
        assert np.linalg.det(rot) == pytest.approx(1.0, abs=1e-6)
        assert HEIGHTS[alt][0] <= centre[2] <= HEIGHTS[alt][1]
        assert np.degrees(np.arcsin(-(-rot[:, 2])[2])) == pytest.approx(PITCH[alt], abs=1e-3)
        assert rot[2, 1] >= -1e-9  # camera y has no downward world component
        assert abs(rot[2, 0]) < 1e-9  # no roll: camera x stays horizontal
        # Ground pixels: depth is where the pixel's ray meets the plane z = 0.
        expected = centre[2] / -(rays @ rot[2])
        ground = np.isin(semantic, list(GROUND_CLASSES))
        assert ground.mean() > 0.2
        np.testing.assert_allclose(depth[ground], expected[ground], rtol=1e-4)
        # Objects stand on the ground: never farther than the ground behind them.
        assert np.all(depth <= expected * (1 + 1e-4))


def test_dynamic_objects_are_a_subset_of_vehicles_and_pedestrians(urban):
    dynamic = vehicles = 0
    for frame in _frames(urban):
        f = _read(urban, *frame)
        semantic = f["pan_seg"][..., 1]
        moving = f["dynamic_mask"] == 0
        assert set(np.unique(semantic[moving])) <= DYNAMIC_CLASSES
        # Whole objects move: an instance is either all dynamic or all static.
        instance = f["pan_seg"][..., 0]
        for i in np.unique(instance[moving]):
            assert moving[instance == i].all()
        dynamic += moving.sum()
        vehicles += np.isin(semantic, list(DYNAMIC_CLASSES)).sum()
    assert 0 < dynamic < vehicles  # some move, some are parked


def test_depth_grows_towards_the_top_of_oblique_images(urban):
    for mission, alt, d, stem in _frames(urban):
        depth = _read(urban, mission, alt, d, stem)["depth"]
        top, bottom = np.median(depth[:10]), np.median(depth[-10:])
        if alt == "high":  # nadir: the ground is as far at the top as at the bottom
            assert top == pytest.approx(bottom, rel=0.25)
        else:  # flat ground: 3.7x at 45 degrees; the towers in front of the far ground: less
            assert top > 1.5 * bottom


def test_flight_grid_spreads_positions(tmp_path):
    root = synthesize(
        tmp_path, frames_per_viewpoint=16, size=(16, 12), missions=["rural_1"], altitude=["high"]
    )
    for d, along in (("h", 0), ("v", 1)):
        folder = root / MISSIONS["rural_1"] / "extrinsics" / viewpoint_folder("high", d)
        xy = np.array([modalities.read_extrinsics(p)[:2, 3] for p in sorted(folder.glob("*.json"))])
        assert np.ptp(xy[:, 0]) > 100 and np.ptp(xy[:, 1]) > 100
        steps = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        # Consecutive frames are neighbours along a pass: mostly short steps along one axis.
        assert np.median(steps) < 60
        first_pass = xy[: len(xy) // 2]  # 16 frames: two passes of 8
        assert np.ptp(first_pass[:, along]) > np.ptp(first_pass[:, 1 - along])


def test_same_seed_same_bytes_other_seed_other_scene(tmp_path, tiny):
    again = synthesize(
        tmp_path / "again",
        seed=3,
        frames_per_viewpoint=2,
        size=TINY,
        missions=["urban_high_1", "rural_1"],
    )
    files = sorted(p.relative_to(tiny) for p in tiny.rglob("*") if p.is_file())
    for rel in files:
        assert sha256(tiny / rel) == sha256(again / rel), rel
    other = synthesize(
        tmp_path / "other",
        seed=4,
        frames_per_viewpoint=2,
        size=TINY,
        missions=["rural_1"],
        altitude=["low"],
        direction=["h"],
    )
    rel = Path(MISSIONS["rural_1"], "panoptic_seg", "45deg_low_h", "000000.png")
    assert (tiny / rel).read_bytes() != (other / rel).read_bytes()


def test_workers_write_the_same_bytes(tmp_path, tiny):
    """``--workers 2``: the viewpoints render in worker processes, the files are the same."""
    assert main(["-o", str(tmp_path / "w"), "--seed", "3", "--frames-per-viewpoint", "2",
                 "--size", "64x48", "--missions", "rural_1,urban_high_1", "--workers", "2",
                 "--no-progress"]) == 0  # fmt: skip
    files = sorted(p.relative_to(tiny) for p in tiny.rglob("*") if p.is_file())
    assert files == sorted(p.relative_to(tmp_path / "w") for p in (tmp_path / "w").rglob("*")
                           if p.is_file())  # fmt: skip
    for rel in files:
        assert sha256(tiny / rel) == sha256(tmp_path / "w" / rel), rel


def test_a_subset_renders_the_same_frames(tmp_path, tiny):
    part = synthesize(
        tmp_path,
        seed=3,
        frames_per_viewpoint=2,
        size=TINY,
        missions=["008_urban_dense_1"],
        altitude=["mid"],
        direction=["v"],
    )
    for p in part.rglob("*"):
        if p.is_file():
            assert sha256(p) == sha256(tiny / p.relative_to(part)), p


def _gradient(root: Path, mission: str) -> float:
    values = []
    for f in (root / MISSIONS[mission] / "left_rgb").rglob("*.jpg"):
        grey = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE).astype(np.float32)
        gx, gy = cv2.Sobel(grey, cv2.CV_32F, 1, 0), cv2.Sobel(grey, cv2.CV_32F, 0, 1)
        values.append(np.hypot(gx, gy).mean())
    return float(np.mean(values))


def test_missions_differ_in_complexity(tmp_path, urban):
    root = synthesize(
        tmp_path, seed=1, frames_per_viewpoint=3, size=(160, 120), missions=["rural_1", "nature_1"]
    )
    dense = _gradient(urban, "urban_high_1")
    assert dense > 1.4 * _gradient(root, "rural_1")
    assert dense > 1.4 * _gradient(root, "nature_1")


def test_aliases_and_folder_names_select_missions(tmp_path):
    root = synthesize(
        tmp_path,
        frames_per_viewpoint=1,
        size=(16, 12),
        altitude=["low"],
        direction=["h"],
        missions=["urban_high", "003_urban_1"],
    )
    assert sorted(p.name for p in root.iterdir()) == [MARKER, "003_urban_1", "008_urban_dense_1"]


def test_cli_end_to_end(tmp_path, capsys):
    out = tmp_path / "cli"
    code = main(
        [
            "--output",
            str(out),
            "--seed",
            "2",
            "--frames-per-viewpoint",
            "1",
            "--size",
            "32x24",
            "--missions",
            "nature_1",
            "--altitude",
            "mid",
            "--direction",
            "v",
            "--no-progress",
        ]
    )
    assert code == 0
    assert capsys.readouterr().out.strip() == str(out)
    rgb = modalities.read_rgb(out / "007_nature_1" / "left_rgb" / "55deg_mid_v" / "000000.jpg")
    assert rgb.shape == (24, 32, 3)
    files = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    assert len(files) == 7 and files[0] == Path(MARKER)  # 6 modalities + the marker


def test_cli_output_flag_and_square_size(tmp_path, capsys):
    out = tmp_path / "o"
    argv = ["--frames-per-viewpoint", "1", "--missions", "nature_1", "--altitude", "mid",
            "--direction", "v", "--no-progress"]  # fmt: skip
    assert main(["-o", str(out), "--size", "16", *argv]) == 0  # N: a 16 x 16 square
    captured = capsys.readouterr()
    assert captured.out.strip() == str(out) and captured.err == ""  # no progress bar
    rgb = modalities.read_rgb(out / "007_nature_1" / "left_rgb" / "55deg_mid_v" / "000000.jpg")
    assert rgb.shape == (16, 16, 3)
    for missing in ([*argv], [str(out), *argv]):  # -o is required; OUT alone is no spelling
        with pytest.raises(SystemExit) as info:
            main(missing)
        assert info.value.code == 2
        _one_error(capsys, "the following arguments are required: -o/--output")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"size": (0, 48)}, "size must be positive"),
        ({"size": (64,)}, "width, height"),
        ({"size": (64.0, 48)}, "width, height"),
        ({"frames_per_viewpoint": 0}, "frames_per_viewpoint must be a positive integer"),
        ({"missions": ["mars_1"]}, "unknown ClaraVid mission 'mars_1'"),
        ({"missions": []}, "missions must name at least one"),
        ({"altitude": ["sky"]}, "unknown altitude 'sky'; valid: low, mid, high"),
        ({"altitude": []}, "altitude must name at least one of low, mid, high"),
        ({"direction": "d"}, "unknown direction 'd'; valid: h, v"),
        ({"seed": -1}, "seed must be a non-negative integer"),
    ],
)
def test_bad_arguments_raise(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        synthesize(tmp_path, **{"size": (16, 12), **kwargs})
    assert not any(tmp_path.iterdir())  # nothing written before the check


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--size", "64x"], "expected WxH (width x height"),
        (["--size", "64x48x3"], "expected WxH"),
        (["--size", "0x48"], "must be positive"),
        (["--frames-per-viewpoint", "0"], "expected a positive integer"),
        (["--seed", "-1"], "expected an integer >= 0"),
        (["--altitudes", "low"], "unrecognized arguments"),  # the old plural flag is gone
        (["--missions", "rural_1", "urban_1"], "unrecognized arguments: urban_1"),  # commas
    ],
)
def test_cli_rejects_bad_arguments(tmp_path, capsys, args, match):
    with pytest.raises(SystemExit) as exit_info:
        main(["-o", str(tmp_path / "x"), "--no-progress", *args])
    assert exit_info.value.code == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    assert UNLABELED_ID == 255


def _one_error(capsys, match):
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("claravid-synth: error:")]
    assert len(lines) == 1 and match in lines[0], err
    assert "Traceback" not in err


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert main(["-o", str(tmp_path / "x"), "--no-progress", "--missions", "mars_1"]) == 2
    _one_error(capsys, "unknown ClaraVid mission 'mars_1'")
    assert main(["-o", str(tmp_path / "x"), "--no-progress", "--altitude", "low,sky"]) == 2
    _one_error(capsys, "unknown altitude 'sky'; valid: low, mid, high")
    assert main(["-o", str(tmp_path / "x"), "--no-progress", "--direction", " , "]) == 2
    _one_error(capsys, "--direction is empty; give e.g. --direction h")
    (tmp_path / "afile").write_text("x")
    assert main(["-o", str(tmp_path / "afile"), "--no-progress"]) == 2
    _one_error(capsys, "is a file; give a folder")
    assert main(["-o", str(tmp_path / "afile" / "sub"), "--no-progress"]) == 2
    _one_error(capsys, "afile")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_a_tree_it_did_not_write_is_refused(tmp_path, capsys):
    """Pointed at a real ClaraVid root, the generator must not replace a single file."""
    real = tmp_path / "claravid"
    frame = real / "003_urban_1" / "left_rgb" / "45deg_low_h" / "000000.jpg"
    frame.parent.mkdir(parents=True)
    frame.write_bytes(b"a real frame")
    args = ["--frames-per-viewpoint", "1", "--size", "16x12", "--missions", "urban_1",
            "--no-progress"]  # fmt: skip
    assert main(["-o", str(real), *args]) == 2
    _one_error(capsys, "not written by claravid-synth (no .claravid-synth)")
    with pytest.raises(FileExistsError, match="overwrite=True"):
        synthesize(real, size=(16, 12), frames_per_viewpoint=1, missions="urban_1")
    assert frame.read_bytes() == b"a real frame"
    assert sorted(p.relative_to(real) for p in real.rglob("*") if p.is_file()) == [
        frame.relative_to(real)
    ]
    # Explicitly asked: written, and from then on the tree is the generator's.
    assert main(["-o", str(real), *args, "--overwrite"]) == 0
    assert frame.read_bytes() != b"a real frame" and (real / MARKER).is_file()
    capsys.readouterr()
    # Its own output (also after an interrupted run: the marker comes first) is fine to redo.
    assert main(["-o", str(real), *args]) == 0
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["-o", str(empty), *args]) == 0  # an empty folder holds nothing to lose


def test_single_keys_select_like_the_datasets(tmp_path):
    root = synthesize(
        tmp_path, frames_per_viewpoint=1, size=(16, 12), missions="urban_1", altitude="low",
        direction="v",
    )  # fmt: skip
    rgb = sorted(p.relative_to(root) for p in root.rglob("*.jpg"))
    assert rgb == [Path("003_urban_1", "left_rgb", "45deg_low_v", "000000.jpg")]
