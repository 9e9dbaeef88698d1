"""Grounding pieces on constructed inputs (no sim): plane, colour names, shapes, parsing, scoring."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import depth_to_point_map
from prompose_grasp.perception.estimator import ProMPose
from prompose_grasp.perception.grounding import Grounder, GroundingConfig, SupportPlane, ground, parse_prompt
from prompose_grasp.perception.grounding.describe import (
    HEIGHT_BINS,
    PALETTE,
    colour_names,
    dominant_colour,
    handle_seen,
    outline_hidden,
    shape_families,
    shape_family,
    size_class,
    taper,
    top_height_cell_fraction,
    top_height_histogram,
)
from prompose_grasp.perception.grounding.plane import (
    PlaneFrame,
    fit_support_plane,
    plane_candidates,
    plane_under_object,
)
from prompose_grasp.perception.grounding.score import (
    CandidateFeatures,
    NounPrior,
    RivalReadings,
    ScoringWeights,
    metric_size_term,
    score_candidates,
)
from prompose_grasp.perception.grounding.segment import concave_creases
from prompose_grasp.perception.grounding.segment.cells import _support_colour, _thin_parts
from prompose_grasp.perception.grounding.segment.cluster import _attach_fragments, _chain_pieces
from prompose_grasp.perception.grounding.segment.join import _join_hinged, _shade_distance
from prompose_grasp.perception.priors import PriorLibrary
from prompose_grasp.robot import RGBDFrame

K = CameraIntrinsics(400.0, 400.0, 159.5, 119.5, 320, 240)


def tilted_table(n_cam: np.ndarray, d: float) -> np.ndarray:
    """(H, W) float32 depth [m] of the plane n . x + d = 0 seen by K (exact, by ray intersection)."""
    u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u, dtype=float)], -1)
    return (-d / (rays @ n_cam)).astype(np.float32)


def table_normal(tilt_deg: float) -> np.ndarray:
    """Unit normal pointing at a camera looking down at a table `tilt_deg` below the horizon."""
    t = math.radians(tilt_deg)
    return np.array([0.0, -math.cos(t), -math.sin(t)])


def test_plane_fit_recovers_a_noisy_plane():
    n = table_normal(35.0)
    depth = tilted_table(n, 0.5)
    rng = np.random.default_rng(0)
    noisy = depth + rng.normal(0.0, 0.004, depth.shape).astype(np.float32)  # 4 mm: D435 at ~0.9 m
    P = depth_to_point_map(noisy, K)[::4, ::4].reshape(-1, 3)  # the grounder's sampling grid
    plane = fit_support_plane(P, GroundingConfig())
    assert plane is not None
    # 4800 points with 4 mm noise over ~0.5 m: the normal is good to ~0.05 deg; 0.5 deg is a loose bound
    assert math.degrees(math.acos(min(1.0, plane.normal_cam @ n))) < 0.5
    assert abs(plane.offset_m - 0.5) < 0.003  # zero-mean noise averaged over thousands of points
    assert plane.inlier_fraction > 0.9  # 12 mm inlier band = 3 sigma


def test_a_flat_object_near_the_camera_does_not_tilt_the_table():
    # A laptop's base, 14 mm high, fills the lower left quarter of the image, in front of the camera where
    # the table's noise is ~2 mm: in the fixed 12 mm RANSAC band its top's points are half inliers and
    # tilted the least-squares plane (~1 deg on the dev splits); the last refits keep the sensor's own noise
    # band (2.5 sigma(z), at least 4 mm) and leave them out. (A slab over a third of the table still wins:
    # the fixed band's tilted compromise through the slab's near and the table's far side stays the
    # RANSAC winner; docs/grounding.md.)
    config = GroundingConfig()
    n = table_normal(45.0)
    d = 0.45
    depth = tilted_table(n, d)
    slab = np.zeros(depth.shape, dtype=bool)
    slab[K.height // 2 :, : K.width // 2] = True
    depth[slab] = tilted_table(n, d - 0.014)[slab]
    rng = np.random.default_rng(1)
    noisy = (depth + rng.normal(size=depth.shape) * config.sigma_m(depth)).astype(np.float32)
    P = depth_to_point_map(noisy, K)[::4, ::4].reshape(-1, 3)
    plane = fit_support_plane(P, config)
    assert plane is not None
    # the table alone (half of the points, noise 1.6-2.2 mm) fixes the normal to ~0.05 deg; 0.2 deg is a
    # quarter of the tilt the slab caused with the fixed band
    assert math.degrees(math.acos(min(1.0, plane.normal_cam @ n))) < 0.2
    assert abs(plane.offset_m - d) < 0.002  # the table's offset, not pulled towards the slab's top


def test_a_table_with_the_floor_seen_around_it_is_the_support():
    """A table filling the middle of the view, 0.75 m above a floor seen behind and beside it (nearly as much
    of the floor as of the table). Every reading off the table's plane is the floor, below it: counted as a
    vote against the table, the floor's edge-of-view support outscored the table. Only what lies within
    0.5 m of a plane says which side the scene is on, and the floor is farther."""
    n = table_normal(40.0)
    table = tilted_table(n, 0.8)
    floor = tilted_table(n, 0.8 + 0.75)
    v, u = np.mgrid[0 : K.height, 0 : K.width]
    on_table = (v > 0.25 * K.height) & (np.abs(u - K.cx) < 0.35 * K.width)
    depth = np.where(on_table, table, floor)
    P = depth_to_point_map(depth, K)[::4, ::4].reshape(-1, 3)
    plane = fit_support_plane(P, GroundingConfig())
    assert plane is not None and abs(plane.offset_m - 0.8) < 0.003  # exact depth: the table's own offset


def test_plane_frame_axes_follow_the_image():
    from prompose_grasp.perception.grounding.types import SupportPlane

    frame = PlaneFrame(SupportPlane(table_normal(35.0), 0.5, 1.0))
    assert frame.right @ np.array([1.0, 0.0, 0.0]) > 0.99  # image right
    assert frame.forward[2] > 0.5  # away from the camera
    np.testing.assert_allclose(frame.R_cam_plane.T @ frame.R_cam_plane, np.eye(3), atol=1e-12)
    # a point 10 cm above the plane has height 0.1 in plane coordinates
    p = frame.origin_cam + 0.3 * frame.forward + 0.1 * frame.up
    np.testing.assert_allclose(frame.coords(p[None])[0], [0.0, 0.3, 0.1], atol=1e-12)


def test_synthetic_blocks_on_a_table_are_found_by_colour():
    """Two coloured blocks raised 4 cm above a tilted grey table; prompts by colour pick each block."""
    n = table_normal(40.0)
    depth = tilted_table(n, 0.6).astype(np.float64)
    rgb = np.full((K.height, K.width, 3), 128, np.uint8)
    masks = {}
    for name, colour, (r0, r1, c0, c1) in (("red", (200, 30, 30), (100, 140, 60, 110)),
                                           ("blue", (30, 40, 200), (110, 150, 200, 250))):  # fmt: skip
        m = np.zeros(depth.shape, bool)
        m[r0:r1, c0:c1] = True
        # a block top 4 cm above the table: the plane n.x + d - 0.04 = 0
        depth[m] = tilted_table(n, 0.6 - 0.04)[m]
        rgb[m] = colour
        masks[name] = m
    depth = depth.astype(np.float32)
    for name in ("red", "blue"):
        result = ground(rgb, depth, K, f"the {name} block")
        best = result.candidates[0]
        overlap = (best.mask & masks[name]).sum() / (best.mask | masks[name]).sum()
        assert overlap > 0.9  # noise-free: only the grid-step rim of the mask may differ
        assert best.attributes.colour_name == name
    assert len(result.candidates) == 2


def test_inner_floor_of_a_tray_joins_its_walls():
    """A red tray: 4 cm rim (top view: a 6-px band) around a floor 3 mm above a grey table (below the cut)."""
    n = table_normal(40.0)
    depth = tilted_table(n, 0.6).astype(np.float64)
    rgb = np.full((K.height, K.width, 3), 128, np.uint8)
    tray = np.zeros(depth.shape, bool)
    tray[90:150, 100:180] = True
    floor = np.zeros(depth.shape, bool)
    floor[96:144, 106:174] = True
    rim = tray & ~floor
    depth[rim] = tilted_table(n, 0.6 - 0.04)[rim]
    depth[floor] = tilted_table(n, 0.6 - 0.003)[floor]
    rgb[tray] = (200, 30, 30)
    result = ground(rgb, depth.astype(np.float32), K, "the red tray")
    best = result.candidates[0]
    # the floor is 3 mm up, below the 8 mm height cut, yet inside the rim's outline and of its colour
    assert (best.mask & floor).sum() / floor.sum() > 0.95  # noise-free: all but the grid-step rim of cells
    assert (best.mask & ~tray).sum() < 0.05 * tray.sum()  # the grey table around it stays out
    assert len(result.candidates) == 1


def test_the_table_between_open_jaws_is_not_an_inner_floor():
    """A dark spring clamp lying open: two arms 2.5 cm high meeting at the jaw, on a table of nearly its
    colour. The table between the arms lies inside the mask's convex outline and the footprint's hull, low
    and of the object's colour, like a tray's floor, but the arms do not enclose it: it stays out (a real
    frame's clamp had the whole triangle between its handles as mask)."""
    n = table_normal(40.0)
    depth = tilted_table(n, 0.6).astype(np.float64)
    rgb = np.full((K.height, K.width, 3), 128, np.uint8)
    arms = np.zeros(depth.shape, np.uint8)
    cv2.line(arms, (90, 120), (230, 60), 1, 8)
    cv2.line(arms, (90, 120), (230, 180), 1, 8)
    arms = arms.view(bool)
    depth[arms] = tilted_table(n, 0.6 - 0.025)[arms]
    rgb[arms] = 100  # 28 grey levels darker: within one colour edge of the table (Lab L at half weight)
    between = np.zeros(depth.shape, np.uint8)
    cv2.fillConvexPoly(between, np.array([[90, 120], [230, 60], [230, 180]], np.int32), 1)
    between = between.view(bool) & ~cv2.dilate(arms.view(np.uint8), np.ones((25, 25), np.uint8)).view(bool)
    result = ground(rgb, depth.astype(np.float32), K, "the clamp")
    best = result.candidates[0]
    assert (best.mask & arms).sum() / arms.sum() > 0.9
    assert (best.mask & between).sum() < 0.02 * between.sum()  # the open triangle's middle is table


def test_a_handles_fragments_join_their_body_and_far_or_low_ones_do_not():
    """Fragments the sensor broke off a thin part (no geometric neighbour) join the body they stand next to:
    a handle's root within 2.5 cm of the body, though most of it reaches 3-4 cm off (dev 29 mugs: the
    median cell 26-27 mm away); a piece all 3-4 cm away, or a speck of table noise, does not."""
    z = np.linspace(0.02, 0.10, 100)
    body = np.column_stack([np.zeros(100), np.zeros(100), z])  # segment 0: a body's side, x = 0
    lift = np.full(8, 0.06)
    handle = np.column_stack([[0.012, 0.018, 0.022, 0.032, 0.034, 0.036, 0.038, 0.04], np.zeros(8), lift])
    far = np.column_stack([np.linspace(0.03, 0.04, 8), np.zeros(8), lift])
    speck = np.column_stack([np.full(8, 0.005), np.zeros(8), np.full(8, 0.03)])
    P = np.concatenate([body, handle, far, speck])
    heights = np.concatenate([z, lift, lift, np.full(8, 0.01)])  # the speck stands 1 cm up: table noise
    compact = np.repeat([0, 1, 2, 3], [100, 8, 8, 8])
    alone = np.array([False, True, True, True])
    target = np.arange(4)
    _attach_fragments(target, compact, alone, P, heights)
    assert target.tolist() == [0, 0, 2, 3]


def test_an_edge_on_screens_pieces_chain_into_one_segment_and_scattered_specks_do_not():
    """A screen seen edge-on leaves depth in pieces of a few cells, 1-2 cm apart up its 20 cm (dev 28 scene
    122): chained, they are one segment of at least the minimum size. So is a stapler 1.2 m away whose
    depth the sensor drops along all its edges (6 pieces, 18 cells: over half the minimum; its painted mask
    is judged by size). Pieces as far apart as table specks (5 cm), pieces standing under 2 cm (table
    noise) and a chain under half the minimum (9 cells) stay apart."""
    up = np.linspace(0.03, 0.21, 13)  # 13 pieces 1.5 cm apart up a screen, 3 cells each
    screen = np.repeat(np.column_stack([np.zeros(13), np.zeros(13), up]), 3, axis=0)
    specks = np.repeat(np.column_stack([np.full(5, 0.5), np.linspace(0, 0.2, 5), np.full(5, 0.1)]), 3, axis=0)
    low = np.repeat(np.column_stack([np.full(5, 1.0), np.zeros(5), np.linspace(0.002, 0.012, 5)]), 3, axis=0)
    short = np.repeat(np.column_stack([np.full(3, 1.5), np.zeros(3), [0.05, 0.065, 0.08]]), 3, axis=0)
    stapler = np.repeat(
        np.column_stack([np.linspace(2.0, 2.1, 6), np.zeros(6), np.full(6, 0.035)]), 3, axis=0
    )
    P = np.concatenate([screen, specks, low, short, stapler])
    heights = P[:, 2]  # the support is z = 0
    compact = np.repeat(np.arange(32), 3)  # 13 + 5 + 5 + 3 + 6 pieces of 3 cells
    counts = np.full(32, 3)
    target = np.arange(32)
    roots = _chain_pieces(target, compact, np.ones(32, bool), counts, 30, P, heights)
    # the screen's 39 cells reach 30, the stapler's 18 half of it; the short chain's 9 do not
    assert roots.tolist() == [True] + [False] * 25 + [True] + [False] * 5
    assert target.tolist() == [0] * 13 + list(range(13, 26)) + [26] * 6


def test_a_thin_base_under_the_height_cut_joins_what_stands_above_it_and_the_table_does_not():
    """A laptop's 12-22 mm base at 1 m is under the height cut (2.5 sigma = 11.7 mm there) in about half its
    cells: the cells 1.5 sigma up (7 mm) that are not of the table's colour and touch a cell above the cut
    count as above it. The same height in the table's colour, or apart from anything above the cut, does
    not."""
    h, w = 40, 40
    height = np.zeros((h, w))
    height[10:20, 10:20] = 0.10  # a box above the cut
    height[10:20, 20:30] = 0.009  # a thin base beside it, under the cut, of another colour
    height[20:30, 10:20] = 0.009  # as thin, beside the box, of the table's colour
    height[30:38, 30:38] = 0.009  # as thin, of another colour, touching nothing above the cut
    xs, ys = np.meshgrid(np.arange(w) * 0.005, np.arange(h) * 0.005)
    Pg = np.stack([xs, ys, 1.0 - height], axis=-1)  # looking straight down from 1 m
    plane = SupportPlane(np.array([0.0, 0.0, -1.0]), 1.0, 1.0)
    lab = np.zeros((h, w, 3), np.float32)
    lab[..., 0] = 120.0  # the table's colour
    lab[10:20, 10:30, 1] = 40.0  # box and base: 40 Lab units off, over the 28 of `colour_edge`
    lab[30:38, 30:38, 1] = 40.0
    fg = height > 0.05
    cfg = GroundingConfig()
    assert 0.009 < cfg.height_sigmas * cfg.sigma_m(1.0)  # the base is under the full cut here
    out = _thin_parts(fg, Pg, lab, plane, cfg, _support_colour(Pg, lab, plane, cfg))
    expected = fg.copy()
    expected[10:20, 20:30] = True
    np.testing.assert_array_equal(out, expected)


def test_colour_names_of_pure_and_shaded_colours():
    rgb = np.array(
        [[220, 30, 30], [230, 130, 20], [132, 117, 14], [30, 140, 40], [20, 60, 200], [120, 40, 160],
         [230, 120, 180], [120, 80, 40], [10, 10, 10], [240, 240, 240], [128, 128, 128], [30, 180, 190]],
        np.uint8,
    )  # fmt: skip
    expected = ["red", "orange", "yellow", "green", "blue", "purple", "pink", "brown", "black", "white"]
    expected += ["grey", "cyan"]
    assert [PALETTE[i] for i in colour_names(rgb)] == expected
    name, med, shares = dominant_colour(np.array([[200, 20, 20]] * 7 + [[20, 20, 200]] * 3, np.uint8))
    assert name == "red" and tuple(med) == (200, 20, 20)
    assert shares["red"] == pytest.approx(0.7) and shares["blue"] == pytest.approx(0.3)


def cylinder_points(r: float, h: float, rng) -> np.ndarray:
    """Front half of a cylinder's side plus its top disc, in plane coordinates (right, forward, up)."""
    a = rng.uniform(-math.pi, 0.0, 800)
    z = rng.uniform(0, h, 800)
    side = np.stack([r * np.cos(a), r * np.sin(a), z], 1)
    rr, aa = r * np.sqrt(rng.uniform(0, 1, 300)), rng.uniform(0, 2 * math.pi, 300)
    top = np.stack([rr * np.cos(aa), rr * np.sin(aa), np.full(300, h)], 1)
    return np.concatenate([side, top])


def box_points(a: float, b: float, h: float, rng) -> np.ndarray:
    """Front and left faces of an upright box plus its top."""
    front = np.stack([rng.uniform(0, a, 600), np.zeros(600), rng.uniform(0, h, 600)], 1)
    left = np.stack([np.zeros(300), rng.uniform(0, b, 300), rng.uniform(0, h, 300)], 1)
    top = np.stack([rng.uniform(0, a, 300), rng.uniform(0, b, 300), np.full(300, h)], 1)
    return np.concatenate([front, left, top])


def extents(P: np.ndarray) -> np.ndarray:
    e = np.sort(np.ptp(P[:, :2], axis=0))[::-1]
    return np.array([e[0], e[1], P[:, 2].max()])


def test_shape_families_of_constructed_point_sets():
    rng = np.random.default_rng(0)
    cyl = cylinder_points(0.035, 0.12, rng)
    assert shape_family(cyl, np.array([0.07, 0.07, 0.12])) == "cylinder"  # amodal footprint of the can
    box = box_points(0.16, 0.07, 0.22, rng)
    assert shape_family(box, extents(box)) == "box"
    u = rng.normal(size=(1500, 3))
    ball = 0.04 * u / np.linalg.norm(u, axis=1, keepdims=True)
    ball = ball[ball[:, 1] < 0.01] + [0.0, 0.0, 0.04]  # the half facing the camera
    assert shape_family(ball, np.array([0.08, 0.08, 0.08])) == "sphere"
    plate = np.stack([rng.uniform(0, 0.2, 500), rng.uniform(0, 0.15, 500), rng.uniform(0, 0.02, 500)], 1)
    assert shape_family(plate, extents(plate)) == "flat"
    stick = np.stack([rng.uniform(0, 0.3, 500), rng.uniform(0, 0.03, 500), rng.uniform(0, 0.03, 500)], 1)
    assert shape_family(stick, extents(stick)) == "elongated"
    assert size_class(np.array([0.05, 0.04, 0.06])) == "small"
    assert size_class(np.array([0.12, 0.04, 0.06])) == "medium"
    assert size_class(np.array([0.3, 0.2, 0.1])) == "large"


#: Camera over the origin of the support-plane frame, 0.7 m above the table (the tabletop's front camera).
_CAM = np.array([0.0, 0.0, 0.7])


def _along_rays(P: np.ndarray, sigma: float, rng) -> np.ndarray:
    """(N, 3) points moved along their camera rays by N(0, sigma) [m]: axial depth noise."""
    ray = (P - _CAM) / np.linalg.norm(P - _CAM, axis=1, keepdims=True)
    return P + rng.normal(0.0, sigma, (len(P), 1)) * ray


def _visible_box(a: float, b: float, h: float, yaw: float, centre: np.ndarray, rng) -> np.ndarray:
    """The faces of an upright a x b x h box (yaw about the up axis) that face the camera, and its top."""
    R = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    parts = []
    for normal, half, length in (
        ((1, 0), a / 2, b),
        ((-1, 0), a / 2, b),
        ((0, 1), b / 2, a),
        ((0, -1), b / 2, a),
    ):
        n = R @ np.array(normal, dtype=float)
        mid = centre + n * half
        if n @ (_CAM[:2] - mid) > 0:
            k = int(400 * length)  # ~150 side points in all, as many as the tabletop's tea box has
            t = rng.uniform(-length / 2, length / 2, k)
            parts.append(np.column_stack([mid + t[:, None] * [-n[1], n[0]], rng.uniform(0, h, k)]))
    top = rng.uniform(-0.5, 0.5, (200, 2)) * [a, b] @ R.T + centre
    return np.concatenate([*parts, np.column_stack([top, np.full(200, h)])])


def _visible_cylinder(r: float, h: float, centre: np.ndarray, rng) -> np.ndarray:
    """The half of an upright cylinder's side that faces the camera, and its top disc."""
    ang = math.atan2(-centre[1], -centre[0]) + rng.uniform(-math.pi / 2, math.pi / 2, 150)
    side = np.column_stack([centre + r * np.column_stack([np.cos(ang), np.sin(ang)]), rng.uniform(0, h, 150)])
    rr, aa = r * np.sqrt(rng.uniform(0, 1, 200)), rng.uniform(0, 2 * math.pi, 200)
    top = centre + np.column_stack([rr * np.cos(aa), rr * np.sin(aa)])
    return np.concatenate([side, np.column_stack([top, np.full(200, h)])])


def _measured_extent(P: np.ndarray) -> np.ndarray:
    """Footprint length, width (minimum-area rectangle), 98th-percentile height: as the grounder measures."""
    a, b = sorted(cv2.minAreaRect(P[:, :2].astype(np.float32))[1], reverse=True)
    return np.array([a, b, np.percentile(P[:, 2], 98)])


@pytest.mark.parametrize("sigma", [0.0, 0.007])
def test_a_box_corner_and_a_can_through_depth_noise(sigma):
    """A tea box (12 x 7 x 8.5 cm) seen corner-on and a soda can (r 3.3 cm, 12 cm tall) ~1 m from the camera.

    sigma 7 mm is the RealSense-like preset's axial noise at the tabletop's 1.1-1.2 m: a side is then a band
    ~1.5 cm thick. The box is turned 30-60 deg from square-on (two faces seen: the corner view; a square-on
    box shows one flat face, which a circle can follow too: the rule's known weak case, module docstring).
    Every one of the draws must be right: over 60 draws the rule made no error at 7 mm, while the former rule
    (circle against the enclosing rectangle) read 6 of these boxes "cylinder" at 7 mm and 25 noise-free.
    """
    for i in range(8):
        rng = np.random.default_rng(i)
        centre = np.array([rng.uniform(-0.2, 0.3), rng.uniform(0.9, 1.2)])
        view = math.atan2(centre[1], centre[0])
        box = _along_rays(
            _visible_box(0.12, 0.07, 0.085, view + rng.uniform(math.pi / 6, math.pi / 3), centre, rng),
            sigma,
            rng,
        )
        can = _along_rays(_visible_cylinder(0.033, 0.12, centre, rng), sigma, rng)
        assert shape_family(box, _measured_extent(box)) == "box", i
        assert shape_family(can, _measured_extent(can)) == "cylinder", i


def test_a_box_seen_end_on_through_noise_keeps_box_among_its_readings():
    """A tea box (13 x 6.2 x 8.5 cm) seen end-on, 0.9-1.2 m away, through 8 mm of axial noise (the
    RealSense-like preset at 1.3 m): its one seen face is 6 cm wide, which a 6 cm circle follows nearly as
    well as the rectangle does, so the box/cylinder rule is unreliable here (tabletop seed 922: 0.09 mm of
    change in the points flipped it). Near its threshold the other reading is kept (`shape_families`), so
    "box" stays among the readings of some boxes that the family alone reads "cylinder"; a can keeps its
    clear "cylinder" at the same noise.

    Counts over 40 draws, measured: 14 boxes read "cylinder", 8 of them with "box" as the alternative; 2 of
    the 40 cans gain "box" as theirs (their family stays "cylinder"). The bounds leave a few draws of slack.
    Most end-on boxes far out are still misread outright: the band softens the rule, it does not mend it.
    """
    readings, cans = [], []
    for i in range(40):
        rng = np.random.default_rng(i)
        centre = np.array([rng.uniform(-0.2, 0.3), rng.uniform(0.9, 1.2)])
        view = math.atan2(centre[1], centre[0])  # the long side along the line of sight: end-on
        box = _along_rays(_visible_box(0.13, 0.062, 0.085, view + rng.uniform(-0.05, 0.05), centre, rng),
                          0.008, rng)  # fmt: skip
        can = _along_rays(_visible_cylinder(0.033, 0.12, centre, rng), 0.008, rng)
        readings.append(shape_families(box, _measured_extent(box)))
        cans.append(shape_families(can, _measured_extent(can)))
        # the family is the first reading, and an alternative is always the other of box and cylinder
        assert readings[-1][0] == shape_family(box, _measured_extent(box))
        assert readings[-1][1] in (None, {"box": "cylinder", "cylinder": "box"}.get(readings[-1][0], "-"))
    misread = [g for f, g in readings if f == "cylinder"]
    assert len(misread) >= 8  # the case this is for: the family alone misreads some of these boxes
    assert misread.count("box") >= 5
    assert all(f == "cylinder" for f, _ in cans) and sum(g == "box" for _, g in cans) <= 3


def test_a_near_threshold_reading_scores_half_way_between_box_and_cylinder():
    """The shape term of a candidate read "cylinder" with "box" as the alternative is the mean of the two
    readings' terms: its total (logit / 2 + 1, see `score_candidates`) lies exactly half way."""
    prob = {"box": 0.9, "cylinder": 0.05, "sphere": 0.05}  # p(family | noun) of a box-like noun
    f = feats(
        families=("box", "cylinder", "cylinder"),
        alternative_families=(None, None, "box"),
    )
    s = score_candidates(parse_prompt("the tea box"), f, prob)
    total = np.log(s / (1.0 - s)) / 2.0 + 1.0
    assert total[0] > total[2] > total[1]
    assert total[2] == pytest.approx(0.5 * (total[0] + total[1]), abs=1e-9)
    # without alternatives (a grounder that does not measure them) the families alone count
    families_only = feats(families=("box", "cylinder", "cylinder"))
    plain = score_candidates(parse_prompt("the tea box"), families_only, prob)
    assert plain[1] == plain[2] == pytest.approx(s[1])


def _handle(r: float, h: float, centre: np.ndarray, azimuth: float, rng) -> np.ndarray:
    """A mug handle's outer loop: 20 points (as dense as `_visible_cylinder`'s side) on a half circle in the
    vertical plane through the body's axis at `azimuth`, from 0.8 h out 2.5 cm and back to 0.25 h, 1 cm
    wide."""
    t = rng.uniform(0.0, math.pi, 20)
    reach, mid, half = 0.025, 0.525 * h, 0.275 * h
    radial = r + reach * np.sin(t)
    u = np.array([math.cos(azimuth), math.sin(azimuth)])
    across = np.array([-u[1], u[0]]) * rng.uniform(-0.005, 0.005, 20)[:, None]
    return np.column_stack([centre + radial[:, None] * u + across, mid + half * np.cos(t)])


@pytest.mark.parametrize("sigma", [0.0, 0.007])
def test_a_handle_is_seen_beside_a_round_body_only(sigma):
    """A mug (r 4 cm, 9.5 cm tall) ~1 m from the camera with its handle beside the body, against the same body
    without it (a cup, a can), with it behind the body, and against a bowl whose wall flares out.

    sigma 7 mm: the RealSense-like axial noise at 1.1-1.2 m, as in the box/can test. The handle stands
    2.5 cm out, beyond the 12 mm (0.3 r) threshold at any noise, in one direction; the bowl's flare stands
    out all along the half circle the camera sees (the concentration test), so it is no handle.
    """
    for i in range(8):
        rng = np.random.default_rng(i)
        centre = np.array([rng.uniform(-0.2, 0.3), rng.uniform(0.9, 1.2)])
        view = math.atan2(-centre[1], -centre[0])  # from the body towards the camera, in the plane
        body = _visible_cylinder(0.04, 0.095, centre, rng)
        side = view + rng.choice([-1.0, 1.0]) * rng.uniform(math.radians(60), math.radians(100))
        mug = _along_rays(np.concatenate([body, _handle(0.04, 0.095, centre, side, rng)]), sigma, rng)
        cup = _along_rays(body, sigma, rng)
        ext_mug, ext_cup = _measured_extent(mug), _measured_extent(cup)
        assert handle_seen(mug, ext_mug, "cylinder"), i
        assert not handle_seen(cup, ext_cup, "cylinder"), i
        # the same points read as a box (or anything not round) are not judged
        assert not handle_seen(mug, ext_mug, "box"), i
        # a bowl: radius 5 cm at the foot to 8 cm at the rim, the camera's half of its outer wall
        ang = view + rng.uniform(-math.pi / 2, math.pi / 2, 300)
        z = rng.uniform(0.0, 0.07, 300)
        rad = 0.05 + 0.03 * z / 0.07
        bowl = _along_rays(
            np.column_stack([centre + rad[:, None] * np.column_stack([np.cos(ang), np.sin(ang)]), z]),
            sigma,
            rng,
        )
        assert not handle_seen(bowl, _measured_extent(bowl), "cylinder"), i


@pytest.mark.parametrize("sigma", [0.0, 0.007])
def test_a_protrusion_beside_a_box_shaped_body_is_no_handle(sigma):
    """A camera-sized box (11 x 8 x 8 cm) seen corner-on, with the mug's handle loop 5.5 cm off its axis.

    The grounder can read such a body "cylinder" (dev splits 28 and 29: 17 of 96 camera candidates for
    "mug" had a "handle"); the loop stands out of the circle like a mug's, but the box's faces do not lie on
    that circle, so it is no handle. Without the roundness test, 2 (noise-free) and 8 (7 mm) of these 40
    draws read as a handle; the mug body with the loop (the test above) still shows one.
    """
    for i in range(40):
        rng = np.random.default_rng(i)
        centre = np.array([rng.uniform(-0.2, 0.3), rng.uniform(0.9, 1.2)])
        view = math.atan2(-centre[1], -centre[0])
        yaw = view + rng.uniform(math.pi / 6, math.pi / 3)
        side = view + rng.choice([-1.0, 1.0]) * rng.uniform(math.radians(60), math.radians(100))
        box = _visible_box(0.11, 0.08, 0.08, yaw, centre, rng)
        camera = _along_rays(np.concatenate([box, _handle(0.055, 0.08, centre, side, rng)]), sigma, rng)
        assert not handle_seen(camera, _measured_extent(camera), "cylinder"), i


def _visible_frustum(r_bottom: float, r_top: float, h: float, centre: np.ndarray, rng) -> np.ndarray:
    """The camera's half of an upright truncated cone's side (a paper cup: r_top > r_bottom) and its rim.

    1000 side points: the grounder's 2 px grid on a cup ~1 m away (points ~3 mm apart over a 12 x 10 cm
    half side)."""
    ang = math.atan2(-centre[1], -centre[0]) + rng.uniform(-math.pi / 2, math.pi / 2, 1000)
    z = rng.uniform(0.0, h, 1000)
    rad = r_bottom + (r_top - r_bottom) * z / h
    side = np.column_stack([centre + rad[:, None] * np.column_stack([np.cos(ang), np.sin(ang)]), z])
    a = rng.uniform(0, 2 * math.pi, 100)
    rim = np.column_stack([centre + r_top * np.column_stack([np.cos(a), np.sin(a)]), np.full(100, h)])
    return np.concatenate([side, rim])


@pytest.mark.parametrize("sigma", [0.0, 0.007])
def test_taper_tells_a_widening_cup_from_a_straight_mug(sigma):
    """A paper cup (radius 2.8 cm at the foot, 4.2 cm at the rim, 10 cm tall) and a straight mug body (4 cm).

    The cup's bands (25-45 % and 65-90 % of its height) hold radii of 3.15-3.43 and 3.71-4.06 cm, 3.29 and
    3.89 cm in the middle: log(3.885 / 3.29) = 0.166 by construction. Noise-free, the bands share the axis
    of a circle fitted to a half arc whose radius spreads over 0.9 cm, which moves it a little (up to 0.03 of
    log radius). With 7 mm noise, the bounds are the development table's gap (mugs -0.02 to 0.03, cups from
    0.05).
    """
    for i in range(8):
        rng = np.random.default_rng(i)
        centre = np.array([rng.uniform(-0.2, 0.3), rng.uniform(0.9, 1.2)])
        cup = _along_rays(_visible_frustum(0.028, 0.042, 0.1, centre, rng), sigma, rng)
        mug = _along_rays(_visible_frustum(0.04, 0.04, 0.095, centre, rng), sigma, rng)
        t_cup = taper(cup, _measured_extent(cup), "cylinder")
        t_mug = taper(mug, _measured_extent(mug), "cylinder")
        if sigma == 0.0:
            assert t_cup == pytest.approx(math.log(0.03885 / 0.0329), abs=0.03), i
            assert t_mug == pytest.approx(0.0, abs=0.01), i  # the ray denoising's 4 mm bins: ~1 mm of radius
        assert t_cup > 0.1 and abs(t_mug) < 0.05, (i, t_cup, t_mug)
        # not measured: a candidate that does not read round, or whose lower band is hidden (an occluder)
        assert math.isnan(taper(cup, _measured_extent(cup), "box"))
        upper = cup[cup[:, 2] > 0.05]
        assert math.isnan(taper(upper, _measured_extent(cup), "cylinder"))


def test_taper_term_takes_away_for_a_taper_unlike_the_nouns():
    # a cup (widens 0.2), a straight body, a camera body narrowing upwards; alike in every other way
    f = feats(tapers=np.array([0.2, 0.0, -0.4]))
    mug = NounPrior("mug", 0.9, np.full(3, 0.1), taper=0.0)
    cup = NounPrior("cup", 0.9, np.full(3, 0.1), taper=0.2)
    s_mug = score_candidates(parse_prompt("the mug"), f, None, noun_prior=mug)
    s_cup = score_candidates(parse_prompt("the cup"), f, None, noun_prior=cup)
    assert s_mug[1] > s_mug[0] > s_mug[2] and s_cup[0] > s_cup[1] > s_cup[2]
    # a straight body is no evidence for a mug: it scores as one not measured (a box); alike is 0
    unmeasured = feats(tapers=np.array([0.0, np.nan, np.nan]))
    assert np.ptp(score_candidates(parse_prompt("the mug"), unmeasured, None, noun_prior=mug)) == 0.0
    # the penalty on the total (the score is sigmoid(2 (total - 1))): exp(-(gap / 0.08)^2 / 2) - 1
    total = lambda s: 1.0 + 0.5 * np.log(s / (1.0 - s))  # noqa: E731
    assert total(s_mug[0]) - total(s_mug[1]) == pytest.approx(math.exp(-0.5 * (0.2 / 0.08) ** 2) - 1.0)
    assert total(s_cup[1]) - total(s_cup[0]) == pytest.approx(math.exp(-0.5 * (0.2 / 0.08) ** 2) - 1.0)
    # nouns whose mesh narrows upwards (a bottle's shoulder) or has no taper (not round) judge nothing
    bottle = NounPrior("bottle", 0.9, np.full(3, 0.1), taper=-0.24)
    box = NounPrior("box", 0.9, np.full(3, 0.1))
    for noun, prior in (("the bottle", bottle), ("the box", box)):
        assert np.ptp(score_candidates(parse_prompt(noun), f, None, noun_prior=prior)) == 0.0


def _laptop_from_behind(
    gap: float, screen_ab: tuple[float, float], lean_m: float = 0.03
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid labels and points (in plane coordinates: right, forward, height) of a laptop seen from behind:
    rows 0-9 the screen's back (30 cm wide, `lean_m` of footprint, 21 cm tall) `gap` [m] behind the 8 cm
    strip of its base the screen leaves in view (rows 10-19, 2 cm high); `screen_ab` the two segments' Lab
    (a, b)."""
    x = np.linspace(0.0, 0.3, 30)
    t = np.linspace(0.0, 1.0, 10)[:, None] * np.ones((1, 30))
    screen = np.stack([np.broadcast_to(x, t.shape), gap + 0.08 + lean_m * (1 - t), 0.21 * (1 - t)], -1)
    base = np.stack([np.broadcast_to(x, t.shape), 0.08 * (1 - t), np.full(t.shape, 0.02)], -1)
    labels = np.repeat([0, 1], 10)[:, None] * np.ones((1, 30), dtype=np.int64)
    lab = np.zeros((20, 30, 3))
    lab[:10] = (40.0, *screen_ab)
    lab[10:] = (40.0, 30.0, -30.0)
    return labels, np.concatenate([screen, base]), lab


def test_a_screen_joins_its_base_across_the_strip_it_hides():
    """Seen from behind and low, a laptop's screen hides its hinge and up to its height of the base (dev 29:
    base strips 14-15 cm in front of 21-23 cm screens). Of one colour the two join up to the screen's height
    apart; of two colours (a black screen on a red base) only within 12 cm (`_HINGE_GAP_M`), as before."""
    same, other = (30.0, -30.0), (-30.0, 30.0)
    cfg = GroundingConfig()
    cases = ((0.14, same, True), (0.14, other, False), (0.10, other, True), (0.25, same, False))
    for gap, ab, joined in cases:
        labels, P, lab = _laptop_from_behind(gap, ab)
        out = _join_hinged(labels, P, lambda q: q, lab, cfg)
        assert (out.max() == 0) == joined, (gap, ab)


def test_a_panel_across_the_slab_is_no_hinge():
    """A hinge is a line the screen and the base share, so a screen's footprint runs along the base's edge.
    A box standing beside a banana lying at an angle has the sizes of a panel and a slab, about as long
    and within reach, but across it (a real frame: 52 deg apart, and joined into one "laptop" before)."""
    cfg = GroundingConfig()
    labels, P, lab = _laptop_from_behind(0.10, (-30.0, 30.0))
    assert _join_hinged(labels, P, lambda q: q, lab, cfg).max() == 0  # along the edge: joined
    for deg, joined in ((15.0, True), (45.0, False), (90.0, False)):
        turned = P.copy()
        c, s_ = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        xy = turned[:10, :, :2] - turned[:10, :, :2].reshape(-1, 2).mean(axis=0)
        turned[:10, :, 0] = c * xy[..., 0] - s_ * xy[..., 1] + P[:10, :, 0].mean()
        turned[:10, :, 1] = s_ * xy[..., 0] + c * xy[..., 1] + P[:10, :, 1].mean()
        out = _join_hinged(labels, turned, lambda q: q, lab, cfg)
        assert (out.max() == 0) == joined, deg


def test_a_screen_leaning_back_joins_its_base_and_a_box_does_not():
    """A screen opened past 110 deg leans back: 13 cm of footprint, wider than an upright panel's 9 cm
    (dev 29: 11-15 cm screens stayed apart from their bases), but its points lie on one steep plane, so it
    joins. A box's front and top seen together (one colour, as wide and as tall) are not flat, and its top
    seen alone is flat but level (dev 28: a carton's top joined a laptop's base): both stay apart."""
    cfg = GroundingConfig()
    labels, P, lab = _laptop_from_behind(0.10, (30.0, -30.0), lean_m=0.13)
    assert _join_hinged(labels, P, lambda q: q, lab, cfg).max() == 0
    box = P.copy()
    top = box[:5]  # rows 0-4: the box's top face, 13 cm deep at 21 cm; rows 5-9: its front face
    top[..., 1] = 0.18 + np.linspace(0.13, 0.0, 5)[:, None]
    top[..., 2] = 0.21
    box[5:10, :, 1] = 0.18
    box[5:10, :, 2] = 0.21 * np.linspace(0.8, 0.0, 5)[:, None]
    assert _join_hinged(labels, box, lambda q: q, lab, cfg).max() == 1
    box_top = P.copy()
    box_top[:10, :, 1] = 0.18 + np.linspace(0.13, 0.0, 10)[:, None]
    box_top[:10, :, 2] = 0.21
    assert _join_hinged(labels, box_top, lambda q: q, lab, cfg).max() == 1


@pytest.mark.parametrize(
    ("prompt", "text", "noun", "colours", "size", "position", "relation", "ref_noun"),
    [
        ("the yellow can", "yellow can", "can", ("yellow",), None, None, None, None),
        ("Pick up the RED mug!", "red mug", "mug", ("red",), None, None, None, None),
        ("put the soda can in the bin", "soda can", "soda can", (), None, None, None, None),
        ("the largest object", "largest object", "object", (), ("volume", 1, True), None, None, None),
        ("a tiny grey ball", "tiny grey ball", "ball", ("grey",), ("volume", -1, False), None, None, None),
        ("the mug left of the bowl", "mug", "mug", (), None, None, "left_of", "bowl"),
        ("the cup to the right of the blue box", "cup", "cup", (), None, None, "right_of", "box"),
        ("the bottle behind the bowl", "bottle", "bottle", (), None, None, "behind", "bowl"),
        ("the can in front of the box", "can", "can", (), None, None, "in_front_of", "box"),
        ("the mug next to the laptop", "mug", "mug", (), None, None, "near", "laptop"),
        ("the object nearest to the camera", "object", "object", (), None, "nearest", None, None),
        ("the farthest gray bottle", "gray bottle", "bottle", ("grey",), None, "farthest", None, None),
        ("the mug on the left", "mug", "mug", (), None, "leftmost", None, None),
        # a colour word that names a content or a product, or the fruit itself, asks for no colour
        ("the olive oil bottle", "olive oil bottle", "olive oil bottle", (), None, None, None, None),
        ("the red wine bottle", "red wine bottle", "red wine bottle", (), None, None, None, None),
        (
            "the green olive oil bottle",
            "green olive oil bottle",
            "olive oil bottle",
            ("green",),
            None,
            None,
            None,
            None,
        ),
        ("pick up the orange", "orange", "orange", (), None, None, None, None),
        ("the small lime", "small lime", "lime", (), ("volume", -1, False), None, None, None),
        ("the orange ball", "orange ball", "ball", ("orange",), None, None, None, None),
        ("the orange one", "orange one", "", ("orange",), None, None, None, None),
        ("the orange left of the lime", "orange", "orange", (), None, None, "left_of", "lime"),
    ],
)
def test_parse_prompt(prompt, text, noun, colours, size, position, relation, ref_noun):
    p = parse_prompt(prompt)
    assert (p.text, p.noun, p.colours, p.size, p.position, p.relation) == (
        text, noun, colours, size, position, relation
    )  # fmt: skip
    assert (p.reference.noun if p.reference else None) == ref_noun


def feats(**kw) -> CandidateFeatures:
    k = 3
    base = dict(
        description_sim=np.full(k, 0.3),
        colour_shares=np.zeros((k, len(PALETTE))),
        palette=PALETTE,
        size_classes=("medium",) * k,
        families=("irregular",) * k,
        extents_m=np.full((k, 3), 0.1),
        plane_xy_m=np.zeros((k, 2)),
        distance_m=np.ones(k),
    )
    base.update(kw)
    return CandidateFeatures(**base)


def test_scoring_terms_rank_as_their_words_say():
    shares = np.zeros((3, len(PALETTE)))
    shares[0, PALETTE.index("red")] = 0.9
    shares[1, PALETTE.index("blue")] = 0.9
    shares[2, PALETTE.index("red")] = 0.1
    s = score_candidates(parse_prompt("the red thing"), feats(colour_shares=shares), None)
    assert np.argmax(s) == 0 and s[2] > s[1]
    ext = np.array([[0.1, 0.1, 0.1], [0.3, 0.2, 0.2], [0.05, 0.05, 0.05]])
    assert np.argmax(score_candidates(parse_prompt("the largest object"), feats(extents_m=ext), None)) == 1
    assert np.argmax(score_candidates(parse_prompt("the smallest object"), feats(extents_m=ext), None)) == 2
    xy = np.array([[-0.2, 0.0], [0.0, 0.0], [0.2, 0.0]])
    assert np.argmax(score_candidates(parse_prompt("the leftmost object"), feats(plane_xy_m=xy), None)) == 0
    dist = np.array([1.0, 0.6, 0.8])
    assert np.argmax(score_candidates(parse_prompt("the nearest object"), feats(distance_m=dist), None)) == 1
    # relation: candidate 1 is the reference (description matches "bowl" best); 0 is left of it, 2 right
    ref_sim = np.array([0.2, 0.8, 0.2])
    f = feats(plane_xy_m=xy)
    ref = (feats(plane_xy_m=xy, description_sim=ref_sim), None)
    assert np.argmax(score_candidates(parse_prompt("the thing left of the bowl"), f, None, ref)) == 0
    assert np.argmax(score_candidates(parse_prompt("the thing right of the bowl"), f, None, ref)) == 2


def test_a_candidate_another_family_explains_better_loses_by_the_rival_term():
    """The prompt "the mug" and two round candidates, of a mug's typical size and of a can's. Read as a can,
    the can-sized one scores higher than read as a mug, so the rival term takes w.rival times the difference
    from it; the mug-sized one is better read as the mug, and keeps its score. Known answers from the size
    term alone (`metric_size_term`, computed independently here): the two readings differ only by it."""
    w = ScoringWeights()
    mug = NounPrior("mug", 0.9, np.array([0.116, 0.082, 0.095]))
    can = NounPrior("can", 0.9, np.array([0.066, 0.066, 0.115]))
    ext = np.stack([mug.typical_extent_m, can.typical_extent_m])
    f = feats(extents_m=ext, families=("cylinder", "cylinder"), description_sim=np.full(2, 0.3),
              colour_shares=np.zeros((2, len(PALETTE))), size_classes=("medium",) * 2,
              plane_xy_m=np.zeros((2, 2)), distance_m=np.ones(2))  # fmt: skip
    prompt = parse_prompt("the mug")
    plain = score_candidates(prompt, f, None, noun_prior=mug)
    with_rival = score_candidates(prompt, f, None, noun_prior=mug, rivals=RivalReadings(f, ((f, None, can),)))
    logit = lambda s: np.log(s / (1.0 - s)) / 2.0  # noqa: E731 -- total - 1 of `score_candidates`
    as_mug = metric_size_term(ext, mug.typical_extent_m, w)
    as_can = metric_size_term(ext, can.typical_extent_m, w)
    assert as_can[1] > as_mug[1] and as_can[0] < as_mug[0]  # the construction
    expected = w.rival * w.metric_size * (as_can[1] - as_mug[1])
    assert logit(plain[1]) - logit(with_rival[1]) == pytest.approx(expected, abs=1e-9)
    assert with_rival[0] == pytest.approx(plain[0], abs=1e-12)
    # no noun prior (a noun the library does not know) or no rivals: the term is off
    assert np.allclose(score_candidates(prompt, f, None, rivals=RivalReadings(f, ((f, None, can),))),
                       score_candidates(prompt, f, None))  # fmt: skip


def test_metric_size_term_prefers_the_typical_size_and_forgives_shrinking():
    w = ScoringWeights()
    typical = np.array([0.12, 0.08, 0.10])
    ext = np.stack([typical, typical * 0.8, typical * 1.25, typical * 3.0])
    t = metric_size_term(ext, typical, w)
    assert t[0] == pytest.approx(1.0)  # exactly typical: exp(0) maps to +1
    # occlusion only shrinks what is seen: 20 % too small costs less than 25 % too large (same |log ratio|)
    assert 1.0 > t[1] > t[2] > t[3]
    assert t[3] < -0.9  # three times the typical size is implausible (d2 ~ 10: 2 exp(-5) - 1)
    assert np.all((t >= -1.0) & (t <= 1.0))


def test_noun_prior_ranks_by_metric_size_unless_a_size_word_is_said():
    # three identical-looking candidates: only their measured extents differ; the noun's family is 10 cm
    prior = NounPrior("mug", 0.9, np.array([0.1, 0.08, 0.1]))
    ext = np.array([[0.3, 0.25, 0.3], [0.1, 0.07, 0.1], [0.03, 0.03, 0.03]])
    f = feats(extents_m=ext)
    assert np.argmax(score_candidates(parse_prompt("the mug"), f, None, noun_prior=prior)) == 1
    without = score_candidates(parse_prompt("the mug"), f, None)
    assert np.ptp(without) == 0.0  # nothing else tells them apart
    # "the small mug": the user says it is not typical; the size adjective ranks, the typical size does not
    small = score_candidates(
        parse_prompt("the small mug"),
        feats(extents_m=ext, size_classes=("large", "medium", "small")),
        None,
        noun_prior=prior,
    )
    assert np.argmax(small) == 2


def test_handle_term_tells_a_mug_from_a_cup():
    # three candidates alike in every measured way but the handle, which only the first shows
    f = feats(handles=np.array([True, False, False]))
    mug = NounPrior("mug", 0.9, np.full(3, 0.1), has_handle=True)
    cup = NounPrior("cup", 0.9, np.full(3, 0.1), has_handle=False)
    s_mug = score_candidates(parse_prompt("the mug"), f, None, noun_prior=mug)
    s_cup = score_candidates(parse_prompt("the cup"), f, None, noun_prior=cup)
    assert np.argmax(s_mug) == 0 and s_mug[1] == s_mug[2]
    assert np.argmin(s_cup) == 0 and s_cup[1] == s_cup[2]
    # a handle not seen is not judged: the cups score the same for "the mug" as for "the cup"
    assert s_mug[1] == pytest.approx(s_cup[1])
    # and nothing changes when handles were not measured
    assert np.ptp(score_candidates(parse_prompt("the cup"), feats(), None, noun_prior=cup)) == 0.0


def test_top_height_histogram_of_constructed_shapes():
    rng = np.random.default_rng(1)
    box = box_points(0.16, 0.07, 0.22, rng)
    hb = top_height_histogram(box, 0.22, 0.16)
    assert hb.shape == (HEIGHT_BINS,) and hb.sum() == pytest.approx(1.0)
    # the camera side of a box (two faces and the top): the top covers every cell but those of the front
    # face's one-cell-thick strip
    assert hb[-1] > 0.7
    # a laptop: a 2 cm base 0.3 x 0.22 m and a thin screen standing 0.22 m at its back edge
    base = np.stack([rng.uniform(0, 0.3, 3000), rng.uniform(0, 0.22, 3000), np.full(3000, 0.02)], 1)
    screen = np.stack(
        [rng.uniform(0, 0.3, 2000), rng.uniform(0.22, 0.23, 2000), rng.uniform(0, 0.22, 2000)], 1
    )
    hl = top_height_histogram(np.vstack([base, screen]), 0.22, 0.3)
    assert hl[0] > 0.7 and hl[-1] > 0.05  # mostly low; the screen's top edge is the top
    # yaw does not matter (up to the cell grid): the box turned by 30 deg about the vertical
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    turned = box @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    # cells cut a turned outline differently; 0.15 of the mass moving between bins is that grid effect
    assert np.abs(top_height_histogram(turned, 0.22, 0.16) - hb).sum() < 0.15
    np.testing.assert_array_equal(top_height_histogram(np.zeros((0, 3)), 0.1, 0.1), np.zeros(HEIGHT_BINS))


def test_top_height_cells_hold_several_samples_of_a_sparsely_seen_object():
    """A 6 x 6 x 9 cm can-sized box seen far away, sampled every 5 mm: its top on that grid, and one point
    of its front wall per column, at heights up the wall, 7 mm in front of the top's first row (depth noise
    along oblique rays at 1.4 m). Cells of a tenth of the footprint (6 mm) hold those wall points alone
    along the front and read them as low tops; cells three samples wide (15 mm) hold top points too, so
    the histogram is the box's: all top."""
    step, side, h = 0.005, 0.06, 0.09
    g = np.arange(0.0, side + 1e-9, step)
    # (the footprint starts 2 cm off the origin, where no cell edge of either size falls between the rows)
    top = np.array([(x, y, h) for x in g for y in g + 0.023])
    wall = np.column_stack([g, np.full(len(g), 0.016), np.linspace(0.0, 0.8 * h, len(g))])
    pts = np.vstack([top, wall])
    fine = top_height_histogram(pts, h, side)
    cell = top_height_cell_fraction(side, step)
    assert cell == 0.25  # 3 x 5 mm = 15 mm, a quarter of the 6 cm footprint
    coarse = top_height_histogram(pts, h, side, cell)
    assert fine[:-1].sum() > 0.05  # the construction: a row of wall-only cells
    assert coarse[-1] == pytest.approx(1.0)
    # dense points (a mesh's) keep the finest cells; beyond the coarsest the coarsest stands
    assert top_height_cell_fraction(side, 0.0) == 0.1 and top_height_cell_fraction(side, 0.05) == 0.5


def test_an_outline_is_hidden_where_something_nearer_or_the_image_edge_bounds_it():
    """The box on the table, exact depth: free space (table, floor) all round: 0. A board in front hides
    its lower part: the board's top edge is nearer and not the table, a share of the outline. Depth that
    drops out in a band along the silhouette says nothing either way; an outline with no readings at all
    cannot be judged (1). Cut by the image's right edge, that side counts."""
    depth, label, R = _raycast([_FLOOR, _TABLE_TOP, _OBJECT])
    P = depth_to_point_map(depth, K)
    table = PlaneFrame(_plane_at(R, 0.72))

    def height_of(p):
        return table.coords(p)[:, 2]

    box = label == 2
    assert outline_hidden(box, P, height_of) < 0.02
    d2, l2, _ = _raycast([_FLOOR, _TABLE_TOP, _OBJECT, _BOARD])
    assert outline_hidden(l2 == 2, depth_to_point_map(d2, K), height_of) > 0.2
    # a 2 px band without readings along the silhouette
    band = (cv2.dilate(box.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0) & ~box
    P_band = P.copy()
    P_band[band] = np.nan
    assert outline_hidden(box, P_band, height_of) < 0.02
    P_none = P.copy()
    P_none[~box] = np.nan
    assert outline_hidden(box, P_none, height_of) == 1.0
    # the image cut through the box's middle column
    xs = np.nonzero(box.any(axis=0))[0]
    cut = int(xs.mean())
    assert outline_hidden(box[:, :cut], P[:, :cut], height_of) > 0.15
    assert outline_hidden(np.zeros_like(box), P, height_of) == 1.0


def test_top_heights_term_prefers_the_family_signature():
    prior = NounPrior("laptop", 0.9, np.full(3, 0.1), np.array([0.8, 0.0, 0.0, 0.0, 0.0, 0.2]))
    tops = np.zeros((3, HEIGHT_BINS))
    tops[0, -1] = 1.0  # a box
    tops[1, [0, -1]] = [0.75, 0.25]  # laptop-like
    tops[2, 3] = 1.0
    s = score_candidates(parse_prompt("the laptop"), feats(top_heights=tops), None, noun_prior=prior)
    assert np.argmax(s) == 1 and s[0] > s[2]  # the box shares the top bin at least


def table_and_wall_depth(tilt_deg: float, height_m: float, wall_distance_m: float) -> np.ndarray:
    """(H, W) float32 depth of a table `height_m` under the camera meeting a wall `wall_distance_m` ahead.

    The camera looks down `tilt_deg` below the horizon; each ray hits whichever plane comes first.
    """
    t = math.radians(tilt_deg)
    n_table = table_normal(tilt_deg)
    n_wall = np.array([0.0, math.sin(t), -math.cos(t)])  # horizontal, pointing back at the camera
    u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u, dtype=float)], -1)
    with np.errstate(divide="ignore"):
        hits = [-d / (rays @ n) for n, d in ((n_table, height_m), (n_wall, wall_distance_m))]
    hits = [np.where(h > 0, h, np.inf) for h in hits]
    return np.minimum(*hits).astype(np.float32)


def test_a_wall_with_more_points_than_the_table_is_not_the_support():
    """Camera 0.5 m above a table, looking down 30 deg at a wall 0.7 m ahead: the wall fills the top 2/3."""
    depth = table_and_wall_depth(30.0, 0.5, 0.7)
    rng = np.random.default_rng(3)
    noisy = depth + rng.normal(0.0, 0.003, depth.shape).astype(np.float32)  # 3 mm: D435 at ~0.8 m
    P = depth_to_point_map(noisy, K)[::4, ::4].reshape(-1, 3)
    candidates = plane_candidates(P, GroundingConfig())
    table = table_normal(30.0)
    angles = [math.degrees(math.acos(min(1.0, abs(c.plane.normal_cam @ table)))) for c in candidates]
    # the test only means something when the wall is the bigger plane, i.e. what "most inliers" picks;
    # 1 deg: thousands of noisy points pin each plane to hundredths of a degree
    wall = [c for c, a in zip(candidates, angles) if a > 80.0]
    floor = [c for c, a in zip(candidates, angles) if a < 1.0]
    assert len(wall) == 1 and len(floor) == 1
    assert wall[0].plane.inlier_fraction > floor[0].plane.inlier_fraction
    assert wall[0].wall and not floor[0].wall
    plane = fit_support_plane(P, GroundingConfig())
    assert plane is not None
    assert math.degrees(math.acos(min(1.0, plane.normal_cam @ table))) < 1.0  # the same 1 deg as above
    assert abs(plane.offset_m - 0.5) < 0.003  # zero-mean noise over thousands of points


def test_a_box_top_below_which_the_scene_lies_loses_to_the_table():
    """A plane under which most of the scene lies (a box's top face) scores below the table it stands on."""
    n = table_normal(40.0)
    depth = tilted_table(n, 0.6).astype(np.float64)
    top = np.zeros(depth.shape, bool)
    top[40:200, 40:280] = True  # a large box top 10 cm up, filling the middle of the view (~50 %)
    depth[top] = tilted_table(n, 0.5)[top]
    P = depth_to_point_map(depth.astype(np.float32), K)[::4, ::4].reshape(-1, 3)
    candidates = plane_candidates(P, GroundingConfig())
    by_height = sorted(candidates, key=lambda c: c.plane.offset_m)
    # the box top (d 0.5) has the whole table below it; the table (d 0.6) has the box above it
    assert by_height[0].above_share < 0.1 and by_height[-1].above_share > 0.9
    plane = fit_support_plane(P, GroundingConfig())
    assert plane is not None and abs(plane.offset_m - 0.6) < 1e-3  # noise-free: exact up to float32 depth


def fold_depth(slope: float, z0: float = 0.6) -> np.ndarray:
    """(H, W) depth of two planes meeting in a vertical fold line through the image centre column.

    slope > 0: the sides come towards the camera away from the fold, which is a valley (concave, like two
    touching objects' faces); slope < 0: a ridge (convex, like a box's edge). X = u' z, z = z0 - slope |X|.
    """
    u, _ = np.meshgrid(np.arange(K.width), np.arange(K.height))
    up = np.abs((u - K.cx) / K.fx)
    return (z0 / (1.0 + slope * up)).astype(np.float64)


def test_shading_joins_one_hue_in_two_lights_not_two_hues():
    edge = GroundingConfig().colour_edge
    # dev 26 scene 19: a purple camera's lens facing the light and its body in shade (median Lab chromas);
    # plain distance 30.2, over the edge; one hue angle (-39.5 vs -39.7 deg): the hue part alone is ~0.1
    lens, body = np.array([69.3, -57.2]), np.array([45.9, -38.1])
    assert np.hypot(*(lens - body)) > edge
    assert _shade_distance(lens, body) < 1.0
    # two hues 30 deg apart at the same chroma: the plain distance (~31)
    red = np.array([60.0, 0.0])
    turned = 60.0 * np.array([np.cos(np.radians(30)), np.sin(np.radians(30))])
    assert _shade_distance(red, turned) == pytest.approx(np.hypot(*(red - turned)))
    # greys (chroma under 20: the hue angle is noise) and a twofold chroma (a pale and a deep colour) too
    assert _shade_distance(np.array([5.0, 5.0]), np.array([12.0, 12.0])) == pytest.approx(np.hypot(7.0, 7.0))
    assert _shade_distance(np.array([25.0, 0.0]), np.array([50.0, 0.0])) == pytest.approx(25.0)


def test_concave_creases_flag_valleys_and_the_foot_of_steps_not_ridges_nor_noise():
    cfg = GroundingConfig()
    s = 2  # the grounder's clustering grid
    centre = round(K.cx / s)
    # a 90 deg valley at 0.6 m: over k = 8 cells (16 px, u' = 0.04) the fold lies z0 u' / (1 + u') = 23 mm
    # behind the mean of its neighbours, over 6 sigma(0.6 m) = 14 mm; a cell j cells off the fold has
    # one neighbour on its own face, so its excess falls as (k - j) / k: flagged within ~3 cells
    valley = concave_creases(fold_depth(1.0)[::s, ::s], cfg)
    cols = np.nonzero(valley.any(axis=0))[0]
    assert centre in cols and np.all(np.abs(cols - centre) <= 3)
    assert valley[:, centre].mean() > 0.85  # the whole column but the k rows at the image's top and bottom
    # a wider valley (127 deg: 12 mm) stays under 6 sigma: the test is meant for sharp folds and steps
    assert not concave_creases(fold_depth(0.5)[::s, ::s], cfg).any()
    assert not concave_creases(fold_depth(-1.0)[::s, ::s], cfg).any()  # a ridge is convex
    # a block 5 cm above a table: the table cells next to the block's silhouette are at the foot of a step
    n = table_normal(40.0)
    depth = tilted_table(n, 0.6).astype(np.float64)
    block = np.zeros(depth.shape, bool)
    block[100:140, 120:200] = True
    depth[block] = tilted_table(n, 0.55)[block]
    steps = concave_creases(depth[::s, ::s], cfg)
    on_block = block[::s, ::s]
    assert steps.any() and not (steps & on_block).any()  # the block's own cells are on the near side
    rng = np.random.default_rng(0)
    flat = tilted_table(n, 0.6).astype(np.float64)
    noisy = flat + rng.normal(0.0, 1.0, flat.shape) * np.asarray(cfg.sigma_m(flat))
    # 6 sigma against noise of sqrt(1.5) sigma (a reading minus the mean of two): ~5 standard deviations,
    # 4 directions x 4800 cells: ~0.01 false flags expected; the seed is fixed
    assert not concave_creases(noisy[::s, ::s], cfg).any()


# --- real frames (../shared/data/real, not in the repository; skipped when absent) ---------------------

REAL = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "real"
_POSECNN_K = (618.0172729492188, 618.0033569335938, 312.376953125, 232.37530517578125)  # meta.yml

#: name: (colour, depth, fx fy cx cy, table rectangles, wall rectangle or None, prompt, object rectangle).
#: Rectangles (x0, y0, x1, y1) in pixels were picked by eye on the colour images: table rectangles hold
#: only bare table, object rectangles enclose the named object with a margin of 10-25 px.
REAL_FRAMES = {
    "graspnet": ("graspnet_example/color.png", "graspnet_example/depth.png",
                 (631.549, 631.208, 638.435, 366.499), [(80, 450, 330, 680), (40, 40, 400, 170)], None,
                 "the red cracker box", (700, 200, 960, 660)),
    "real275": ("cppf_real275_demo/0000_color.png", "cppf_real275_demo/0000_depth.png",
                (591.0125, 590.16775, 322.525, 244.11084), [(450, 320, 630, 400), (20, 380, 120, 440)],
                (200, 20, 600, 90), "the mug", (110, 250, 215, 360)),
    "posecnn0": ("posecnn_demo/000000-color.png", "posecnn_demo/000000-depth.png", _POSECNN_K,
                 [(30, 330, 130, 470), (560, 60, 630, 200)], None,
                 "the yellow mustard bottle", (180, 120, 295, 280)),
    "posecnn1": ("posecnn_demo/000001-color.png", "posecnn_demo/000001-depth.png", _POSECNN_K,
                 [(30, 60, 200, 150), (450, 380, 630, 470)], None, "the red mug", (310, 170, 415, 280)),
    "posecnn4": ("posecnn_demo/000004-color.png", "posecnn_demo/000004-depth.png", _POSECNN_K,
                 [(30, 360, 200, 470), (560, 380, 630, 470)], (100, 10, 600, 60),
                 "the red mug", (235, 330, 390, 470)),
}  # fmt: skip


def _rect_points(P: np.ndarray, rects) -> np.ndarray:
    pts = np.concatenate([P[y0:y1, x0:x1].reshape(-1, 3) for x0, y0, x1, y1 in rects])
    return pts[np.isfinite(pts[:, 2])]


def _lsq_plane(pts: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through points, normal towards the camera (independent of the grounder's)."""
    c = pts.mean(axis=0)
    n = np.linalg.eigh((pts - c).T @ (pts - c))[1][:, 0]
    if n @ c > 0:
        n = -n
    return n, -float(n @ c)


@pytest.fixture(scope="module")
def real_grounder():
    from prompose_grasp.perception.grounding import Grounder

    return Grounder(GroundingConfig())


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/real is not here")
@pytest.mark.parametrize("name", sorted(REAL_FRAMES))
def test_real_frame_support_plane_and_named_object(name, real_grounder):
    from prompose_grasp.perception.frames_io import load_rgbd

    colour, depth, k, table, wall, prompt, (x0, y0, x1, y1) = REAL_FRAMES[name]
    frame = load_rgbd(REAL / colour, REAL / depth, 0.001, k)
    P = depth_to_point_map(frame.depth_m, frame.intrinsics)
    n_table, d_table = _lsq_plane(_rect_points(P, table))
    result = real_grounder.ground(frame.rgb, frame.depth_m, frame.intrinsics, prompt)
    plane = result.support_plane
    assert plane is not None
    angle = math.degrees(math.acos(min(1.0, float(plane.normal_cam @ n_table))))
    # The hand-picked patches hold 13k-100k points with ~2 mm RMS about their own plane (measured), which
    # pins their normal to ~0.1 deg; real tables and real depth bend by more over the view (measured
    # 0.4-1.1 deg on GraspNet and PoseCNN). REAL275's depth is smoothed and its counter is seen at a
    # grazing 30 deg, so its hand patch (the front of the counter) differs by 2.5 deg from the fit over
    # the whole counter: 5 deg there, 2 deg elsewhere. A wall is 90 deg off.
    assert angle < (5.0 if name == "real275" else 2.0)
    assert abs(plane.offset_m - d_table) < 0.02  # the camera's height: 2 cm, the same bending
    if wall is not None:  # a wall in view with many points: the plane is not it
        n_wall, _ = _lsq_plane(_rect_points(P, [wall]))
        assert math.degrees(math.acos(min(1.0, abs(float(plane.normal_cam @ n_wall))))) > 80.0
    best = result.best
    assert best is not None
    ys, xs = np.nonzero(best.mask)
    inside = float(((xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1)).mean())
    # the named object's mask lies in its hand-measured rectangle: measured 100 % on four frames, 96 % on
    # REAL275, whose mug mask leaks into the laptop base behind its handle (the depth there is smoothed
    # across the gap); 90 % leaves room for that leak and nothing else
    assert inside > 0.9
    h = P[best.mask] @ n_table + d_table
    h = h[np.isfinite(h)]
    # Table pixels (height under 5 mm, 2.5 x the patches' 2 mm RMS) in the mask: a mug shows its inner
    # floor, which is at table height by design (measured 4-18 %); a bottle or a box has none, yet the
    # inner-floor fill takes a few table pixels of similar colour at its foot (measured 0 % for the
    # cracker box, 3 % for the mustard bottle on the yellowish wood): at most 5 %.
    if "mug" not in prompt:
        assert (h < 0.005).mean() < 0.05


# ------------------------------------------------------------------------------- the plane under an object

#: World boxes (lo, hi) [m], z up: the floor; a 50 x 50 cm table top 72 cm high; a 10 x 8 x 12 cm box on it.
_FLOOR = (np.array([-5.0, -5.0, -0.01]), np.array([5.0, 5.0, 0.0]))
_TABLE_TOP = (np.array([-0.25, -0.25, 0.70]), np.array([0.25, 0.25, 0.72]))
_OBJECT = (np.array([-0.05, -0.04, 0.72]), np.array([0.05, 0.04, 0.84]))
#: A board 8 cm high standing 2 cm in front of the box: from the camera it hides the box's bottom 6 cm.
_BOARD = (np.array([-0.15, -0.09, 0.72]), np.array([0.15, -0.06, 0.80]))
_EYE = np.array([0.0, -0.9, 1.45])


def _raycast(boxes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact depth (H, W) [m] and the index of the box seen at each pixel, by slab intersection of each
    pixel's ray with axis-aligned world boxes; and R_world_cam of a camera at `_EYE` looking at the table."""
    z = np.array([0.0, 0.0, 0.75]) - _EYE
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u, dtype=float)], -1) @ R.T
    depth = np.full(rays.shape[:2], np.inf)
    label = np.full(rays.shape[:2], -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        for k, (lo, hi) in enumerate(boxes):
            t1, t2 = (lo - _EYE) / rays, (hi - _EYE) / rays
            t_in = np.nanmax(np.minimum(t1, t2), axis=-1)
            t_out = np.nanmin(np.maximum(t1, t2), axis=-1)
            hit = (t_out >= t_in) & (t_in > 0) & (t_in < depth)  # z-depth: the rays have camera z = 1
            depth[hit], label[hit] = t_in[hit], k
    return np.where(np.isfinite(depth), depth, 0.0), label, R


def _plane_at(R: np.ndarray, height_m: float) -> SupportPlane:
    """The horizontal plane z = height_m in the camera frame of `_raycast`."""
    return SupportPlane(normal_cam=R.T @ [0.0, 0.0, 1.0], offset_m=_EYE[2] - height_m, inlier_fraction=0.5)


def test_a_table_top_under_the_object_is_its_support_not_the_floor():
    # The frame's plane is the floor (a small table seen over a larger floor); the box stands on the table
    # top, 72 cm higher. Its support is the table top: parallel to the floor, at the table's height.
    depth, label, R = _raycast([_FLOOR, _TABLE_TOP, _OBJECT])
    mask = label == 2
    pts = depth_to_point_map(depth, K)[mask]
    floor = _plane_at(R, 0.0)
    support = plane_under_object(floor, pts, depth, K, mask)
    np.testing.assert_allclose(support.normal_cam, floor.normal_cam)
    assert support.offset_m == pytest.approx(_EYE[2] - 0.72, abs=1e-6)  # exact depth: the top's own height
    table = _plane_at(R, 0.72)
    assert plane_under_object(table, pts, depth, K, mask) is table  # standing on it: kept
    # A board in front hides the box's bottom: its lowest points are well above the table, yet the table
    # round it shows more than the board's top does, so the table stays its support.
    depth, label, _ = _raycast([_FLOOR, _TABLE_TOP, _OBJECT, _BOARD])
    mask = label == 2
    pts = depth_to_point_map(depth, K)[mask]
    assert np.percentile(pts @ table.normal_cam + table.offset_m, 2) > 0.05  # the construction
    assert plane_under_object(table, pts, depth, K, mask) is table


def test_a_carton_level_with_its_layer_keeps_the_frame_plane():
    # A 3 x 3 layer of 30 cm cartons on the floor seen from above: the middle one shows only its top, level
    # with its neighbours' tops. That level is not its support (it does not rise from it): the floor stays.
    size, gap = 0.2, 0.005
    cartons = [
        (np.array([x - size / 2, y - size / 2, 0.0]), np.array([x + size / 2, y + size / 2, 0.3]))
        for x in (-(size + gap), 0.0, size + gap)
        for y in (-(size + gap), 0.0, size + gap)
    ]
    depth, label, R = _raycast([_FLOOR, *cartons])
    mask = label == 5  # the middle carton
    pts = depth_to_point_map(depth, K)[mask]
    floor = _plane_at(R, 0.0)
    assert np.percentile(pts @ floor.normal_cam + floor.offset_m, 2) > 0.25  # the construction: its top
    assert plane_under_object(floor, pts, depth, K, mask) is floor


def test_an_estimate_over_a_floor_rests_on_the_table_top():
    # ProMPose's own plane for the frame may be the floor or the table; either way the fitted box stands on
    # the table top and keeps its 12 cm height (it grew to the floor, 84 cm, when the floor was its support).
    depth, label, _ = _raycast([_FLOOR, _TABLE_TOP, _OBJECT])
    frame = RGBDFrame(np.full((K.height, K.width, 3), 128, np.uint8), depth.astype(np.float32), K, 0.0)
    prior = PriorLibrary().family_prior("box")
    est = ProMPose(Grounder(), PriorLibrary()).estimate(frame, "box", prior=prior, mask=label == 2)
    assert est.support_plane is not None
    # 5 mm: the RANSAC plane's normal is fitted on exact depth, off by a fraction of a degree
    assert est.support_plane.offset_m == pytest.approx(_EYE[2] - 0.72, abs=0.005)
    # 10 %: SIZE_RTOL of the fit tests; exact depth, the prior's own family
    assert est.pose.size[1] == pytest.approx(0.12, rel=0.10)


# ------------------------------------------------------------------------------- objects standing on others

#: A 22 x 16 x 6.5 cm carton lying on the table top, and a 6 x 10 x 18 cm carton standing on its top face.
_LYING = (np.array([-0.11, -0.08, 0.72]), np.array([0.11, 0.08, 0.785]))
_ON_TOP = (np.array([-0.06, -0.02, 0.785]), np.array([0.0, 0.08, 0.965]))
#: ... or standing on the table against the lying carton's back, as tall above the table.
_BESIDE = (np.array([-0.06, 0.08, 0.72]), np.array([0.0, 0.18, 0.9]))
#: A table top filling most of the view: the frame's plane.
_WIDE_TABLE_TOP = (np.array([-0.8, -0.6, 0.70]), np.array([0.8, 0.6, 0.72]))


def _one_colour_frame(boxes) -> tuple[RGBDFrame, np.ndarray]:
    """The ray-cast frame of the table top and `boxes`, all boxes one red (colour does not tell them
    apart), the table grey; and the index of the box seen at each pixel (-1: table, floor)."""
    depth, label, _ = _raycast([_FLOOR, _WIDE_TABLE_TOP, *boxes])
    rgb = np.full((K.height, K.width, 3), 120, np.uint8)
    rgb[label >= 2] = (200, 40, 30)
    return RGBDFrame(rgb, depth.astype(np.float32), K, 0.0), label - 2


def test_a_carton_standing_on_another_is_its_own_candidate_standing_on_its_top():
    """One colour and touching surfaces join the two cartons in the grid; the lower one's top face, with
    walls under its edge and free area round the upper one's foot, splits them. The upper carton is
    measured from the face it stands on (18 cm, not the 24.5 cm from the table) and the pose is fitted
    standing on that face."""
    frame, label = _one_colour_frame([_LYING, _ON_TOP])
    res = Grounder().ground(frame.rgb, frame.depth_m, K, "the box")
    assert len(res.candidates) == 2
    upper = [c for c in res.candidates if c.attributes.support_height_m > 0]
    assert len(upper) == 1
    a = upper[0].attributes
    # 1 cm: the face's height is the median of its cells' (exact depth; the bin is 1 cm wide)
    assert a.support_height_m == pytest.approx(0.065, abs=0.01)
    assert a.extent_m[2] == pytest.approx(0.18, abs=0.015)  # 98th percentile of the heights above the face
    # the upper candidate's mask is the upper carton but for the cells within the margin over the face
    # (max(1 cm, 3 sigma) of its foot) that stay with the lower one
    assert np.mean(label[upper[0].mask] == 1) > 0.95
    lower = next(c for c in res.candidates if c is not upper[0])
    assert lower.attributes.extent_m[2] == pytest.approx(0.065, abs=0.015)
    est = ProMPose(Grounder(), PriorLibrary()).estimate_all(frame, "the box", max_objects=2)
    on_top = next(e for e in est if e.attributes.support_height_m > 0)
    assert on_top.support_plane.offset_m == pytest.approx(_EYE[2] - 0.785, abs=0.01)
    assert max(on_top.pose.size) == pytest.approx(0.18, rel=0.10)  # 10 %: SIZE_RTOL of the fit tests


def test_a_carton_beside_a_lower_one_is_not_split_at_its_top_height():
    """The same tall carton standing on the table behind the lying one: as high, but not over its top face
    (its front stands on the face's back edge). Nothing is split at the face's height: one colour and
    touching surfaces leave the two one candidate, measured from the table."""
    frame, _ = _one_colour_frame([_LYING, _BESIDE])
    res = Grounder().ground(frame.rgb, frame.depth_m, K, "the box")
    assert len(res.candidates) == 1
    assert res.candidates[0].attributes.support_height_m == 0.0
    assert res.candidates[0].attributes.extent_m[2] == pytest.approx(0.18, abs=0.015)
