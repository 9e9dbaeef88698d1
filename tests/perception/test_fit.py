"""Metric 9-DoF fit: known answers by construction (visible surface samples of a scaled, posed prior with
RealSense-like noise), warm starts, the upright constraint, symmetry-canonical output, bad input; and the
tracker's re-fit of a mug whose handle the track has on the wrong side."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import trimesh

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import back_project
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.geometry.se3 import rotation_angle, so3_exp
from prompose_grasp.perception.estimator import ProMPose
from prompose_grasp.perception.fit import (
    FitConfig,
    FitStage,
    SceneView,
    canonicalize_symmetry,
    fit_pose,
    grow_to_seen,
    mask_coverage,
    protrusion_points,
    seen_surface,
)
from prompose_grasp.perception.fit.objective import (
    _containment_cost,
    _containment_jacobian,
    _normal_equations,
)
from prompose_grasp.perception.fit.observation import _next_to_occluder, _observable
from prompose_grasp.perception.fit.problem import _Problem, _State
from prompose_grasp.perception.grounding import Grounder, SupportPlane
from prompose_grasp.perception.priors import PriorLibrary
from prompose_grasp.perception.priors.library import (
    articulated_variants,
    aspect_weight_factors,
    round_body_axis,
)
from prompose_grasp.perception.priors.prior import make_prior
from prompose_grasp.perception.tracker import Tracker
from prompose_grasp.robot import RGBDFrame

# Rotation error bound [deg]: noise of 2-5 mm over objects 7-30 cm wide tilts a fitted face by < 2 deg; the
# yaw of a mug rests on its handle (~1 cm of points), so a few degrees; 5 deg is also the strict NOCS bar.
ROT_TOL_DEG = 5.0
# Centre error bound [m]: 1 cm, the brief's bar; noise averages out over thousands of points (~1 mm), what is
# left is the mean shape of the prior against the instance.
T_TOL_M = 0.01
# Size error bound (relative): 10 %; the prior is the family's exact shape here, so the error is noise and
# the missing grazing-angle band at the silhouette (a few mm on 7-30 cm).
SIZE_RTOL = 0.10
# Exact 3D IoU lower bound (symmetry-aware): the NOCS 3D75 bar; errors within the bounds above keep it.
IOU_MIN = 0.75
# Up direction bound [deg] when the support normal is given: the fit holds +y on it exactly (rounding only).
UP_TOL_DEG = 2.0


@pytest.fixture(scope="module")
def library() -> PriorLibrary:
    return PriorLibrary()


def _dense_surface(prior, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    pts, face = trimesh.sample.sample_surface(prior.mesh, n, seed=seed)
    return np.asarray(pts), np.asarray(prior.mesh.face_normals)[face]


def _zbuffer_visible(pts: np.ndarray) -> np.ndarray:
    """(N,) bool: points not hidden behind nearer points of the same cloud, as a depth camera sees them: a
    z-buffer of 1/300 rad pixels (~3 mm at 0.8 m, several surface samples each); a point is seen when it is
    within 4 mm of its pixel's nearest depth (the depth change of a slanted surface across one pixel)."""
    px = np.floor(300.0 * pts[:, :2] / pts[:, 2:3]).astype(np.int64)
    px -= px.min(axis=0)
    key = px[:, 0] * (px[:, 1].max() + 1) + px[:, 1]
    z_min = np.full(int(key.max()) + 1, np.inf)
    np.minimum.at(z_min, key, pts[:, 2])
    return pts[:, 2] <= z_min[key] + 0.004


def _ray_noise(pts: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Axial depth noise along each point's ray, 1 mm + 3.7 mm/m^2 z^2 (RealSense D435-like, docs/sim.md)."""
    sigma = 0.001 + 0.0037 * pts[:, 2] ** 2
    ray = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    return pts + ray * (rng.normal(size=len(pts)) * sigma)[:, None]


def _upright_scene(
    prior,
    rng: np.random.Generator,
    yaw: float | None = None,
    elevation_deg: float | None = None,
    noise: bool = True,
):
    """A posed, scaled prior standing on a table seen from 30-65 deg elevation at 0.6-0.9 m, and its visible
    surface points (facing the camera and not hidden by the object itself) with axial noise 1 mm +
    3.7 mm/m^2 z^2 (RealSense D435-like, docs/sim.md)."""
    elevation = math.radians(rng.uniform(30.0, 65.0) if elevation_deg is None else elevation_deg)
    up = np.array([0.0, -math.cos(elevation), -math.sin(elevation)])  # table normal, camera frame
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.cross(up, e1)
    yaw = rng.uniform(0.0, 2.0 * math.pi) if yaw is None else yaw
    x = math.cos(yaw) * e1 + math.sin(yaw) * e2
    R = np.column_stack([x, up, np.cross(x, up)])
    size = prior.typical_size_m * rng.uniform(0.85, 1.2, 3)
    if prior.symmetry == "y_continuous":
        size[2] = size[0]
    t = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.05, 0.05), rng.uniform(0.6, 0.9)])
    gt = Pose9D(R, t, size)
    pts_u, nrm_u = _dense_surface(prior, 30000, int(rng.integers(1 << 30)))
    pts = gt.points_to_camera(pts_u)
    nrm = (nrm_u / size) @ R.T
    pts = pts[np.einsum("ij,ij->i", nrm, pts) < 0.0]
    pts = pts[_zbuffer_visible(pts)]
    if noise:
        pts = _ray_noise(pts, rng)
    bottom = t - 0.5 * size[1] * up
    plane = np.array([*up, -float(up @ bottom)])
    return gt, pts, up, plane


def _rotation_error_deg(pred: Pose9D, gt: Pose9D, symmetry: str) -> float:
    if symmetry == "y_continuous":
        return math.degrees(math.acos(float(np.clip(pred.R[:, 1] @ gt.R[:, 1], -1.0, 1.0))))
    if symmetry == "box":  # the half-turns about the box axes map the shape onto itself
        flips = [
            np.eye(3),
            np.diag([-1.0, 1.0, -1.0]),
            np.diag([1.0, -1.0, -1.0]),
            np.diag([-1.0, -1.0, 1.0]),
        ]
        return min(math.degrees(rotation_angle(pred.R @ F, gt.R)) for F in flips)
    return math.degrees(rotation_angle(pred.R, gt.R))


def _iou(pred: Pose9D, gt: Pose9D, symmetry: str) -> float:
    if symmetry != "y_continuous":
        return pred.iou(gt)
    # best over turns about the predicted y axis (the NOCS protocol for y-symmetric objects)
    return max(
        Pose9D(pred.R @ so3_exp([0.0, 2.0 * math.pi * k / 36, 0.0]), pred.t, pred.size).iou(gt)
        for k in range(36)
    )


# Share of the observed points in a mug's handle region (unit-box x > 0.25: the family mug's body ends at
# x = 0.21) below which the handle counts as hidden and the mug as symmetric about y (the NOCS protocol's
# handle visibility; sim.dataset uses 20 pixels, ~1 % of a mug's ~2000 pixels at 0.7 m).
HANDLE_MIN_FRACTION = 0.01


def _scored_symmetry(prior, gt: Pose9D, pts: np.ndarray) -> str:
    """The symmetry the errors are scored with: a mug whose handle is not seen is round about y (NOCS)."""
    if prior.name != "mug":
        return prior.symmetry
    seen = int(np.count_nonzero(gt.points_to_object(pts)[:, 0] / gt.size[0] > 0.25))
    return prior.symmetry if seen >= HANDLE_MIN_FRACTION * len(pts) else "y_continuous"


def _check(result, gt: Pose9D, symmetry: str) -> None:
    p = result.pose
    assert _rotation_error_deg(p, gt, symmetry) < ROT_TOL_DEG
    assert np.linalg.norm(p.t - gt.t) < T_TOL_M
    np.testing.assert_allclose(p.size, gt.size, rtol=SIZE_RTOL)
    assert _iou(p, gt, symmetry) >= IOU_MIN
    assert np.all(p.size > 0.0)


@pytest.mark.parametrize("family", ["box", "can", "mug", "laptop", "bottle"])
def test_known_pose_on_support_plane(library: PriorLibrary, family: str) -> None:
    prior = library.family_prior(family)
    rng = np.random.default_rng(["box", "can", "mug", "laptop", "bottle"].index(family))
    for _ in range(2):
        gt, pts, up, plane = _upright_scene(prior, rng)
        result = fit_pose(pts, prior, support_plane_cam=plane)
        _check(result, gt, _scored_symmetry(prior, gt, pts))
        assert result.mode == "upright_plane"
        # +y is the support normal
        assert math.degrees(math.acos(min(1.0, float(result.pose.R[:, 1] @ up)))) < UP_TOL_DEG
        assert result.loss == pytest.approx(result.obs_to_prior + result.prior_to_obs)


@pytest.mark.parametrize("family", ["box", "mug"])
def test_known_pose_with_up_only(library: PriorLibrary, family: str) -> None:
    prior = library.family_prior(family)
    gt, pts, up, _ = _upright_scene(prior, np.random.default_rng(11))
    result = fit_pose(pts, prior, up_cam=up)
    _check(result, gt, prior.symmetry)
    assert math.degrees(math.acos(min(1.0, float(result.pose.R[:, 1] @ up)))) < UP_TOL_DEG


def test_free_rotation_recovers_a_bottle(library: PriorLibrary) -> None:
    # Without a support normal the 24 signed, permuted PCA frames are tried; for a y-round shape, 6.
    prior = library.family_prior("bottle")
    gt, pts, _, _ = _upright_scene(prior, np.random.default_rng(5))
    result = fit_pose(pts, prior)
    assert result.hypotheses == 6
    _check(result, gt, prior.symmetry)


def test_warm_start_from_perturbed_pose_converges(library: PriorLibrary) -> None:
    prior = library.family_prior("mug")
    gt, pts, up, plane = _upright_scene(prior, np.random.default_rng(3))
    # 8 deg of yaw, 1.5 cm of offset and 12 % of size off: a frame-to-frame change well beyond 30 Hz motion
    init = Pose9D(
        so3_exp(up * math.radians(8.0)) @ gt.R, gt.t + np.array([0.015, 0.0, -0.01]), gt.size * 1.12
    )
    result = fit_pose(pts, prior, support_plane_cam=plane, init=init)
    assert result.hypotheses == 1 and result.mode.startswith("warm_")
    _check(result, gt, _scored_symmetry(prior, gt, pts))


def test_amodal_box_reaches_hidden_bottom(library: PriorLibrary) -> None:
    # Only the upper 60 % of a box is seen (an occluder in front): the support plane completes the height.
    prior = library.family_prior("box")
    gt, pts, up, plane = _upright_scene(prior, np.random.default_rng(8))
    heights = pts @ up + plane[3]
    seen = pts[heights > 0.4 * gt.size[1]]
    result = fit_pose(seen, prior, support_plane_cam=plane)
    assert result.pose.size[1] == pytest.approx(gt.size[1], rel=SIZE_RTOL)
    assert result.pose.iou(gt) >= IOU_MIN


def test_equal_shapes_give_equal_poses_for_round_objects(library: PriorLibrary) -> None:
    # The same can turned about its axis gives the same (canonical) pose: yaw is not observable.
    prior = library.family_prior("can")
    rng = np.random.default_rng(21)
    gt, clean, _, plane = _upright_scene(prior, rng, noise=False)
    c = gt.t
    turn = so3_exp(gt.R[:, 1] * 1.0)
    # the visible surface of a can turned about its axis is the same surface: turn the noise-free samples,
    # then add the depth noise along each one's own ray, as the camera would
    pts = _ray_noise(clean, rng)
    pts_turned = _ray_noise((clean - c) @ turn.T + c, rng)
    a = fit_pose(pts, prior, support_plane_cam=plane).pose
    b = fit_pose(pts_turned, prior, support_plane_cam=plane).pose
    # 2 deg / 3 mm: two fits on differently sampled noise
    assert math.degrees(rotation_angle(a.R, b.R)) < 2.0
    assert np.linalg.norm(a.t - b.t) < 0.003


def test_canonicalize_symmetry_is_idempotent_and_keeps_the_box() -> None:
    rng = np.random.default_rng(0)
    pose = Pose9D(so3_exp(rng.normal(size=3)), np.array([0.05, -0.02, 0.8]), np.array([0.07, 0.2, 0.07]))
    for sym in ("y_continuous", "box", "y_2fold", "x_continuous", "none"):
        once = canonicalize_symmetry(pose, sym)
        twice = canonicalize_symmetry(once, sym)
        # rounding only: the second call finds the representative already chosen
        assert twice.allclose(once, 1e-9, 1e-12, 1e-12)
        if sym in ("box", "y_2fold", "none"):
            # a half-turn about a box axis maps the box onto itself: same volume overlap
            assert once.iou(pose) == pytest.approx(1.0, abs=1e-9)


def test_bad_input_is_refused(library: PriorLibrary) -> None:
    prior = library.family_prior("box")
    good = np.random.default_rng(0).normal(size=(200, 3)) * 0.03 + [0.0, 0.0, 0.8]
    with pytest.raises(InvalidInputError, match="at least"):
        fit_pose(good[:10], prior)
    bad = good.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        fit_pose(bad, prior)
    with pytest.raises(InvalidInputError, match=r"\(N, 3\)"):
        fit_pose(good[:, :2], prior)
    with pytest.raises(InvalidInputError, match="in front"):
        fit_pose(good * [1.0, 1.0, -1.0], prior)
    with pytest.raises(InvalidInputError, match="non-zero"):
        fit_pose(good, prior, up_cam=[0.0, 0.0, 0.0])
    with pytest.raises(InvalidInputError, match="disagree"):
        fit_pose(good, prior, up_cam=[0.0, -1.0, 0.0], support_plane_cam=[1.0, 0.0, 0.0, 0.5])
    with pytest.raises(InvalidInputError, match="ShapePrior"):
        fit_pose(good, "box")  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="positive int"):
        FitConfig(n_points=0)
    with pytest.raises(InvalidInputError, match="FitStage"):
        FitStage(obs_points=10, prior_points=0, iterations=1, keep=1)


def test_laptop_seen_from_behind_keeps_its_depth(library: PriorLibrary) -> None:
    # The camera looks at the back of the screen: the keyboard is hidden behind it and the box must keep the
    # base's depth. (On the sim dataset, without the fit's self-occlusion test the box collapsed to the
    # screen's thickness in such views; on this clean construction the fit holds the depth either way, so
    # this is a known-answer guard, not a proof of that test.)
    prior = library.family_prior("laptop")
    rng = np.random.default_rng(5)
    # yaw pi turns the object's +z (keyboard side) away from the camera: the screen's back faces it
    # seen from 28 deg above the table the screen hides the whole keyboard, which faces up (cos 0.47 to the
    # view, above visible_cos)
    gt, pts, _, plane = _upright_scene(prior, rng, yaw=math.pi, elevation_deg=28.0)
    assert float(gt.R[:, 2] @ gt.t) > 0.0  # the keyboard side points away from the camera
    result = fit_pose(pts, prior, support_plane_cam=plane)
    _check(result, gt, prior.symmetry)


def test_wide_open_laptop_is_fitted_by_an_articulated_variant(library: PriorLibrary) -> None:
    # The instance's screen is opened to 135 deg (the family's mean shape has 110): the variant wins.
    prior = library.family_prior("laptop")
    wide = articulated_variants(prior)[-1]
    assert wide.source == "library:laptop:opening 135 deg" and wide.name == prior.name
    assert articulated_variants(library.family_prior("mug")) == ()
    gt, pts, _, plane = _upright_scene(wide, np.random.default_rng(9))
    result = fit_pose(pts, prior, support_plane_cam=plane)
    assert result.prior is wide
    _check(result, gt, prior.symmetry)
    # without the variants the mean shape cannot reach the wide screen's depth
    plain = fit_pose(pts, prior, FitConfig(articulations=False), support_plane_cam=plane)
    assert plain.prior is prior
    assert plain.pose.iou(gt) < result.pose.iou(gt)


def test_a_laptops_base_depth_follows_its_screen_height(library: PriorLibrary) -> None:
    # A laptop's screen folds onto its base, so the family holds the y:z pair (screen height : base depth)
    # firmer than the other pairs (`ShapeFamily.aspect_weight_factors`); a prior of no family holds none.
    prior = library.family_prior("laptop")
    for p in (prior, *articulated_variants(prior)):
        factors = aspect_weight_factors(p)
        assert factors[1] > 1.0 and factors[0] == factors[2] == 1.0
    assert aspect_weight_factors(library.family_prior("bottle")).tolist() == [1.0, 1.0, 1.0]
    user = make_prior(
        trimesh.creation.box([0.3, 0.2, 0.25]),
        name="laptop",
        source="user:cad.stl",
        symmetry="none",
        n_points=500,
    )
    assert aspect_weight_factors(user).tolist() == [1.0, 1.0, 1.0]
    # An instance whose base is 25 % shallower than its screen is tall (no real laptop), seen from behind its
    # screen: held firm, the fit keeps the family's y:z and leaves the width, which the points show, alone.
    rng = np.random.default_rng(1)
    view, _, _, _ = _upright_scene(prior, rng, yaw=math.pi, elevation_deg=28.0)  # its pose, resized below
    size = prior.typical_size_m * np.array([1.0, 1.0, 0.75])
    gt = Pose9D(view.R, view.t + 0.5 * (size[1] - view.size[1]) * view.R[:, 1], size)  # same bottom
    pts_u, nrm_u = _dense_surface(prior, 30000, 1)
    pts = gt.points_to_camera(pts_u)
    pts = pts[np.einsum("ij,ij->i", (nrm_u / size) @ gt.R.T, pts) < 0.0]
    pts = _ray_noise(pts[_zbuffer_visible(pts)], rng)
    plane = np.array([*gt.R[:, 1], -float(gt.R[:, 1] @ (gt.t - 0.5 * size[1] * gt.R[:, 1]))])
    held = fit_pose(pts, prior, support_plane_cam=plane).pose
    loose = fit_pose(pts, prior, FitConfig(aspect_weight=0.0003), support_plane_cam=plane).pose
    family_yz = prior.aspect[1] / prior.aspect[2]
    off = [abs(math.log(p.size[1] / p.size[2] / family_yz)) for p in (held, loose)]
    assert off[0] < 0.5 * off[1]  # held firm: at most half the log-ratio error of the loose fit
    for p in (held, loose):  # 3 %: the width is seen whole, end to end
        assert p.size[0] == pytest.approx(size[0], rel=0.03)


def test_normal_equations_match_an_explicit_jacobian() -> None:
    # Closed-form moments against the (K, 3, 9) Jacobian built point by point.
    rng = np.random.default_rng(4)
    K = 40
    R = so3_exp(rng.normal(size=3))
    s = rng.uniform(0.05, 0.3, 3)
    a = rng.uniform(-0.5, 0.5, (K, 3)) * s
    q = a @ R.T
    r = rng.normal(size=(K, 3)) * 0.01
    w = rng.uniform(0.0, 1.0, K)
    u = rng.normal(size=3) * 0.05
    J = np.zeros((K, 3, 9))
    for k in range(K):
        qx, qy, qz = q[k]
        J[k, :, 0:3] = -np.array([[0.0, -qz, qy], [qz, 0.0, -qx], [-qy, qx, 0.0]])
        J[k, :, 3:6] = np.eye(3)
        J[k, :, 6:9] = R * a[k]
    for extra in (None, u):
        Jk = J.copy()
        if extra is not None:
            Jk[:, :, 7] += extra
        H_ref = np.einsum("k,kai,kaj->ij", w, Jk, Jk)
        g_ref = np.einsum("k,kai,ka->i", w, Jk, r)
        H, g = _normal_equations(q, a, r, w, R, extra)
        # float64 sums of 40 terms of size <= 1: agreement to rounding
        np.testing.assert_allclose(H, H_ref, atol=1e-12)
        np.testing.assert_allclose(g, g_ref, atol=1e-12)


@pytest.mark.parametrize("round_section", [False, True])
def test_containment_jacobian_matches_finite_differences(round_section: bool) -> None:
    # The containment term's residuals are piecewise smooth in the box parameters (linear for a box, the
    # radial distance for a body of revolution); away from the kinks its analytic Jacobian must match
    # central differences of the residuals (with a plane: bottom held). The ray-dependent noise margin is
    # held constant within a step (a Gauss-Newton approximation), so it is off here; the outlier cap is
    # raised so that enough residuals of each kind pull.
    rng = np.random.default_rng(7)
    R = so3_exp(rng.normal(size=3))
    up = R[:, 1]
    obs = rng.normal(size=(200, 3)) * 0.06 + np.array([0.0, 0.0, 0.8])
    cfg = FitConfig(contain_ray_margin_m=0.0, contain_cap_m=0.05)
    for plane in (None, (up, -float(up @ np.array([0.0, 0.05, 0.8])))):
        pb = _Problem(obs, None, np.zeros((1, 3)), np.zeros((1, 3)), up if plane else None, plane, np.eye(9),
                      np.zeros(3), cfg, round_section=round_section)  # fmt: skip
        st = _State(R, np.array([0.01, -0.02, 0.79]), np.log(np.array([0.08, 0.1, 0.06])))

        def residuals(x: np.ndarray, st=st, pb=pb) -> np.ndarray:
            s2 = _State(so3_exp(x[0:3]) @ st.R, st.b + x[3:6], st.log_s + x[6:9])
            s = np.exp(s2.log_s)
            _, part = _containment_cost(pb, s2, s, pb.centre(s2))
            _, _, e = _containment_jacobian(pb, s2, s, part)
            return e

        s0 = np.exp(st.log_s)
        _, part0 = _containment_cost(pb, st, s0, pb.centre(st))
        J, _, e0 = _containment_jacobian(pb, st, s0, part0)
        assert J is not None and len(e0) > 20  # many points outside the small box
        h = 1e-7
        J_num = np.column_stack(
            [(residuals(h * np.eye(9)[i]) - residuals(-h * np.eye(9)[i])) / (2 * h) for i in range(9)]
        )
        # central differences of smooth pieces: rounding and, for the radial residual, its curvature over
        # the step (h^2 / rho ~ 1e-12) only (residuals ~1e-2 m, h 1e-7)
        np.testing.assert_allclose(J, J_num, atol=1e-6)


def test_round_containment_holds_points_in_the_inscribed_cylinder() -> None:
    # A body of revolution fills its box's inscribed cylinder, not the box: a point in the box's corner
    # (45 deg between the x and z axes, 0.9 of the half-width along each) lies 0.27 half-widths outside the
    # cylinder and pays; the box alone lets it in. A point on the axis-aligned side inside both pays nothing.
    cfg = FitConfig(contain_ray_margin_m=0.0, contain_margin_m=0.001, contain_cap_m=0.05)
    half = 0.04
    centre = np.array([0.0, 0.0, 0.8])
    size = np.full(3, 2.0 * half)
    st = _State(np.eye(3), centre, np.log(size))
    corner = centre + np.array([0.9 * half, 0.0, 0.9 * half])
    side = centre + np.array([0.95 * half, 0.0, 0.0])
    # the corner's excess beyond the margin: 0.9 sqrt(2) half - half - 1 mm = 9.9 mm, squared and weighted
    corner_cost = cfg.contain_weight * (math.hypot(0.9 * half, 0.9 * half) - half - 0.001) ** 2
    for point, round_cost in ((corner, corner_cost), (side, 0.0)):
        for round_section, want in ((False, 0.0), (True, round_cost)):
            pb = _Problem(point[None, :], None, np.zeros((1, 3)), np.zeros((1, 3)), None, None, np.eye(9),
                          np.zeros(3), cfg, round_section=round_section)  # fmt: skip
            cost, _ = _containment_cost(pb, st, size, centre)
            assert cost == pytest.approx(want, rel=1e-9, abs=0.0)


# --------------------------------------------------------------------------------------------------------
# Scenes rendered into a depth image (occlusion, image border) and mugs whose handle is hidden

_CAM = CameraIntrinsics(300.0, 300.0, 159.5, 119.5, 320, 240)


def _mug_pose(rng: np.random.Generator, handle_from_away_deg: float, elevation_deg: float = 40.0):
    """A mug standing on a table 0.7-0.8 m from the camera, its handle (+x) turned `handle_from_away_deg`
    from straight away from the camera (0: directly behind the body), and the table plane."""
    elevation = math.radians(elevation_deg)
    up = np.array([0.0, -math.cos(elevation), -math.sin(elevation)])
    t = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.03, 0.03), rng.uniform(0.7, 0.8)])
    away = t - (t @ up) * up
    away /= np.linalg.norm(away)
    x = so3_exp(up * math.radians(handle_from_away_deg)) @ away
    R = np.column_stack([x, up, np.cross(x, up)])
    return R, t, up


def _render(objects: list[tuple[np.ndarray, int]], plane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth image [m] and label image of dense surface samples (label per object) z-buffered into `_CAM`;
    pixels no sample reaches show the table `plane` (label 0), or 3 m where the ray misses it."""
    h, w = _CAM.height, _CAM.width
    v, u = np.mgrid[0:h, 0:w]
    rays = np.stack([(u - _CAM.cx) / _CAM.fx, (v - _CAM.cy) / _CAM.fy, np.ones((h, w))], axis=-1)
    denom = rays @ plane[:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = -plane[3] / denom
    depth = np.where((lam > 0) & np.isfinite(lam), lam, 3.0)
    label = np.zeros((h, w), dtype=np.int64)
    for pts, lab in objects:
        iu = np.floor(_CAM.fx * pts[:, 0] / pts[:, 2] + _CAM.cx + 0.5).astype(np.int64)
        iv = np.floor(_CAM.fy * pts[:, 1] / pts[:, 2] + _CAM.cy + 0.5).astype(np.int64)
        ok = (iu >= 0) & (iu < w) & (iv >= 0) & (iv < h)
        for a, b, z in zip(iv[ok], iu[ok], pts[ok, 2], strict=True):
            if z < depth[a, b]:
                depth[a, b] = z
                label[a, b] = lab
    return depth, label


def _observed(depth: np.ndarray, mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    pts = back_project(depth, _CAM, mask)
    return _ray_noise(pts, rng)


def test_hidden_handle_is_put_behind_the_body(library: PriorLibrary) -> None:
    # The handle straight behind the body: no observed point tells its yaw, but the box (which includes
    # the handle, as the NOCS ground truth does) has its centre 1.7 cm behind the body's axis. The fit puts
    # the handle in the middle of the turns that keep it hidden, i.e. behind.
    prior = library.family_prior("mug")
    rng = np.random.default_rng(12)
    for k in range(2):
        R, t, up = _mug_pose(rng, handle_from_away_deg=0.0, elevation_deg=35.0 + 10.0 * k)
        gt = Pose9D(R, t, prior.typical_size_m * rng.uniform(0.9, 1.1))
        scene, plane = _alone(prior, gt, up, k)
        pts = _observed(scene.depth_m, scene.mask, rng)
        fit = fit_pose(pts, prior, support_plane_cam=plane, scene=scene)
        # 6 mm: the band's middle is found to half a 20 deg scan step, which swings the box centre (1.7 cm
        # in front of the handle side of the body's axis) by <= 3 mm; the body's own fit adds ~2 mm
        assert np.linalg.norm(fit.pose.t - gt.t) < 0.006
        assert _iou(fit.pose, gt, "y_continuous") >= IOU_MIN


def _plane_below(gt: Pose9D, up: np.ndarray) -> np.ndarray:
    bottom = gt.t - 0.5 * gt.size[1] * up
    return np.array([*up, -float(up @ bottom)])


def _alone(prior, gt: Pose9D, up: np.ndarray, seed: int) -> tuple[SceneView, np.ndarray]:
    """The prior posed by `gt`, alone on the plane below it (surface samples drawn with `seed`): the scene
    (depth image, its mask) and that plane."""
    samples, _ = _dense_surface(prior, 60000, seed)
    plane = _plane_below(gt, up)
    depth, label = _render([(gt.points_to_camera(samples), 1)], plane)
    return SceneView(depth, _CAM, label == 1), plane


def test_seen_handle_keeps_its_yaw(library: PriorLibrary) -> None:
    # The handle 70 deg off "behind": seen from the side, its points pin the yaw; the hidden-handle rule
    # must not move it.
    prior = library.family_prior("mug")
    rng = np.random.default_rng(4)
    R, t, up = _mug_pose(rng, handle_from_away_deg=70.0)
    gt = Pose9D(R, t, prior.typical_size_m)
    scene, plane = _alone(prior, gt, up, 1)
    pts = _observed(scene.depth_m, scene.mask, rng)
    _check(fit_pose(pts, prior, support_plane_cam=plane, scene=scene), gt, "none")


@pytest.mark.parametrize("away_deg", [36.0, 37.0, -37.0])
def test_handle_seen_edge_on_sets_the_yaw(library: PriorLibrary, away_deg: float) -> None:
    # The handle 36-37 deg off "behind": only its edge shows beside the body, 11-18 points outside it
    # (fewer than the 20 of a seen handle). Taken for hidden, the handle went to the middle of the hiding
    # turns, 10-29 deg off; its few points match the prior's handle at one turn, and that turn is taken.
    prior = library.family_prior("mug")
    rng = np.random.default_rng(6)
    R, t, up = _mug_pose(rng, handle_from_away_deg=away_deg, elevation_deg=35.0)
    gt = Pose9D(R, t, prior.typical_size_m)
    scene, plane = _alone(prior, gt, up, 1)
    pts = _observed(scene.depth_m, scene.mask, rng)
    axis = round_body_axis(prior)
    assert axis is not None
    sliver = len(protrusion_points(gt, axis, pts, FitConfig().handle_margin_m))
    assert FitConfig().handle_sliver_points <= sliver < FitConfig().handle_min_points  # the construction
    fit = fit_pose(pts, prior, support_plane_cam=plane, scene=scene)
    # 5 deg, the NOCS bar: the handle's points fix the turn to ~1 deg (0.4-1.6 measured)
    assert _rotation_error_deg(fit.pose, gt, "none") < 5.0


def test_occluded_object_keeps_its_size(library: PriorLibrary) -> None:
    # A can whose left half is hidden by a box standing in front of it: only a sliver of its arc is seen.
    # With the depth image the fit knows the rest is behind the box and keeps the radius; without it the
    # prior's unseen arc pulls towards the seen sliver and the can shrinks.
    prior = library.family_prior("can")
    rng = np.random.default_rng(3)
    R, t, up = _mug_pose(rng, handle_from_away_deg=0.0)
    gt = Pose9D(R, t, prior.typical_size_m)
    box = library.family_prior("box")
    right = np.cross(up, -t / np.linalg.norm(t))  # the camera's left-right direction on the table
    # the occluder: 8 cm in front of the can, shifted 2 cm to the side, taller than the can
    occ = Pose9D(R, t - 0.08 * (t - (t @ up) * up) / np.linalg.norm(t - (t @ up) * up) - 0.02 * right
                 + 0.02 * up, np.array([0.08, gt.size[1] + 0.04, 0.03]))  # fmt: skip
    s_can, _ = _dense_surface(prior, 60000, 2)
    s_box, _ = _dense_surface(box, 60000, 3)
    plane = _plane_below(gt, up)
    depth, label = _render([(gt.points_to_camera(s_can), 1), (occ.points_to_camera(s_box), 2)], plane)
    mask = label == 1
    pts = _observed(depth, mask, rng)
    visible_share = len(pts) / np.count_nonzero(_render([(gt.points_to_camera(s_can), 1)], plane)[1] == 1)
    assert 0.2 < visible_share < 0.7  # the construction: the occluder hides part of the can
    with_scene = fit_pose(pts, prior, support_plane_cam=plane, scene=SceneView(depth, _CAM, mask))
    without = fit_pose(pts, prior, support_plane_cam=plane)
    # the radius within 10 % (SIZE_RTOL) with the scene; without it noticeably smaller
    assert with_scene.pose.size[0] == pytest.approx(gt.size[0], rel=SIZE_RTOL)
    assert _iou(with_scene.pose, gt, "y_continuous") > _iou(without.pose, gt, "y_continuous")
    # the fit says how much of its box rests on the prior alone: about the share the occluder leaves seen
    # (0.52 measured, visible_share's bounds above)
    assert 0.2 < with_scene.coverage < 0.7


@pytest.mark.parametrize("family", ["bottle", "laptop"])
def test_object_cut_by_the_image_border_keeps_its_size(library: PriorLibrary, family: str) -> None:
    # The object stands high in the image: the top row cuts off its upper part (a bottle's shoulder and
    # neck, a laptop's screen top), so the seen points end at the border, not at the object's end. The object
    # is its family's prior at the typical size, so the prior's aspect, scaled to the uncut width, gives the
    # cut height exactly; without the scene (no image bounds) the fit keeps the seen part only.
    prior = library.family_prior(family)
    rng = np.random.default_rng(3)
    elevation = math.radians(40.0)
    up = np.array([0.0, -math.cos(elevation), -math.sin(elevation)])
    R = np.column_stack([[1.0, 0.0, 0.0], up, np.cross([1.0, 0.0, 0.0], up)])
    gt = Pose9D(R, np.array([0.02, -0.26, 0.75]), prior.typical_size_m)
    scene, plane = _alone(prior, gt, up, 1)
    assert scene.mask[0].any() and not scene.mask[-1].any()  # the construction: cut at the top row only
    pts = _observed(scene.depth_m, scene.mask, rng)
    seen_height = float(np.max(pts @ plane[:3] + plane[3]))
    assert seen_height < 0.85 * gt.size[1]  # more than 15 % of the height is beyond the border
    with_scene = fit_pose(pts, prior, support_plane_cam=plane, scene=scene)
    without = fit_pose(pts, prior, support_plane_cam=plane)
    # the height within 10 % (SIZE_RTOL: the width it is scaled from is fitted to a few %); the seen part
    # alone is short of it
    assert with_scene.pose.size[1] == pytest.approx(gt.size[1], rel=SIZE_RTOL)
    assert without.pose.size[1] < 0.9 * gt.size[1]
    assert _iou(with_scene.pose, gt, prior.symmetry) >= IOU_MIN > _iou(without.pose, gt, prior.symmetry)


def test_mug_seen_as_a_sliver_beside_an_occluder_keeps_its_section(library: PriorLibrary) -> None:
    # A board 10 cm wide stands 8 cm in front of a mug and hides all but a strip of its side (12-18 % of
    # the pixels the mug alone would show). The strip ends at the board's edge, not at the mug's: the cut
    # side takes the prior's aspect. Without that the seen strip fitted a thin slab best (dev split 29: 0.3-
    # 0.5 of the depth); here the old fit kept 0.33 / 0.41 / 0.73 of a horizontal size on the three seeds.
    prior = library.family_prior("mug")
    board = library.family_prior("box")
    for seed in range(3):
        rng = np.random.default_rng(seed)
        R, t, up = _mug_pose(rng, handle_from_away_deg=0.0)
        gt = Pose9D(R, t, prior.typical_size_m)
        forward = t - (t @ up) * up
        forward /= np.linalg.norm(forward)
        right = np.cross(up, forward)
        right /= np.linalg.norm(right)
        occluder = Pose9D(np.column_stack([right, up, np.cross(right, up)]), t - 0.08 * forward + 0.02 * up,
                          np.array([0.10, gt.size[1] + 0.04, 0.03]))  # fmt: skip
        s_mug, _ = _dense_surface(prior, 60000, 2)
        s_board, _ = _dense_surface(board, 60000, 3)
        plane = _plane_below(gt, up)
        depth, label = _render(
            [(gt.points_to_camera(s_mug), 1), (occluder.points_to_camera(s_board), 2)], plane
        )
        mask = label == 1
        alone = np.count_nonzero(_render([(gt.points_to_camera(s_mug), 1)], plane)[1] == 1)
        assert 0.1 < mask.sum() / alone < 0.2  # the construction: a strip is seen
        pts = _observed(depth, mask, rng)
        fit = fit_pose(pts, prior, support_plane_cam=plane, scene=SceneView(depth, _CAM, mask))
        # 0.8: the section from the prior's aspect scaled to the height, which the plane fixes; measured
        # 0.81-0.98 (a strip this narrow still tilts the section's two axes against each other)
        assert np.all(fit.pose.size[[0, 2]] > 0.8 * gt.size[[0, 2]])
        assert fit.pose.size[1] == pytest.approx(gt.size[1], rel=SIZE_RTOL)


def test_points_next_to_a_nearer_surface_lie_on_an_occluders_edge() -> None:
    depth = np.full(_CAM.shape, 1.0)
    depth[:, :100] = 0.5  # a nearer surface on the left
    depth[:, 201:] = 2.0  # a farther one on the right
    depth[:, 120:123] = np.nan  # no reading
    mask = np.zeros(_CAM.shape, dtype=bool)
    mask[:, 102:201] = True  # the object's pixels, at 1 m
    mask[:, 120:123] = True

    def at(u: float) -> np.ndarray:  # the object's point at image column u, middle row
        return np.array([(u - _CAM.cx) / _CAM.fx, 0.0, 1.0])

    x = np.array([at(102), at(103), at(118), at(200)])
    # 3 px from the nearer surface; 4 px from it; beside the pixels without a reading; beside the farther one
    assert _next_to_occluder(SceneView(depth, _CAM, mask), x, 0.01).tolist() == [True, False, False, False]
    # a nearer surface within the margin is the object's own continuation, not an occluder
    depth[:, :100] = 0.995
    assert not _next_to_occluder(SceneView(depth, _CAM, mask), x, 0.01).any()


def test_mask_coverage_is_the_seen_share_of_the_facing_surface(library: PriorLibrary) -> None:
    # A can rendered alone: its mask shows the whole side the camera faces. Cut at the column of its axis
    # the mask shows about half of it, empty none; the fit reports the coverage of its own pose.
    prior = library.family_prior("can")
    rng = np.random.default_rng(5)
    R, t, up = _mug_pose(rng, handle_from_away_deg=0.0)
    gt = Pose9D(R, t, prior.typical_size_m)
    scene, plane = _alone(prior, gt, up, 4)
    depth, mask = scene.depth_m, scene.mask
    # 0.97: a prior point on the silhouette may round to the pixel just outside it (a ring one pixel wide,
    # under 3 % of a can ~60 pixels across)
    assert mask_coverage(gt, prior, scene) > 0.97
    u_axis = int(_CAM.fx * t[0] / t[2] + _CAM.cx)
    half = mask.copy()
    half[:, :u_axis] = False
    # +-0.1: the camera looks down 30-65 deg on the can, so the two halves of its seen side differ by
    # perspective only (a few %); the top face adds to both halves alike
    assert mask_coverage(gt, prior, SceneView(depth, _CAM, half)) == pytest.approx(0.5, abs=0.1)
    assert mask_coverage(gt, prior, SceneView(depth, _CAM, np.zeros_like(mask))) == 0.0
    pts = _observed(depth, mask, rng)
    fit = fit_pose(pts, prior, support_plane_cam=plane, scene=scene)
    assert fit.coverage == mask_coverage(fit.pose, fit.prior, scene)
    assert fit.coverage > 0.9  # the fit within the bounds above covers the mask as the truth does
    assert math.isnan(fit_pose(pts, prior, support_plane_cam=plane).coverage)  # no scene, no coverage


def test_observable_points_know_the_image_and_occluders(library: PriorLibrary) -> None:
    box = library.family_prior("box")
    depth = np.full(_CAM.shape, 1.0)
    depth[:, :100] = 0.5  # something nearer on the left
    depth[:, 100:110] = 0.0  # no reading
    mask = np.zeros(_CAM.shape, dtype=bool)
    mask[:, 200:] = True  # the object's pixels
    scene = SceneView(depth, _CAM, mask)

    def at(u: float, z: float) -> np.ndarray:  # a point at image column u, middle row, depth z
        return np.array([(u - _CAM.cx) * z / _CAM.fx, 0.0, z])

    x = np.array([at(50, 0.8), at(105, 0.8), at(150, 0.8), at(150, 1.2), at(250, 1.3), at(400, 0.8)])
    got = _observable(scene, x, 0.01)
    # behind the near surface; no reading; in front of the far one; behind the far one (occluded by it);
    # on the object's own mask (observable at any depth); off the image
    assert got.tolist() == [False, False, True, False, True, False]
    with pytest.raises(InvalidInputError, match="depth_m"):
        SceneView(depth[:10], _CAM, mask)
    with pytest.raises(InvalidInputError, match="mask"):
        SceneView(depth, _CAM, mask.astype(np.uint8))
    with pytest.raises(InvalidInputError, match="SceneView"):
        fit_pose(np.full((50, 3), 1.0), box, scene=depth)  # type: ignore[arg-type]


def _instance_mug() -> tuple[np.ndarray, np.ndarray]:
    """Dense surface samples of a mug unlike the family's mean shape (radius 45 mm, 100 mm tall, a ring
    handle of 28 mm radius and 7 mm tube at mid-height, in the x-y plane on the +x side, half sunk in the
    body), centred on its amodal box; and the box size [m]."""
    r, h = 0.045, 0.10
    body = trimesh.creation.cylinder(radius=r, height=h, sections=64)
    body.apply_transform(trimesh.transformations.rotation_matrix(-math.pi / 2.0, [1.0, 0.0, 0.0]))
    handle = trimesh.creation.torus(major_radius=0.028, minor_radius=0.007)
    handle.apply_translation([r, 0.0, 0.0])
    mesh = trimesh.util.concatenate([body, handle])
    lo, hi = mesh.bounds
    pts, _ = trimesh.sample.sample_surface(mesh, 80000, seed=7)
    return np.asarray(pts) - 0.5 * (lo + hi), hi - lo


def test_seen_handle_sets_the_yaw_of_a_mug_unlike_the_prior(library: PriorLibrary) -> None:
    # The instance's handle is rounder and reaches less far than the family's: the full fit's yaw drifts
    # (body and handle share the x scale); the handle's own points set it.
    prior = library.family_prior("mug")
    samples, size = _instance_mug()
    rng = np.random.default_rng(6)
    errors = []
    for k, away_deg in enumerate((60.0, 100.0, -75.0)):
        R, t, up = _mug_pose(rng, handle_from_away_deg=away_deg, elevation_deg=35.0 + 5.0 * k)
        gt = Pose9D(R, t, size)
        plane = _plane_below(gt, up)
        depth, label = _render([(samples @ R.T + t, 1)], plane)
        pts = _observed(depth, label == 1, rng)
        fit = fit_pose(pts, prior, support_plane_cam=plane, scene=SceneView(depth, _CAM, label == 1))
        errors.append(_rotation_error_deg(fit.pose, gt, "none"))
    # 4.5 deg, under the NOCS 5 deg bar: the handle's points fix its direction to ~1 deg, but the
    # instance's handle is a ring half sunk in the body and the family's a half ellipse, and their best
    # match differs by ~3 deg here (2.7-3.3; without the handle's own yaw step 4.2-7.3 deg)
    assert max(errors) < 4.5, errors


@pytest.mark.parametrize(
    ("away_deg", "turn_deg", "still_camera"),
    [
        (90.0, 90.0, False),
        (120.0, 90.0, False),
        (120.0, -90.0, False),
        (90.0, 90.0, True),
        (120.0, 180.0, True),
    ],
)
def test_tracker_refit_sees_a_handle_the_track_has_on_the_wrong_side(
    library: PriorLibrary, away_deg: float, turn_deg: float, still_camera: bool
) -> None:
    # A seen handle (90-120 deg from straight behind), and a track that has the mug turned a quarter turn
    # about its body's axis (the handle where the camera sees only the body). The tracker selects each
    # frame's points near the tracked pose's surface: that cuts away most of the real handle, the very
    # points that can correct the yaw (on the dev splits a track kept a mug 90-130 deg off this way). The
    # re-fit's selection keeps every point the prior explains at any turn about the axis, so its cold fit
    # sees the whole handle and turns the track back. `still_camera`: the frame carries its camera pose and
    # the camera holds still, so the view never turns by `refit_angle_deg`; the re-fit must then be started
    # by the handle the track does not explain (`Tracker._protrusion_missed`).
    samples, size = _instance_mug()
    axis = np.array([0.045 - 0.5 * size[0], 0.0, 0.0])  # body axis in the object frame: radius 45 mm
    rng = np.random.default_rng(3)
    R, t, up = _mug_pose(rng, handle_from_away_deg=away_deg)
    gt = Pose9D(R, t, size)
    plane = _plane_below(gt, up)
    depth, label = _render([(samples @ R.T + t, 1)], plane)
    depth = depth + rng.normal(size=depth.shape) * (0.001 + 0.0037 * depth**2)  # D435-like axial noise
    T_base_cam = np.eye(4) if still_camera else None
    frame = RGBDFrame(np.zeros((*depth.shape, 3), np.uint8), depth.astype(np.float32), _CAM, 0.0, T_base_cam)
    turn = so3_exp(up * math.radians(turn_deg)) @ R
    wrong = Pose9D(turn, t + R @ axis - turn @ axis, size)  # turned about the body's axis

    def on_handle(p: np.ndarray) -> int:
        # outside the 45 mm body by 6 mm (noise ~3 mm at 0.75 m): points only the handle explains
        local = (p - t) @ R - axis
        return int(np.count_nonzero(np.hypot(local[:, 0], local[:, 2]) > 0.051))

    tracker = Tracker(ProMPose(Grounder(), PriorLibrary()), "mug", prior=library.family_prior("mug"))
    first = tracker.update(frame, mask=label == 1)
    assert _rotation_error_deg(first.pose, gt, "none") < 4.5  # test_seen_handle_sets_the_yaw_...: 2.6-3.7
    seen = on_handle(back_project(frame.depth_m, _CAM, label == 1))
    support = SupportPlane(plane[:3], plane[3], 1.0)
    near_track = on_handle(tracker._select(frame, wrong, support, stride=1)[1])
    any_turn = on_handle(tracker._select(frame, wrong, support, stride=1, any_turn=True)[1])
    # measured: 43-49 % near the turned track (the 2 cm surface margin keeps the handle's root), 100 % at
    # any turn (the family's handle, scaled to the box, reaches as far from the axis as the instance's)
    assert near_track < 0.6 * seen
    assert any_turn >= 0.99 * seen
    # the same frame again from the wrong track: without a camera pose the object-frame view has turned by
    # the wrong turn, so the re-fit runs; with the still camera only the unexplained handle starts it
    tracker._pose = wrong
    est = tracker.update(frame)
    assert tracker.refits == 1 and tracker.refits_taken == 1
    # as the first frame's fit (4.5 deg: the instance's ring handle against the family's, see above); at
    # cac87e0 the re-fit saw 17-24 of the 166-190 handle points (pixel stride 2, near the wrong surface),
    # took them for a hidden handle and left the track 106-132 deg off for away_deg 120; at 6f8f069 the
    # still camera never re-fitted and the track stayed 92 / 179 deg off
    assert _rotation_error_deg(est.pose, gt, "none") < 4.5


# Growing the box to the seen surface (`grow_to_seen`)


def _hammer_scene(library: PriorLibrary, rng: np.random.Generator, noise: bool):
    """A hammer-like object on a table 0.75 m away: a 20 x 2.5 x 2.5 cm handle and a 3 x 2.5 x 11 cm head
    across its end (object x along the handle, y up, z along the head). Returns the depth image (axial
    noise of the D435-like model when `noise`), the object's mask, the plane, the whole object's true box
    and the handle's box."""
    box = library.family_prior("box")
    R, t, up = _mug_pose(rng, handle_from_away_deg=60.0, elevation_deg=45.0)
    handle = Pose9D(R, t, np.array([0.20, 0.025, 0.025]))
    head = Pose9D(R, t + R @ np.array([0.085, 0.0, 0.0]), np.array([0.03, 0.025, 0.11]))
    whole = Pose9D(R, t + R @ np.array([0.0, 0.0, 0.0]), np.array([0.20, 0.025, 0.11]))
    plane = _plane_below(handle, up)
    parts = [(p.points_to_camera(_dense_surface(box, 60000, k)[0]), 1) for k, p in enumerate((handle, head))]
    depth, label = _render(parts, plane)
    if noise:
        depth = depth + rng.normal(size=depth.shape) * (0.001 + 0.0037 * depth**2)
    return depth, label == 1, plane, whole, handle


def test_grow_to_seen_takes_in_the_part_a_fit_left_out(library: PriorLibrary) -> None:
    # A box around the handle alone (a prior that matched the handle and not the head): the head's seen
    # points lie outside it by up to 4.25 cm, and the box grows to hold them.
    rng = np.random.default_rng(0)
    depth, mask, plane, whole, handle = _hammer_scene(library, rng, noise=True)
    grown = grow_to_seen(handle, "box", (plane[:3], plane[3]), FitConfig(), SceneView(depth, _CAM, mask))
    assert np.all(grown.size >= handle.size - 1e-12)  # never smaller
    # the head's length along z within 5 mm: two pixel footprints at 0.75 m (2.5 mm each); the median depth
    # keeps the outline where it is, and the k-th farthest point lies at most a pixel inside it
    assert grown.size[2] == pytest.approx(whole.size[2], abs=0.005)
    assert grown.iou(whole) > 0.85


def test_grow_to_seen_leaves_a_box_that_holds_the_object_alone(library: PriorLibrary) -> None:
    # The true box of the whole object, under sensor noise, its mask bled 3 px onto the table all round:
    # neither the noise nor the table pixels (under the plane clearance) push a face out.
    rng = np.random.default_rng(1)
    depth, mask, plane, whole, _ = _hammer_scene(library, rng, noise=True)
    bled = cv2.dilate(mask.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)  # 3 px all round
    view = SceneView(depth, _CAM, bled)
    grown = grow_to_seen(whole, "box", (plane[:3], plane[3]), FitConfig(), view)
    # 2 mm: the median depth of 5 x 5 pixels has a fifth of the pixel noise (0.6 mm at 0.75 m), so its tail
    # stays within the 3 mm margin; the raw depth's tail moved the top out by 3.2 mm
    assert np.all(grown.size - whole.size <= 0.002)


def test_grow_to_seen_ignores_a_piece_of_another_object_in_the_mask(library: PriorLibrary) -> None:
    # The mask bled onto a patch of a neighbour 6 cm beyond the head: a dense piece of surface, but not
    # connected to the object's points, so no face moves towards it.
    rng = np.random.default_rng(2)
    box = library.family_prior("box")
    depth, mask, plane, whole, _ = _hammer_scene(library, rng, noise=False)
    neighbour = Pose9D(whole.R, whole.t + whole.R @ np.array([0.0, 0.0, 0.115]), np.array([0.05, 0.04, 0.05]))
    nd, nl = _render([(neighbour.points_to_camera(_dense_surface(box, 60000, 7)[0]), 1)], plane)
    depth = np.minimum(depth, nd)
    view = SceneView(depth, _CAM, mask | (nl == 1))
    grown = grow_to_seen(whole, "box", (plane[:3], plane[3]), FitConfig(), view)
    assert grown.size[2] < whole.size[2] + 0.006  # the neighbour would add 8.5 cm


def test_seen_surface_is_the_object_alone_and_all_of_it(library: PriorLibrary) -> None:
    # The surface the grasp layer plans on: the mask bled onto a neighbour's patch and onto the table, and a
    # box around the handle alone. The handle's and the head's points are in it; the table's and the
    # neighbour's are not.
    rng = np.random.default_rng(4)
    box = library.family_prior("box")
    depth, mask, plane, whole, handle = _hammer_scene(library, rng, noise=True)
    neighbour = Pose9D(whole.R, whole.t + whole.R @ np.array([0.0, 0.0, 0.115]), np.array([0.05, 0.04, 0.05]))
    nd, nl = _render([(neighbour.points_to_camera(_dense_surface(box, 60000, 7)[0]), 1)], plane)
    depth = np.minimum(depth, nd)
    bled = cv2.dilate(mask.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool) | (nl == 1)
    pts = seen_surface(handle, (plane[:3], plane[3]), FitConfig(), SceneView(depth, _CAM, bled))
    local = (pts - whole.t) @ whole.R
    excess = np.max(np.abs(local) - 0.5 * whole.size, axis=1)
    # within the whole object's box: all within 1 cm (the neighbour's patch lies 6 cm out), 99 % within 3 mm
    # (silhouette points of the median depth spread by about two pixel footprints, 2.5 mm each at 0.75 m)
    assert np.all(excess <= 0.01) and np.quantile(excess, 0.99) <= 0.003
    # the head's length seen, though the box held the handle
    assert np.ptp(local[:, 2]) > whole.size[2] - 0.01
    assert np.all(pts @ plane[:3] + plane[3] > FitConfig().grow_plane_clearance_m)  # no table pixel
    assert len(seen_surface(handle, None, FitConfig(), None)) == 0


def test_grow_to_seen_is_off_without_a_scene_or_when_switched_off(library: PriorLibrary) -> None:
    rng = np.random.default_rng(3)
    depth, mask, _, _, handle = _hammer_scene(library, rng, noise=False)
    assert grow_to_seen(handle, "box", None, FitConfig(), None) is handle
    off = FitConfig(grow_min_points=0)
    assert grow_to_seen(handle, "box", None, off, SceneView(depth, _CAM, mask)) is handle


def _flattened_scene(prior, rng: np.random.Generator, flat: float):
    """`_upright_scene`'s view of the prior with its section squeezed to `flat` of its width along z (a
    squeeze bottle, an oval can): the ground truth is no longer round, its symmetry a 2-fold turn about y."""
    gt, _, up, plane = _upright_scene(prior, rng, noise=False)
    size = gt.size.copy()
    size[2] = flat * size[0]
    gt = Pose9D(gt.R, gt.t, size)
    pts_u, nrm_u = _dense_surface(prior, 30000, int(rng.integers(1 << 30)))
    pts = gt.points_to_camera(pts_u)
    nrm = (nrm_u / size) @ gt.R.T
    pts = pts[np.einsum("ij,ij->i", nrm, pts) < 0.0]
    return gt, _ray_noise(pts[_zbuffer_visible(pts)], rng), up, plane


@pytest.mark.parametrize("family", ["can", "bottle"])
def test_a_flattened_body_of_revolution_gets_two_section_widths(library: PriorLibrary, family: str) -> None:
    # By construction: the family's own shape squeezed to 55 % of its width (a squeeze bottle's 5.8 of
    # 9.5 cm is 61 %). The round fit cannot follow it (one width); the free section can, and is kept.
    prior = library.family_prior(family)
    rng = np.random.default_rng(21)
    for _ in range(2):
        gt, pts, _, plane = _flattened_scene(prior, rng, 0.55)
        result = fit_pose(pts, prior, support_plane_cam=plane)
        assert result.prior.symmetry == "y_2fold" and result.prior.name == prior.name
        # Its section's aspect near the true 0.55: each width within the round tests' 10 % puts the ratio
        # within (1.1 / 0.9 - 1) x 0.55 = 0.12 of it; and the box's IoU the round tests ask of round shapes.
        w = result.pose.size[[0, 2]]
        assert min(w) / max(w) == pytest.approx(0.55, abs=0.12)
        assert result.pose.iou(gt) >= IOU_MIN
        round_only = fit_pose(pts, prior, FitConfig(free_section_ratio=0.0), support_plane_cam=plane)
        assert round_only.prior.symmetry == "y_continuous"  # switched off: one width, as before
        assert _iou(round_only.pose, gt, "y_continuous") < IOU_MIN  # and it misses the flat shape


@pytest.mark.parametrize("family", ["can", "bottle"])
def test_a_round_body_keeps_its_round_section(library: PriorLibrary, family: str) -> None:
    prior = library.family_prior(family)
    rng = np.random.default_rng(22)
    for _ in range(3):
        gt, pts, _, plane = _upright_scene(prior, rng)
        result = fit_pose(pts, prior, support_plane_cam=plane)
        assert result.prior.symmetry == "y_continuous"
        assert result.pose.size[0] == pytest.approx(result.pose.size[2], rel=1e-9)  # one width
        _check(result, gt, "y_continuous")
