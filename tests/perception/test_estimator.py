"""The ProMPose facade end to end on a rendered scene: estimate, user masks, tracking, CLI, errors; and the
tracker's window fusion on a box seen by a camera orbiting it (known camera motion, as from a wrist camera's
forward kinematics; depth rasterised from the prior's own surface with RealSense-like noise, so the answer is
known by construction)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
import trimesh
from grounding_scene import render_scene

from prompose_grasp import InvalidInputError, ObjectNotFoundError, ProMPose
from prompose_grasp.cli import main
from prompose_grasp.cli.perception import overlay_label
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.estimator import EstimatorConfig
from prompose_grasp.perception.grounding import Grounder
from prompose_grasp.perception.priors import PriorLibrary
from prompose_grasp.perception.tracker import Tracker, TrackerConfig
from prompose_grasp.robot import RGBDFrame

pytestmark = pytest.mark.sim

# The scene's objects are 5-25 cm and seen from one side at ~1 m with RealSense-like noise (sigma ~4 mm). A
# 3D IoU of 0.5 is the NOCS "3D50" criterion; the box, bowl and can clear it comfortably (0.7-0.9 measured).
MIN_IOU = 0.5


@pytest.fixture(scope="module")
def scene():
    return render_scene()


@pytest.fixture(scope="module")
def frame(scene):
    return RGBDFrame(scene.rgb, scene.depth_m, scene.intrinsics, timestamp_s=0.0)


@pytest.fixture(scope="module")
def estimator():
    return ProMPose.default()


@pytest.mark.parametrize(
    ("prompt", "name", "family"),
    [("the yellow can", "can", "can"), ("the blue box", "box", "box"), ("the green bowl", "bowl", "bowl")],
)
def test_estimate_finds_and_fits_the_named_object(estimator, frame, scene, prompt, name, family):
    est = estimator.estimate(frame, prompt)
    gt = scene.gt_poses[name]
    assert est.prior.name == family
    assert est.pose.iou(gt) >= MIN_IOU
    # The fitted mask is the named object's: most of its pixels are that object's ground-truth pixels.
    assert np.mean(scene.gt_mask[est.mask] == scene.ids[name]) > 0.9  # mask edges may bleed a few pixels
    # The scaled prior mesh fills the estimated box exactly (the prior is normalised to the unit box).
    unit = est.pose.points_to_unit(est.mesh_cam.vertices)
    lo, hi = unit.min(axis=0), unit.max(axis=0)
    np.testing.assert_allclose(lo, -0.5, atol=1e-9)  # float64 round trip of an affine map
    np.testing.assert_allclose(hi, 0.5, atol=1e-9)
    # +y of the box is the table's up: the object stands on the table.
    assert est.pose.R[:, 1] @ scene.up_cam > np.cos(np.radians(3.0))  # RANSAC plane: ~0.1 deg measured
    assert set(est.timings_ms) == {"grounding", "prior", "pose", "total"}


def test_user_mask_skips_grounding_and_keeps_the_object(estimator, frame, scene):
    mask = scene.gt_mask == scene.ids["box"]
    est = estimator.estimate(frame, "box", mask=mask)
    assert est.score == 1.0 and np.array_equal(est.mask, mask)
    assert est.pose.iou(scene.gt_poses["box"]) >= MIN_IOU
    assert est.coverage > 0.9  # the box stands in full view: its mask shows all its facing surface
    # the overlay's label says it; a tracked update (no coverage) says nothing of it
    assert overlay_label("box", est) == f"box ({est.prior.name}, {round(100 * est.coverage)}% seen)"
    assert overlay_label("box", replace(est, coverage=math.nan)) == f"box ({est.prior.name})"
    with pytest.raises(InvalidInputError, match="mask must be"):
        estimator.estimate(frame, "box", mask=mask[:10])
    with pytest.raises(ObjectNotFoundError, match="valid depth points"):
        estimator.estimate(frame, "box", mask=np.zeros_like(mask))


def test_estimate_all_fits_only_candidates_near_the_best_score(estimator, frame):
    every = estimator.estimate_all(frame, "the can", max_objects=3)
    scores = [e.score for e in every]
    assert len(every) == 3 and scores == sorted(scores, reverse=True)
    # A ratio between the 2nd and 3rd candidates' share of the best keeps exactly the first two, fitted the
    # same (the fit is deterministic given the candidate).
    ratio = 0.5 * (scores[1] + scores[2]) / scores[0]
    near = estimator.estimate_all(frame, "the can", max_objects=3, min_score_ratio=ratio)
    assert [e.score for e in near] == scores[:2]
    for a, b in zip(near, every):
        np.testing.assert_array_equal(a.pose.t, b.pose.t)


def test_bad_input_is_refused_with_clear_errors(estimator, frame):
    with pytest.raises(InvalidInputError, match="prompt"):
        estimator.estimate(frame, "   ")
    empty = RGBDFrame(frame.rgb, np.zeros_like(frame.depth_m), frame.intrinsics, 0.0)
    with pytest.raises(InvalidInputError, match="no valid reading"):
        estimator.estimate(empty, "the can")
    with pytest.raises(InvalidInputError, match="RGBDFrame"):
        estimator.estimate((frame.rgb, frame.depth_m), "the can")


def test_implausible_input_is_refused_saying_what_is_accepted(estimator, frame):
    # millimetres passed as metres: the unit mistake is named
    with pytest.raises(InvalidInputError, match=r"looks like millimetres: median 8\d\d; pass metres"):
        RGBDFrame(frame.rgb, frame.depth_m * 1000.0, frame.intrinsics, 0.0)
    # a whole-image mask fits a box of metres: no object a gripper handles
    whole = np.ones(frame.depth_m.shape, dtype=bool)
    with pytest.raises(ObjectNotFoundError, match=r"m long \(more than EstimatorConfig.max_object_size_m"):
        estimator.estimate(frame, "can", mask=whole)
    # a candidate fitted larger than the bound is left out, and the error says so
    small = ProMPose(estimator.grounder, estimator.priors, config=EstimatorConfig(max_object_size_m=0.05))
    with pytest.raises(ObjectNotFoundError, match="left out as too large"):
        small.estimate(frame, "the blue box")
    assert small.estimate_all(frame, "the blue box") == []
    for prompt in ("赤いマグカップ", "红色杯子", "كوب أحمر", "🥫"):
        with pytest.raises(InvalidInputError, match=r"no word in Latin letters.*understand English"):
            estimator.estimate(frame, prompt)
    for n in ("3", 0, -5, True):
        with pytest.raises(InvalidInputError, match="max_objects must be an integer >= 1"):
            estimator.estimate_all(frame, "the can", max_objects=n)
    with pytest.raises(InvalidInputError, match="sequence of RGBDFrame"):
        estimator.track(frame, "the can")  # refused at the call, not at the first frame


def test_a_full_width_prompt_reads_as_its_ascii_form(estimator, frame):
    plain = estimator.estimate(frame, "the blue box")
    wide = estimator.estimate(frame, "ｔｈｅ　ｂｌｕｅ　ｂｏｘ")  # NFKC: the same words
    assert wide.prior is plain.prior
    np.testing.assert_array_equal(wide.pose.t, plain.pose.t)
    np.testing.assert_array_equal(wide.mask, plain.mask)


@pytest.mark.parametrize(
    "bad",
    [{"outgrown_share": 0.0}, {"outgrown_share": 1.5}, {"redetect_share": -0.1}, {"outgrown_margin_m": 0.0}],
)
def test_tracker_config_refuses_shares_and_margins_out_of_range(bad):
    with pytest.raises(InvalidInputError, match=next(iter(bad))):
        TrackerConfig(**bad)


def test_track_reuses_the_prior_and_stays_on_the_object(estimator, frame, scene):
    # Three noisy renders of the same static scene: tracking must not re-ground after the first frame and
    # must stay on the box.
    frames = [frame] + [
        RGBDFrame(s.rgb, s.depth_m, s.intrinsics, float(k)) for k, s in ((1, render_scene(seed=1)),)
    ]
    estimates = list(estimator.track(frames, "the blue box"))
    assert [e.frame_index for e in estimates] == [0, 1]
    assert estimates[1].timings_ms["grounding"] == 0.0  # tracked, not re-grounded
    # the tracked update carries the grounding score of the frame that started the track: a number, never NaN
    assert math.isfinite(estimates[1].score) and estimates[1].score == estimates[0].score
    assert math.isfinite(estimates[1].to_dict()["score"])
    assert estimates[1].prior is estimates[0].prior or estimates[1].prior.name == estimates[0].prior.name
    for e in estimates:
        assert e.pose.iou(scene.gt_poses["box"]) >= MIN_IOU


def test_cli_estimate_writes_the_json_contract_and_an_overlay(frame, tmp_path, capsys):
    rgb_path, depth_path = tmp_path / "rgb.png", tmp_path / "depth.png"
    cv2.imwrite(str(rgb_path), frame.rgb[..., ::-1])
    cv2.imwrite(str(depth_path), np.round(frame.depth_m * 1000).astype(np.uint16))
    K = frame.intrinsics
    intrinsics = [str(K.fx), str(K.fy), str(K.cx), str(K.cy)]
    args = ["estimate", "--rgb", str(rgb_path), "--depth", str(depth_path), "--depth-scale", "0.001",
            "--intrinsics", *intrinsics, "--prompt", "the blue box"]  # fmt: skip
    out_json, overlay = tmp_path / "out.json", tmp_path / "overlay.png"
    assert main([*args, "--json", str(out_json), "--overlay", str(overlay)]) == 0
    doc = json.loads(out_json.read_text())
    assert doc["prompt"] == "the blue box"
    assert set(doc["timing_ms"]) == {"grounding", "prior", "pose", "total"}
    assert doc["contenders"] == 1  # one blue box in the scene: a clear answer
    best = doc["objects"][0]
    assert set(best) == {"R", "t", "size", "score", "probability", "mask_pixels", "prior"}
    assert 0.75 <= best["probability"] <= 1.0  # clear: the confidence model's `clear_probability` or more
    assert np.asarray(best["R"]).shape == (3, 3) and len(best["t"]) == 3 and best["prior"] == "box"
    assert cv2.imread(str(overlay)).shape == (K.height, K.width, 3)
    # Bad input: a missing file is one line on stderr and exit code 2.
    capsys.readouterr()
    assert main([*args[:2], str(tmp_path / "missing.png"), *args[3:]]) == 2
    assert "no such file" in capsys.readouterr().err


# A small camera keeps the rasterised orbit fast; tracking needs no particular resolution.
K_ORBIT = CameraIntrinsics(430.0, 430.0, 159.5, 119.5, width=320, height=240)


def _camera(azimuth: float, elevation: float = math.radians(6.0), dist: float = 0.7) -> np.ndarray:
    """T_world_cam of a camera on a sphere around the world origin looking at (0, 0, 0.06), OpenCV axes; low
    elevation, so that the box's top face (which would show its depth) is hardly seen."""
    target = np.array([0.0, 0.0, 0.06])
    eye = target + dist * np.array(
        [
            math.cos(elevation) * math.cos(azimuth),
            math.cos(elevation) * math.sin(azimuth),
            math.sin(elevation),
        ]
    )
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = eye
    return T


def _frame(
    gt_world: Pose9D, mesh_unit: trimesh.Trimesh, T_world_cam: np.ndarray, rng
) -> tuple[RGBDFrame, np.ndarray]:
    """Depth of the table plane z = 0 and the object (z-buffered dense surface samples), noise along z."""
    h, w = K_ORBIT.height, K_ORBIT.width
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack(
        [(u - K_ORBIT.cx) / K_ORBIT.fx, (v - K_ORBIT.cy) / K_ORBIT.fy, np.ones_like(u, dtype=float)], axis=-1
    )
    R, t = T_world_cam[:3, :3], T_world_cam[:3, 3]
    dz = rays @ R.T  # ray directions (z-depth 1) in the world
    with np.errstate(divide="ignore"):
        depth = np.where(dz[..., 2] < -1e-6, -t[2] / dz[..., 2], 0.0)  # the table plane z = 0
    samples = trimesh.sample.sample_surface(mesh_unit, 120000, seed=int(rng.integers(1 << 30)))[0]
    pts_cam = (gt_world.points_to_camera(samples) - t) @ R
    uv = np.round(K_ORBIT.project(pts_cam)).astype(int)
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h) & (pts_cam[:, 2] > 0)
    obj = np.full((h, w), np.inf)
    np.minimum.at(obj, (uv[ok, 1], uv[ok, 0]), pts_cam[ok, 2])
    mask = np.isfinite(obj) & ((depth <= 0.0) | (obj < depth - 0.002))  # sky behind the top: depth 0
    depth = np.where(mask, obj, depth)
    noise = rng.normal(size=depth.shape) * (0.001 + 0.0037 * depth**2)  # D435-like axial noise
    depth = np.where(depth > 0.0, depth + noise, 0.0)  # the sky stays "no reading", not millimetres away
    rgb = np.full((h, w, 3), 128, dtype=np.uint8)
    return RGBDFrame(rgb, depth.astype(np.float32), K_ORBIT, 0.0, T_base_cam=T_world_cam), mask


@pytest.fixture(scope="module")
def orbit():
    library = PriorLibrary()
    prior = library.family_prior("box")
    # an instance 1.8x deeper than the family's mean proportions: the aspect prior alone would get it wrong
    aspect = np.asarray(prior.aspect) / np.max(prior.aspect)
    size = 0.16 * aspect * np.array([1.0, 1.0, 1.8])
    gt_world = Pose9D(np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), [0.0, 0.0, size[1] / 2], size)
    rng = np.random.default_rng(3)
    frames = [_frame(gt_world, prior.mesh, _camera(math.radians(-90.0 + 12.0 * k)), rng) for k in range(7)]
    return prior, gt_world, frames


def test_tracked_window_follows_the_orbit_and_fuses_the_size(orbit):
    prior, gt_world, frames = orbit
    estimator = ProMPose(Grounder(), PriorLibrary())  # no text encoder: masks are given
    tracker = Tracker(estimator, "box", prior=prior, config=TrackerConfig(refit_angle_deg=180.0))
    errors, single_errors = [], []
    for k, (frame, mask) in enumerate(frames):
        est = tracker.update(frame, mask=mask if k == 0 else None)
        assert math.isfinite(est.coverage) == (k == 0)  # one mask's measure: the first frame's fit only
        T_cam_world = np.linalg.inv(frame.T_base_cam)
        gt = gt_world.transformed(T_cam_world)
        errors.append(float(np.max(np.abs(np.sort(est.pose.size) / np.sort(gt.size) - 1.0))))
        if k in (0, len(frames) - 1):
            single = estimator.estimate(frame, "box", prior=prior, mask=mask)
            single_errors.append(float(np.max(np.abs(np.sort(single.pose.size) / np.sort(gt.size) - 1.0))))
        # the trajectory: the centre follows the (static) object through the camera motion (1 cm: the bar)
        assert np.linalg.norm(est.pose.t - gt.t) < 0.01
    assert tracker.reinitialisations == 0  # known camera motion: the track is never lost
    # After the camera has turned 72 deg the fused window has seen front and side: every size within 5 %
    # (noise, the grazing-angle band), no worse than the first frame's and the last frame's own fits (2 %:
    # two fits on differently sampled noise).
    assert errors[-1] < 0.05
    assert errors[-1] <= min(single_errors) + 0.02


def _cut_at_column(frame: RGBDFrame, mask: np.ndarray, width: int) -> tuple[RGBDFrame, np.ndarray]:
    """The frame as a camera `width` pixels wide would see it (the same intrinsics otherwise): the columns
    from `width` on are beyond its image border."""
    K = frame.intrinsics
    intr = CameraIntrinsics(K.fx, K.fy, K.cx, K.cy, width=width, height=K.height)
    cut = RGBDFrame(
        np.ascontiguousarray(frame.rgb[:, :width]),
        np.ascontiguousarray(frame.depth_m[:, :width]),
        intr,
        frame.timestamp_s,
        T_base_cam=frame.T_base_cam,
    )
    return cut, np.ascontiguousarray(mask[:, :width])


def test_a_box_the_image_border_cuts_keeps_its_size_while_tracked():
    # The orbit's box, with the family's own proportions, seen by a camera whose image ends at column 175:
    # the border cuts off a third of the box in every frame. The tracked frames' fit takes this camera's
    # view (`SceneView` of the tracked selection): the prior points beyond the border do not pull, so
    # the box keeps the size the first frame gave it (the cut side rests on the prior's proportions) while
    # the fused views settle the rest. Without the view, those prior points pulled the box onto its visible
    # part: one extent fell 5 % -> 49 % -> 66 % below the first frame's over frames 4-6 and the centre
    # went 2.3 cm off (measured before this change).
    prior = PriorLibrary().family_prior("box")
    size = 0.16 * np.asarray(prior.aspect) / np.max(prior.aspect)
    gt_world = Pose9D(np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), [0.0, 0.0, size[1] / 2], size)
    rng = np.random.default_rng(3)
    views = [_frame(gt_world, prior.mesh, _camera(math.radians(-90.0 + 12.0 * k)), rng) for k in range(7)]
    tracker = Tracker(ProMPose(Grounder(), PriorLibrary()), "box", prior=prior,
                      config=TrackerConfig(refit_angle_deg=180.0))  # fmt: skip
    sizes = []
    for k, (full, full_mask) in enumerate(views):
        assert full_mask[:, 175:].any()  # the border cuts the box in every frame
        frame, mask = _cut_at_column(full, full_mask, 175)
        est = tracker.update(frame, mask=mask if k == 0 else None)
        sizes.append(est.pose.size)
        gt = gt_world.transformed(np.linalg.inv(frame.T_base_cam))
        # the centre follows the box within 1.5 cm (the first frame's cut-side guess is 1.4 cm off: measured)
        assert np.linalg.norm(est.pose.t - gt.t) < 0.015
    assert tracker.reinitialisations == 0
    # no extent shrinks by more than 10 % of the first frame's (measured: at most 5 % as the views fuse)
    assert np.all(np.asarray(sizes) >= 0.9 * sizes[0])


@pytest.mark.parametrize("redetect", [True, False])
def test_a_track_started_on_a_cut_view_grows_to_the_whole_object(redetect):
    # Frame 0 ends at column 135: the border leaves a fifth of the box (the family's proportions) in view, and
    # its fit is 16-19 % short along two extents. From frame 1 the whole box is in view (a 320-pixel image,
    # the camera turning 2 deg a frame). The tracked selection reaches only `roi_margin_m` past the tracked
    # box, but its points outside the box start a re-fit (`Tracker._outgrown`), and the re-fit fits the
    # grounder's candidate under the track (`Tracker._redetected`): the whole box, from frame 1 on. Without
    # re-detection (the control) the re-fit sees the same cut selection and the track grows a few cm a frame.
    prior = PriorLibrary().family_prior("box")
    size = 0.16 * np.asarray(prior.aspect) / np.max(prior.aspect)
    gt_world = Pose9D(np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), [0.0, 0.0, size[1] / 2], size)
    rng = np.random.default_rng(3)
    views = [_frame(gt_world, prior.mesh, _camera(math.radians(-90.0 + 2.0 * k)), rng) for k in range(5)]
    config = TrackerConfig() if redetect else TrackerConfig(redetect_share=1.0)
    tracker = Tracker(ProMPose(Grounder(), PriorLibrary()), "box", prior=prior, config=config)
    first = _cut_at_column(*views[0], 135)
    size_errors, centre_errors, grounding_ms = [], [], []
    for k, (frame, mask) in enumerate([first, *views[1:]]):
        est = tracker.update(frame, mask=mask if k == 0 else None)
        gt = gt_world.transformed(np.linalg.inv(frame.T_base_cam))
        size_errors.append(float(np.max(np.abs(est.pose.size / gt.size - 1.0))))
        centre_errors.append(float(np.linalg.norm(est.pose.t - gt.t)))
        grounding_ms.append(est.timings_ms["grounding"])
    assert size_errors[0] > 0.15  # the cut first view (measured 0.19)
    assert tracker.refits_taken >= 1 and tracker.reinitialisations == 0
    # a tracked frame's timings name the re-detection as grounding (the user's mask started the track)
    assert (max(grounding_ms[1:]) > 0.0) == redetect
    if redetect:
        # every extent within 6 % and the centre within 1 cm from frame 1 on (measured <= 5 %, <= 3 mm: the
        # noise and the grazing-angle band, as in the orbit tests)
        assert max(size_errors[1:]) < 0.06 and max(centre_errors[1:]) < 0.01
    else:
        # measured: 42 % short after the re-fit and the centre 2.9 cm off; the seen surface beyond the box
        # then grows it a little each frame (`grow_to_seen`), 1.4 cm off on frame 4
        assert size_errors[1] > 0.3 and centre_errors[1] > 0.02


def test_moved_object_is_followed_and_a_vanished_one_is_lost(orbit):
    prior, gt_world, frames = orbit
    estimator = ProMPose(Grounder(), PriorLibrary())  # no text encoder: masks are given
    tracker = Tracker(estimator, "box", prior=prior, config=TrackerConfig(refit_angle_deg=180.0))
    frame0, mask0 = frames[0]
    tracker.update(frame0, mask=mask0)
    # the object slides 1.5 cm along the table while the camera holds still: the window still holds the old
    # position, so the box follows over a few frames (smoothing, and the window's old views pull with at
    # most the Huber force) and is on the new position within 1 cm after four (measured: 1.45, 1.34, 1.15,
    # 0.88 cm; with the views' outline half a pixel in, before `outline_corrected_points`: 0.89 after three)
    moved = Pose9D(gt_world.R, gt_world.t + np.array([0.015, 0.0, 0.0]), gt_world.size)
    gt1 = moved.transformed(np.linalg.inv(frame0.T_base_cam))
    for seed in range(4):
        est = tracker.update(_frame(moved, prior.mesh, frame0.T_base_cam, np.random.default_rng(seed))[0])
    assert np.linalg.norm(est.pose.t - gt1.t) < 0.01
    assert tracker.reinitialisations == 0
    # the object is gone (an empty table): too few points near the prediction, so the track is lost (and the
    # tracker would ground the prompt again)
    far = Pose9D(gt_world.R, [5.0, 5.0, -5.0], gt_world.size)
    table_only, _ = _frame(far, prior.mesh, frame0.T_base_cam, np.random.default_rng(1))
    assert tracker._track(table_only) is None


def _yaw_error_deg(est: Pose9D, gt: Pose9D) -> float:
    """Angle between the estimated and the true object +x (the mug's handle side) [deg]."""
    return math.degrees(math.acos(float(np.clip(est.R[:, 0] @ gt.R[:, 0], -1.0, 1.0))))


def _mug_orbit(step_deg: float, n_frames: int):
    """The family mug upright on the table (object +y = world +z), its handle (object +x) to the side the
    orbit's first camera sees it from, and `n_frames` views of it, the camera turning `step_deg` a frame."""
    prior = PriorLibrary().family_prior("mug")
    size = np.asarray(prior.typical_size_m, dtype=np.float64)
    gt_world = Pose9D(np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), [0.0, 0.0, size[1] / 2], size)
    rng = np.random.default_rng(5)
    cams = [_camera(math.radians(-90.0 + step_deg * k)) for k in range(n_frames)]
    return prior, gt_world, [_frame(gt_world, prior.mesh, cam, rng) for cam in cams]


def _on_the_other_side(pose: Pose9D) -> Pose9D:
    """The pose turned half round the mug's axis: the handle on the other side, the same footprint."""
    return Pose9D(pose.R @ np.diag([-1.0, 1.0, -1.0]), pose.t, pose.size)


@pytest.mark.parametrize("refit", [True, False])
def test_a_track_on_the_wrong_yaw_is_turned_back_by_the_refit(refit):
    prior, gt_world, frames = _mug_orbit(12.0, 4)
    estimator = ProMPose(Grounder(), PriorLibrary())  # no text encoder: masks are given
    config = TrackerConfig() if refit else TrackerConfig(refit_angle_deg=180.0)
    tracker = Tracker(estimator, "mug", prior=prior, config=config)
    frame0, mask0 = frames[0]
    first = tracker.update(frame0, mask=mask0)
    gt0 = gt_world.transformed(np.linalg.inv(frame0.T_base_cam))
    assert _yaw_error_deg(first.pose, gt0) < 15.0  # the handle is in view: the cold fit finds it
    # as if the first frame had missed the handle: the track goes on with the handle on the other side
    # (a half turn about the mug's axis; the footprint is the same, so the points alone do not object)
    tracker._pose = _on_the_other_side(first.pose)
    for frame, _ in frames[1:]:
        est = tracker.update(frame)
    gt = gt_world.transformed(np.linalg.inv(frames[-1][0].T_base_cam))
    # the camera turns 12 deg a frame: the re-fit runs once the view has turned 20 deg (frame 2); its cold
    # multi-hypothesis fit of the frame puts the handle on the side its points are, and wins. Without it
    # the warm start stays in its basin, the handle on the wrong side (the control).
    if refit:
        assert tracker.refits >= 1 and tracker.refits_taken >= 1
        assert _yaw_error_deg(est.pose, gt) < 15.0
    else:
        assert tracker.refits == 0
        assert _yaw_error_deg(est.pose, gt) > 90.0


def test_slow_camera_refits_once_the_view_has_turned_and_turns_the_track_back():
    # The mug of test_a_track_on_the_wrong_yaw_is_turned_back_by_the_refit, the track on the wrong yaw, but
    # a camera turning 2 deg a frame (a video stream): the re-fit starts once the view has turned by
    # `refit_angle_deg` (8 here, to keep the test short: frame 4) and its verdict is taken on that frame.
    prior, gt_world, frames = _mug_orbit(2.0, 8)
    config = TrackerConfig(refit_angle_deg=8.0)
    tracker = Tracker(ProMPose(Grounder(), PriorLibrary()), "mug", prior=prior, config=config)
    frame0, mask0 = frames[0]
    tracker._pose = _on_the_other_side(tracker.update(frame0, mask=mask0).pose)
    # as if the unexplained-handle re-fit had run at this view already (it would turn the track back on
    # frame 1, in the update): only the turned view starts the re-fit here
    tracker._unturned_refit_done = True
    refits, taken, errors = [0], [0], [180.0]  # per frame, from frame 0
    for frame, _ in frames[1:]:
        est = tracker.update(frame)
        refits.append(tracker.refits)
        taken.append(tracker.refits_taken)
        errors.append(_yaw_error_deg(est.pose, gt_world.transformed(np.linalg.inv(frame.T_base_cam))))
    k_refit = refits.index(1)
    assert 3 <= k_refit <= 5  # 8 deg turned: frame 4, give or take the fitted poses' noise
    # one re-fit until the view has turned most of another 8 deg since it (frame 8 nominally; the turn is
    # measured on the tracked poses, whose yaw wanders by a few degrees, so a second one may start on the
    # last frame), and its verdict is taken on the re-fitted frame
    assert refits[k_refit : k_refit + 3] == [1, 1, 1]
    assert taken[: k_refit + 3] == [0] * k_refit + [1, 1, 1]
    # the handle stays on the wrong side until then (> 90 deg), then within 15 deg of the truth (the bar of
    # the 12-deg-a-frame test above) from that frame on
    assert min(errors[:k_refit]) > 90.0
    assert max(errors[k_refit:]) < 15.0


def test_tracked_selection_is_the_observation_of_its_pixels(orbit):
    # `Tracker._select` back-projects only the valid pixels of the predicted box's image rectangle: at full
    # resolution the same pixels as back-projecting the whole image with `depth_to_point_map` and keeping
    # the points in the grown box, off the plane and within `surface_margin_m` of the posed prior's surface
    # samples, and the same points (row-major) as the first frame's observation of those pixels
    # (`ProMPose.object_points`: the outline half a pixel out). (Against the code before the crop, on 363
    # selections of the video split, strides 1 and 2, with and without `any_turn`: identical arrays.)
    from scipy.spatial import cKDTree

    from prompose_grasp.geometry.pointcloud import depth_to_point_map

    prior, gt_world, frames = orbit
    tracker = Tracker(ProMPose(Grounder(), PriorLibrary()), "box", prior=prior)
    frame0, mask0 = frames[0]
    tracker.update(frame0, mask=mask0)
    frame = frames[1][0]
    pred = gt_world.transformed(np.linalg.inv(frame.T_base_cam))
    plane, cfg = tracker._plane, tracker.config
    mask, pts = tracker._select(frame, pred, plane, stride=1)
    every = depth_to_point_map(frame.depth_m, frame.intrinsics)
    rows, cols = np.nonzero(np.isfinite(every[..., 2]))
    cand = every[rows, cols]
    grown = Pose9D(pred.R, pred.t, pred.size + 2.0 * cfg.roi_margin_m)
    keep = grown.contains(cand) & (plane.height_m(cand) > cfg.plane_clearance_m)
    d, _ = cKDTree(pred.points_to_camera(tracker._prior_sample())).query(cand, k=1)
    keep &= d <= cfg.surface_margin_m
    assert len(pts) > 500
    expected = np.zeros_like(mask)
    expected[rows[keep], cols[keep]] = True
    np.testing.assert_array_equal(mask, expected)
    # the crop's principal point is the image's shifted by whole pixels: (u - cx) is the same number, or
    # one ulp off, so the points agree to round-off of metre-scale coordinates
    observed = tracker.estimator.object_points(frame, expected)
    np.testing.assert_allclose(pts, observed, rtol=0.0, atol=1e-12)
    assert np.any(np.abs(observed - cand[keep]) > 1e-4)  # the outline did move (half a pixel: 1-2 mm)
    # every 2nd pixel: a quarter of those pixels, each pixel's 2 x 2 block in the mask. Interior points
    # are the full-resolution ones; on the outline a point moves by up to one pixel per image axis (half a
    # 2-pixel sample) where the full-resolution one moved by up to half a pixel, either way: each is within
    # 1.5 sqrt(2) pixel footprints (z / f) of a full-resolution point
    mask2, pts2 = tracker._select(frame, pred, plane, stride=2)
    assert 0.2 * len(pts) < len(pts2) < 0.3 * len(pts)  # a quarter of the pixels, give or take the edges
    d2, _ = cKDTree(pts).query(pts2, k=1)
    assert np.median(d2) == 0.0
    assert np.all(d2 <= 1.5 * math.sqrt(2.0) * pts2[:, 2] / frame.intrinsics.fx + 1e-9)
    assert np.count_nonzero(mask2) <= 4 * len(pts2) and np.count_nonzero(mask2 & ~mask) <= 4 * len(pts2)
