"""Gripper geometry: the library's parts are the sim's geoms; the tcp convention matches the robot layer."""

from __future__ import annotations

import math
import os

import mujoco
import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.se3 import make_T
from prompose_grasp.grasp import GRIPPER_TCP, ParallelJawGeometry, SuctionCupGeometry, get_gripper
from prompose_grasp.grasp.grippers import GRAVITY_M_S2
from prompose_grasp.robot import load_robot

os.environ.setdefault("MUJOCO_GL", "egl")


def _sim_model(kind: str) -> mujoco.MjModel:
    """The sim's gripper alone under a `flange` body at the origin."""
    from sim.grippers import add_parallel_jaw, add_suction_cup

    spec = mujoco.MjSpec()
    flange = spec.worldbody.add_body(name="flange")
    (add_parallel_jaw if kind == "parallel_jaw" else add_suction_cup)(spec, flange)
    return spec.compile()


@pytest.mark.parametrize("kind", ["parallel_jaw", "suction"])
def test_parts_are_the_sims_geoms(kind):
    g = get_gripper(kind)
    model = _sim_model(kind)
    data = mujoco.MjData(model)
    if kind == "parallel_jaw":
        for side in ("left", "right"):  # fingers fully open, as parts() defaults to
            data.qpos[model.jnt_qposadr[model.joint(f"finger_{side}_joint").id]] = g.stroke_m / 2.0
    mujoco.mj_kinematics(model, data)
    T_flange_tcp = g.T_flange_tcp
    parts = {p.name: p for p in g.parts()}
    # Every sim geom has a part of the same name, shape, size and pose (relative to the flange at the origin).
    assert model.ngeom == len(parts)
    for gid in range(model.ngeom):
        name = model.geom(gid).name
        part = parts[name]
        T_flange_part = T_flange_tcp @ part.T_tcp_part
        np.testing.assert_allclose(data.geom_xpos[gid], T_flange_part[:3, 3], atol=1e-12)  # same arithmetic
        np.testing.assert_allclose(data.geom_xmat[gid].reshape(3, 3), T_flange_part[:3, :3], atol=1e-12)
        mj_type = "box" if model.geom_type[gid] == mujoco.mjtGeom.mjGEOM_BOX else "cylinder"
        assert mj_type == part.shape
        size = model.geom_size[gid][: 3 if mj_type == "box" else 2]
        np.testing.assert_allclose(size, np.asarray(part.size_m)[: len(size)], atol=1e-12)


def test_tcp_is_the_pad_centre_and_the_robot_tcp():
    """load_robot(tcp_offset=T_flange_tcp).fk_tcp(q) = the centre between the sim's pad faces at any opening,
    and = the robot layer's MuJoCo `tcp` site."""
    rng = np.random.default_rng(7)
    g = ParallelJawGeometry()
    robot = load_robot("ur5e", tcp_offset=g.T_flange_tcp)
    model = _sim_model("parallel_jaw")
    data = mujoco.MjData(model)
    for _ in range(5):
        q = robot.random_configurations(rng, 1)[0]
        opening = rng.uniform(0.0, g.stroke_m)
        for side in ("left", "right"):
            data.qpos[model.jnt_qposadr[model.joint(f"finger_{side}_joint").id]] = opening / 2.0
        mujoco.mj_kinematics(model, data)
        # Inner pad faces in the flange frame (the sim model's flange is the world origin).
        faces = []
        for side, sign in (("left", 1.0), ("right", -1.0)):
            gid = model.geom(f"pad_{side}").id
            centre = (
                data.geom_xpos[gid] - sign * model.geom_size[gid][1] * data.geom_xmat[gid].reshape(3, 3)[:, 1]
            )
            faces.append(centre)
        assert math.isclose(np.linalg.norm(faces[0] - faces[1]), opening, abs_tol=1e-12)  # width = opening
        pad_centre_flange = 0.5 * (faces[0] + faces[1])
        T_base_tcp = robot.fk(q) @ make_T(np.eye(3), pad_centre_flange)
        np.testing.assert_allclose(robot.fk_tcp(q), T_base_tcp, atol=1e-12)
        np.testing.assert_allclose(robot.fk_mujoco(q, "tcp"), robot.fk_tcp(q), atol=1e-9)  # MuJoCo float path
        np.testing.assert_allclose(
            g.pad_centres_tcp(opening), (np.array(faces) - g.T_flange_tcp[:3, 3]), atol=1e-12
        )


def test_suction_tcp_is_the_cup_face_centre():
    g = SuctionCupGeometry()
    model = _sim_model("suction")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.xpos[model.body("suction_cup").id], g.T_flange_tcp[:3, 3], atol=1e-12)
    face = model.geom("suction_cup_face").id
    # The face geom's far end (z + half height) is the tcp: the cup face.
    tip = data.geom_xpos[face] + model.geom_size[face][1] * data.geom_xmat[face].reshape(3, 3)[:, 2]
    np.testing.assert_allclose(tip, g.T_flange_tcp[:3, 3], atol=1e-12)
    np.testing.assert_allclose(GRIPPER_TCP["suction"][:3, 3], [0.0, 0.0, 0.100], atol=1e-12)
    np.testing.assert_allclose(GRIPPER_TCP["parallel_jaw"][:3, 3], [0.0, 0.0, 0.145], atol=1e-12)


def test_hull_boxes_contain_every_part():
    for g, opening in ((ParallelJawGeometry(), 0.03), (SuctionCupGeometry(), None)):
        hulls = g.hull_boxes(opening)
        for part in g.parts(opening):
            lo, hi = part.aabb_tcp()
            h_lo, h_hi = hulls[part.group]
            assert np.all(lo >= h_lo - 1e-15) and np.all(hi <= h_hi + 1e-15)


def test_payload_and_validation():
    g = SuctionCupGeometry()
    assert math.isclose(g.max_payload_kg(2.0), 118.0 / (2.0 * GRAVITY_M_S2))
    # Under 1 g sideways with mu 0.8: m g s <= mu (F - m g) -> m = mu F / (g (s + mu)).
    assert math.isclose(g.max_payload_kg(2.0, lateral_g=1.0), 0.8 * 118.0 / (GRAVITY_M_S2 * 2.8))
    with pytest.raises(InvalidInputError):
        ParallelJawGeometry(stroke_m=-0.01)
    with pytest.raises(InvalidInputError):
        ParallelJawGeometry().parts(0.2)
    with pytest.raises(UnknownNameError, match="parallel_jaw, suction"):
        get_gripper("magnet")
