"""Cross-view consistency: a flat ground seen from known poses with correspondences counted by
hand, generated frames of a pass against a plain restatement, and every bad input."""

import json
import re
import shutil

import cv2
import numpy as np
import pytest
import torch

from claravid.data.index import list_frames
from claravid.eval.inputs.pairs import pair_sums, pass_pairs, read_geometry
from claravid.eval.measures.cross_view import cross_view, visible_range
from claravid.io import modalities
from claravid.io.layout import MISSIONS
from claravid.synth import synthesize

# An 8×6 pinhole camera: fx = fy = 4, principal point (4, 3) (the centre: pixel centres at +0.5).
K = np.array([[4.0, 0, 4], [0, 4.0, 3], [0, 0, 1]])
H, W = 6, 8
UNIQUE = np.arange(H * W, dtype=np.uint8).reshape(H, W)  # every pixel of t its own class
OTHER = 63  # the class of what s sees and t does not


def pose(rotation=None, centre=(0.0, 0.0, 10.0)):
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = np.eye(3) if rotation is None else rotation, centre
    return out


# Both cameras look straight down at the ground (z = 0) from 10 m: OpenGL axes, so the camera's
# y is the world's y and its z points up. A ground pixel (i, j) of t, centre (j + ½, i + ½), is
# the world point x = (j + ½ − 4)·10/4, y = −(i + ½ − 3)·10/4.
# - "shift": s is 2.5 m further along x. Then u_s = u − 1: pixel (i, j) of t is pixel (i, j − 1)
#   of s; column 0 of t falls outside s.
# - "yaw": s is turned 90° about the vertical (its x axis along the world's y). Then u_s = 7 − v
#   and v_s = u − 1: pixel (i, j) of t is pixel (j − 1, 6 − i) of s, for j in 1..6.
CASES = {
    "shift": (pose(centre=(2.5, 0.0, 10.0)), lambda i, j: (i, j - 1)),
    "yaw": (pose(np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])), lambda i, j: (j - 1, 6 - i)),
}


def by_hand(case):
    """gt_s drawn from the correspondences: s's pixel of t's pixel (i, j) holds t's class."""
    gt_s = np.full((H, W), OTHER, np.uint8)
    pairs = {}
    for i in range(H):
        for j in range(W):
            r, c = CASES[case][1](i, j)
            if 0 <= r < H and 0 <= c < W:
                gt_s[r, c] = UNIQUE[i, j]
                pairs[(i, j)] = (r, c)
    return gt_s, pairs


def flat(case, **overrides):
    gt_s, _ = by_hand(case)
    args = dict(
        depth_t=np.full((H, W), 10.0, np.float32),
        depth_s=np.full((H, W), 10.0, np.float32),
        c2w_t=pose(),
        c2w_s=CASES[case][0],
        K=K,
        pred_t=UNIQUE.copy(),
        pred_s=gt_s.copy(),
        gt_t=UNIQUE.copy(),
        gt_s=gt_s,
        dynamic_t=None,
        dynamic_s=None,
    )
    args.update(overrides)
    return cross_view(**args, num_classes=64)


@pytest.mark.parametrize("case", CASES)
def test_flat_ground_correspondences_by_hand(case):
    gt_s, pairs = by_hand(case)
    assert len(pairs) == {"shift": 42, "yaw": 36}[case]
    sums = flat(case)
    assert sums.status == "ok" and sums.reason == ""
    # Every pair of pixels found by hand is kept and carries t's own class back: any pixel
    # carried to another one would bring another class.
    assert sums.kept == sums.gt_agree == sums.agree == len(pairs)
    assert sums.pixels == H * W and sums.consistency == sums.gt_consistency == 1.0
    expected = np.zeros(64, np.int64)
    expected[[UNIQUE[p] for p in pairs]] = 1
    np.testing.assert_array_equal(sums.gt_intersection, expected)
    np.testing.assert_array_equal(sums.gt_union, expected)

    # Predictions of s wrong at three pixels seen from t: three kept pixels disagree.
    (a, b, c) = list(pairs.items())[:3]
    pred_s = gt_s.copy()
    pred_s[a[1]], pred_s[b[1]], pred_s[c[1]] = UNIQUE[b[0]], OTHER, OTHER
    sums = flat(case, pred_s=pred_s)
    assert sums.kept == len(pairs) and sums.agree == len(pairs) - 3
    assert sums.gt_agree == len(pairs)  # the ground truth is untouched
    # Class of a: t says it, s now says b's class there -> a: intersection 0, union 1;
    # b: t at b and s at a both say b -> union 2 (t's pixel b, carried s at a), intersection 0.
    assert sums.intersection[UNIQUE[a[0]]] == 0 and sums.union[UNIQUE[a[0]]] == 1
    assert sums.intersection[UNIQUE[b[0]]] == 0 and sums.union[UNIQUE[b[0]]] == 2
    assert sums.union[OTHER] == 2 and sums.intersection[OTHER] == 0


def test_what_is_not_kept():
    """Depth 0 or 1000 m in t, a pixel of s hidden behind something nearer, a moving pixel in
    either frame, an ignored pixel in either: each loses exactly its own pair."""
    gt_s, pairs = by_hand("shift")  # (i, j) of t is (i, j - 1) of s
    depth_t = np.full((H, W), 10.0, np.float32)
    depth_t[0, 3], depth_t[0, 4] = 0.0, 1000.0  # no hit, sky
    depth_s = np.full((H, W), 10.0, np.float32)
    depth_s[1, 2] = 9.8  # something 0.2 m above the ground in s: t's (1, 3) is hidden (2% > 1%)
    depth_s[1, 4] = 9.95  # 0.5%: within the tolerance, (1, 5) stays
    depth_s[1, 5] = 0.0  # s has no depth there: (1, 6) is lost
    dynamic_t = np.full((H, W), 255, np.uint8)
    dynamic_t[2, 2] = 0  # moving in t
    dynamic_s = np.full((H, W), 255, np.uint8)
    dynamic_s[2, 5] = 0  # moving in s: t's (2, 6)
    gt_t = UNIQUE.copy()
    gt_t[3, 3] = 255  # ignored in t
    gt_s[3, 5] = 255  # ignored in s: t's (3, 6)
    sums = flat("shift", depth_t=depth_t, depth_s=depth_s, dynamic_t=dynamic_t,
                dynamic_s=dynamic_s, gt_t=gt_t, gt_s=gt_s, pred_s=gt_s)  # fmt: skip
    assert sums.kept == len(pairs) - 8
    assert sums.gt_agree == sums.kept and sums.status == "ok"
    # The predictions (those of s hold t's classes where s has no depth or moves) count over
    # the kept pixels only, as the ground truth.
    assert sums.agree == sums.kept
    np.testing.assert_array_equal(sums.intersection, sums.gt_intersection)
    np.testing.assert_array_equal(sums.union, sums.gt_union)


def test_a_pose_that_is_not_rigid_or_intrinsics_that_are_not_pinhole_are_refused():
    scaled = pose()
    scaled[:3, :3] *= 1.1
    with pytest.raises(ValueError, match=r"c2w_s is not a camera pose: .*not orthonormal"):
        flat("shift", c2w_s=scaled)
    mirrored = pose(np.diag([1.0, -1.0, 1.0]))  # OpenCV's y in OpenGL's place
    with pytest.raises(ValueError, match=r"c2w_t is not a camera pose: .*reflection"):
        flat("shift", c2w_t=mirrored)
    with pytest.raises(ValueError, match="K must be pinhole intrinsics"):
        flat("shift", K=np.eye(4))


def test_identical_poses_are_flagged_not_counted():
    sums = flat("shift", c2w_s=pose())
    assert sums.status == "skipped" and not sums.counted
    assert "identical poses" in sums.reason and "trivially 1" in sums.reason


def test_a_pair_that_barely_overlaps_is_skipped_and_says_so():
    far = pose(centre=(21.0, 0.0, 10.0))  # 20 m frame footprint: 1 m of overlap, one column
    sums = flat("shift", c2w_s=far)
    assert sums.status == "skipped" and not sums.counted
    assert sums.kept == 0  # the ground truth of s does not hold t's classes: nothing agrees...
    assert "% of the frame, under the 10% a pair needs" in sums.reason
    behind = pose(np.diag([1.0, -1.0, -1.0]))  # looking up: nothing of t is in front of s
    assert flat("shift", c2w_s=behind).kept == 0


def test_torch_tensors_give_the_same_sums():
    gt_s, _ = by_hand("yaw")
    sums = flat("yaw")
    again = flat("yaw", depth_t=torch.full((H, W), 10.0), pred_t=torch.from_numpy(UNIQUE).long(),
                 gt_s=torch.from_numpy(gt_s), c2w_s=torch.from_numpy(CASES["yaw"][0]))  # fmt: skip
    assert (again.kept, again.agree, again.gt_agree) == (sums.kept, sums.agree, sums.gt_agree)
    np.testing.assert_array_equal(again.union, sums.union)


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ({"depth_s": np.ones((4, 4), np.float32)}, r"depth_s is \(4, 4\) but depth_t is \(6, 8\)"),
        ({"depth_t": np.ones((H, W), np.uint16)}, "depths in metres"),
        ({"dynamic_t": np.ones((H, W), bool)}, "255 static, 0 dynamic"),
        ({"gt_s": np.full((H, W), 70, np.uint8)}, r"frame s's ground truth holds ids \[70\]"),
        ({"pred_t": np.full((H, W), 64, np.uint8)}, r"frame t's prediction holds ids \[64\]"),
    ],
)
def test_bad_arrays_say_what_is_wrong(override, match):
    with pytest.raises(ValueError, match=match):
        flat("shift", **override)


# ------------------------------------------------------------------------------------------
# Generated frames: the ground truth of a frame, carried to the next frame of its pass.


def restated(t, s, gt_t, gt_s):
    """The pair measure written out in float64 from the definition (FORMAT-style equations,
    not the library's): kept pixels and ground-truth agreement."""
    height, width = t.depth.shape
    fx, fy, cx, cy = t.intrinsics[0, 0], t.intrinsics[1, 1], t.intrinsics[0, 2], t.intrinsics[1, 2]
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    d = t.depth.astype(np.float64)
    camera = np.stack([(u - cx) * d / fx, -(v - cy) * d / fy, -d, np.ones_like(d)], -1)
    world = camera @ t.c2w.astype(np.float64).T
    in_s = world @ np.linalg.inv(s.c2w.astype(np.float64)).T
    d_s = -in_s[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u_s, v_s = fx * in_s[..., 0] / d_s + cx, -fy * in_s[..., 1] / d_s + cy
    inside = (d_s > 0) & (u_s >= 0) & (u_s < width) & (v_s >= 0) & (v_s < height)
    col = np.clip(np.floor(np.nan_to_num(u_s)), 0, width - 1).astype(int)
    row = np.clip(np.floor(np.nan_to_num(v_s)), 0, height - 1).astype(int)
    looked = s.depth[row, col]
    kept = (
        inside
        & (d > 0) & (d < 1000) & (looked > 0) & (looked < 1000)
        & (t.dynamic == 255) & (s.dynamic[row, col] == 255)
        & (gt_t != 255) & (gt_s[row, col] != 255)
        & (np.abs(looked - d_s) <= 0.01 * d_s)
    )  # fmt: skip
    return int(kept.sum()), int((kept & (gt_t == gt_s[row, col])).sum())


@pytest.fixture(scope="module")
def forest(tmp_path_factory):
    """A pass of 4 frames over the forest mission (trees, tents, towers: things stand up)."""
    root = tmp_path_factory.mktemp("cross") / "root"
    return synthesize(root, seed=2, frames_per_viewpoint=4, size=(320, 240),
                      missions="nature_1", altitude="low", direction="h")  # fmt: skip


def semantic(root, frame):
    return modalities.read_semantic(frame.paths["pan_seg"])


def test_generated_ground_truth_agrees_across_a_pass(forest):
    frames = list_frames(forest, fields=["pan_seg"])
    pairs = pass_pairs(frames)
    assert pairs == [(0, 1), (1, 2), (2, 3)]
    for i, j in pairs:
        t, s = frames[i], frames[j]
        gt_t, gt_s = semantic(forest, t), semantic(forest, s)
        sums = pair_sums(forest, t, s, gt_t, gt_s, gt_t, gt_s, num_classes=23)
        assert sums.status == "ok", sums.reason
        assert sums.kept_fraction > 0.12
        assert sums.gt_consistency >= 0.99, (t.key, sums.gt_consistency)
        # The same pixels and agreement as the definition written out plainly (a pixel whose
        # carried point falls within float rounding of a pixel border may go either way).
        kept, agree = restated(read_geometry(forest, t), read_geometry(forest, s), gt_t, gt_s)
        assert abs(sums.kept - kept) <= 1e-4 * kept
        assert abs(sums.gt_agree - agree) <= 1e-4 * kept


def test_missing_depth_or_extrinsics_make_a_pair_unavailable(forest, tmp_path):
    root = shutil.copytree(forest, tmp_path / "root")
    frames = list_frames(root, fields=["pan_seg"])
    gt = semantic(root, frames[0])
    depth = root / MISSIONS["nature_1"] / "depth" / "45deg_low_h" / "000001.png"
    depth.unlink()
    sums = pair_sums(root, frames[0], frames[1], gt, gt, gt, gt, num_classes=23)
    assert sums.status == "unavailable" and not sums.counted
    assert "007_nature_1/45deg_low_h/000001 has no depth" in sums.reason
    assert str(depth) in sums.reason
    pose = root / MISSIONS["nature_1"] / "extrinsics" / "45deg_low_h" / "000002.json"
    pose.unlink()
    sums = pair_sums(root, frames[2], frames[3], gt, gt, gt, gt, num_classes=23)
    assert sums.status == "unavailable" and "000002 has no extrinsics" in sums.reason
    # A pose file that is there but not rigid costs its pairs too, naming the file and why.
    bad = root / MISSIONS["nature_1"] / "extrinsics" / "45deg_low_h" / "000003.json"
    matrix = np.array(json.loads(bad.read_text()))
    matrix[:3, :3] *= 2
    bad.write_text(json.dumps(matrix.tolist()))
    sums = pair_sums(root, frames[3], frames[3], gt, gt, gt, gt, num_classes=23)
    assert sums.status == "unavailable" and "damaged file" in sums.reason
    assert re.search(r"000003\.json: not a camera pose", sums.reason)


@pytest.mark.parametrize("tolerance", [0.01, 1e-7, 0.3333, 0.5, 0.9])
def test_the_visibility_range_is_the_rounded_test(tolerance):
    """One range test per pixel decides as ``|r − 1| <= τ`` in float32 does, at both ends (the
    ratios float32 by float32 around 1 ± τ), for NaN, infinities and everything between."""
    tau = np.float32(tolerance)
    ratios = [np.float32(v) for v in (1 - tau, 1 + tau, 1, 0, -1, np.inf, -np.inf, np.nan)]
    for start in ratios[:2]:
        r = start
        for _ in range(300):  # 300 floats on each side of each end
            r = np.nextafter(r, np.float32(0))
        ratios += [r]
        for _ in range(600):
            r = np.nextafter(r, np.float32(2))
            ratios.append(r)
    ratios = np.array(ratios + list(np.random.default_rng(0).uniform(0, 2, 2000)), np.float32)
    ratios = ratios.reshape(1, -1)
    lo, hi = visible_range(tau)
    rounded = (np.abs(ratios - np.float32(1)) <= tau).astype(np.uint8) * 255
    np.testing.assert_array_equal(cv2.inRange(ratios, lo, hi), rounded)
    # OpenCV's float32 difference and comparison (the test as once written) round alike.
    former = cv2.compare(cv2.absdiff(ratios, 1.0), float(tau), cv2.CMP_LE)
    np.testing.assert_array_equal(former, rounded)
