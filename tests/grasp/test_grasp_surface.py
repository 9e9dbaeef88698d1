"""Section grasps on the seen surface: an object wider than the stroke held by a narrow part of it."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError, NoFeasibleGrasp
from prompose_grasp.geometry import Pose9D
from prompose_grasp.grasp import GraspConfig, ObjectModel, ParallelJawGeometry, Plane, plan_grasps
from prompose_grasp.grasp.surface import needs_sections, section_grasps
from prompose_grasp.grasp.synthesis import generate_candidates
from prompose_grasp.robot import HOME_Q, load_robot

R_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # object +y -> base +z
JAW = ParallelJawGeometry()
ROBOT = load_robot("ur5e", tcp_offset=JAW.T_flange_tcp)
TABLE = Plane.horizontal(0.0)
CENTRE = np.array([-0.5, 0.1])


def _top_surface(height_fn, half_m: float, step_m: float = 0.002) -> np.ndarray:
    """(N, 3) points of a height map seen from above: z = height_fn(x, y) where it is finite, around
    `CENTRE` (what the camera sees of an object's top)."""
    g = np.arange(-half_m, half_m, step_m)
    X, Y = np.meshgrid(g, g, indexing="ij")
    Z = height_fn(X, Y)
    ok = np.isfinite(Z)
    return np.stack([X[ok] + CENTRE[0], Y[ok] + CENTRE[1], Z[ok]], axis=1)


def _pan(X, Y):
    """A frying pan: a 20 cm disc (floor 6 mm, a 3 mm rim wall 35 mm high) and a 12 x 2.5 cm handle along
    +x, its top 30 mm above the table."""
    r = np.hypot(X, Y)
    Z = np.full(X.shape, np.nan)
    Z[r <= 0.1] = 0.006
    Z[(r > 0.097) & (r <= 0.1)] = 0.035
    Z[(X > 0.1) & (X < 0.22) & (np.abs(Y) < 0.0125)] = 0.03
    return Z


def _pan_model(**kw) -> ObjectModel:
    pose = Pose9D(R_UP, [CENTRE[0] + 0.06, CENTRE[1], 0.0175], [0.32, 0.035, 0.2])
    return ObjectModel("pan", pose, surface_points=_top_surface(_pan, 0.25), **kw)


def _inside_part(points: np.ndarray, T_base_tcp: np.ndarray, opening: float) -> np.ndarray:
    """(N,) which points lie inside any of the gripper's parts (the sim's primitives) at the opening."""
    hit = np.zeros(len(points), dtype=bool)
    for part in JAW.parts(opening):
        T = T_base_tcp @ part.T_tcp_part
        lo, hi = part.aabb_tcp()
        local = (points - T[:3, 3]) @ T[:3, :3]
        hit |= np.all(np.abs(local) <= (hi - lo) / 2.0, axis=1)
    return hit


def test_a_pan_wider_than_the_stroke_is_held_across_its_handle_or_its_rim():
    target = _pan_model()
    cfg = GraspConfig(max_grasps=10)
    assert needs_sections(target, JAW, cfg)
    plan = plan_grasps(target, ROBOT, JAW, [], TABLE, None, HOME_Q, cfg)
    assert len(plan) > 0 and {g.method for g in plan} == {"section"}
    pts = np.asarray(target.surface_points)
    half_pad = 0.5 * JAW.pad_size_m[2]
    for g in plan:
        np.testing.assert_allclose(g.approach, [0, 0, -1], atol=1e-12)  # top-down
        np.testing.assert_allclose(ROBOT.fk_tcp(g.q), g.T_base_tcp, atol=1e-9)
        assert g.width_m + 2 * cfg.min_clearance_m <= JAW.stroke_m
        # no seen point inside a finger, the palm or the housing at the planned opening
        assert not np.any(_inside_part(pts, g.T_base_tcp, g.opening_m))
        # something to hold: seen points between the pads (within half the opening across, the pad's width
        # along, and the pad's length in height) ...
        local = (pts - g.T_base_tcp[:3, 3]) @ g.T_base_tcp[:3, :3]
        between = (
            (np.abs(local[:, 1]) <= 0.5 * g.opening_m)
            & (np.abs(local[:, 0]) <= 0.5 * JAW.pad_size_m[0])
            & (np.abs(local[:, 2]) <= half_pad)
        )
        assert np.count_nonzero(between) >= 3
        # ... on the handle (x beyond the disc) or on the rim wall (radius 97-100 mm): never the disc's floor
        xy = pts[between, :2] - CENTRE
        on_handle = xy[:, 0] > 0.1
        on_rim = np.abs(np.hypot(xy[:, 0], xy[:, 1]) - 0.0985) <= 0.006
        assert np.all(on_handle | on_rim), g.reason
        # every gripper part above the table
        for part in JAW.parts(g.opening_m):
            T = g.T_base_tcp @ part.T_tcp_part
            lo, hi = part.aabb_tcp()
            corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * (hi - lo) / 2
            assert (corners @ T[:3, :3].T + T[:3, 3])[:, 2].min() >= cfg.support_clearance_m - 1e-9
    # the handle and the rim are both offered among the candidates
    cands = section_grasps(target, JAW, cfg, TABLE)
    at = cands.T_base_tcp[:, :2, 3] - CENTRE
    assert np.any(at[:, 0] > 0.11) and np.any(np.hypot(at[:, 0], at[:, 1]) < 0.1)


def test_without_its_seen_surface_the_pan_has_no_jaw_grasp():
    bare = ObjectModel("pan", _pan_model().pose)
    assert not needs_sections(bare, JAW, GraspConfig())
    with pytest.raises(NoFeasibleGrasp):
        plan_grasps(bare, ROBOT, JAW, [], TABLE, None, HOME_Q)


def test_a_wide_solid_top_has_no_section_to_close_on():
    # A 20 cm cake tin with a flat top: every closing line through it is wider than the stroke.
    def tin(X, Y):
        return np.where(np.hypot(X, Y) <= 0.1, 0.05, np.nan)

    pose = Pose9D(R_UP, [CENTRE[0], CENTRE[1], 0.025], [0.2, 0.05, 0.2])
    target = ObjectModel("tin", pose, surface_points=_top_surface(tin, 0.15))
    assert needs_sections(target, JAW, GraspConfig())
    assert len(section_grasps(target, JAW, GraspConfig(), TABLE)) == 0


def test_an_object_the_jaws_close_across_gets_no_section_grasps():
    # A 6 cm box fits the stroke: its box grasps are planned, the seen surface adds nothing.
    def box(X, Y):
        return np.where((np.abs(X) <= 0.03) & (np.abs(Y) <= 0.03), 0.06, np.nan)

    pose = Pose9D(R_UP, [CENTRE[0], CENTRE[1], 0.03], [0.06, 0.06, 0.06])
    target = ObjectModel("box", pose, surface_points=_top_surface(box, 0.05))
    assert not needs_sections(target, JAW, GraspConfig())
    assert "section" not in set(generate_candidates(target, JAW, GraspConfig(), TABLE).method)


@pytest.mark.parametrize(
    "points",
    [np.zeros((5, 2)), np.zeros((4, 3), dtype=np.int64), np.array([[0.0, 0.0, np.nan]]), np.zeros(3)],
)
def test_malformed_surface_points_are_refused(points):
    with pytest.raises(InvalidInputError, match="surface_points"):
        ObjectModel("x", Pose9D(R_UP, [0, 0, 0], [0.1, 0.1, 0.1]), surface_points=points)
