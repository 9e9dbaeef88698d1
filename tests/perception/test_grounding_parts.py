"""Grounding pieces on constructed inputs (no sim): plane, colour names, shapes, parsing, scoring."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.geometry.pointcloud import depth_to_point_map
from prompose_grasp.perception.grounding import GroundingConfig, ground, parse_prompt
from prompose_grasp.perception.grounding.describe import (
    HEIGHT_BINS,
    PALETTE,
    colour_names,
    dominant_colour,
    shape_family,
    size_class,
    top_height_histogram,
)
from prompose_grasp.perception.grounding.plane import PlaneFrame, fit_support_plane
from prompose_grasp.perception.grounding.score import (
    CandidateFeatures,
    NounPrior,
    ScoringWeights,
    metric_size_term,
    score_candidates,
)

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


def test_top_heights_term_prefers_the_family_signature():
    prior = NounPrior("laptop", 0.9, np.full(3, 0.1), np.array([0.8, 0.0, 0.0, 0.0, 0.0, 0.2]))
    tops = np.zeros((3, HEIGHT_BINS))
    tops[0, -1] = 1.0  # a box
    tops[1, [0, -1]] = [0.75, 0.25]  # laptop-like
    tops[2, 3] = 1.0
    s = score_candidates(parse_prompt("the laptop"), feats(top_heights=tops), None, noun_prior=prior)
    assert np.argmax(s) == 1 and s[0] > s[2]  # the box shares the top bin at least
