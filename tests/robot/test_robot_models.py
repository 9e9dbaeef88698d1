"""The UR table, the registry, and the DH -> URDF -> description round trip."""

from __future__ import annotations

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.robot import JOINT_NAMES, get_ur_spec, known_robots, load_robot, ur_urdf
from prompose_grasp.robot.urdf import describe_arm, parse_urdf, rotation_from_rpy, rpy_from_rotation

# The table, transcribed independently: d1, a2, a3, d4, d5, d6 [m].
UR_DH = {
    "ur3e": (0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
    "ur5e": (0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
    "ur10e": (0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655),
    "ur16e": (0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655),
    "ur5": (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
}
PI = np.pi
SPEEDS = {
    "ur3e": (PI, PI, PI, 2 * PI, 2 * PI, 2 * PI),
    "ur5e": (PI,) * 6,
    "ur5": (PI,) * 6,
    "ur10e": (2 * PI / 3, 2 * PI / 3, PI, PI, PI, PI),
    "ur16e": (2 * PI / 3, 2 * PI / 3, PI, PI, PI, PI),
}


def test_registry_lists_the_five_models_and_ur5e_is_default():
    assert set(known_robots()) == set(UR_DH)
    assert load_robot().name == "ur5e"
    assert get_ur_spec("UR10e").name == "ur10e"  # case-insensitive


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(UnknownNameError) as info:
        load_robot("ur6e")
    message = str(info.value)
    assert "ur6e" in message
    assert all(name in message for name in UR_DH)


@pytest.mark.parametrize("name", sorted(UR_DH))
def test_dh_table_and_limits_match_the_data_sheet(name):
    spec = get_ur_spec(name)
    assert (spec.d1, spec.a2, spec.a3, spec.d4, spec.d5, spec.d6) == UR_DH[name]
    assert spec.d_m[1] == spec.d_m[2] == 0.0
    np.testing.assert_array_equal(spec.alpha_rad, [PI / 2, 0, 0, PI / 2, -PI / 2, 0])
    np.testing.assert_array_equal(spec.max_joint_speed_rad_s, SPEEDS[name])
    lower, upper = spec.joint_limits
    np.testing.assert_array_equal(upper, [2 * PI, 2 * PI, PI, 2 * PI, 2 * PI, 2 * PI])  # elbow: +-pi
    np.testing.assert_array_equal(lower, -upper)
    robot = load_robot(name)
    np.testing.assert_array_equal(robot.max_joint_speed, SPEEDS[name])


def test_ur5e_zero_pose_known_answer():
    # By hand from the DH table: at q = 0 the arm lies along -x; the flange sits at (a2 + a3, -(d4 + d6), d1 -
    # d5) with its z axis along -y, i.e. R = Rx(pi/2). The UR5e teach pendant shows the same numbers at zero.
    d1, a2, a3, d4, d5, d6 = UR_DH["ur5e"]
    T = load_robot("ur5e").fk(np.zeros(6))
    expected_R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    np.testing.assert_allclose(T[:3, 3], [a2 + a3, -(d4 + d6), d1 - d5], atol=1e-12)  # float64 rounding
    np.testing.assert_allclose(T[:3, :3], expected_R, atol=1e-12)  # float64 rounding


@pytest.mark.parametrize("name", sorted(UR_DH))
def test_urdf_round_trips_to_the_same_description(name):
    spec = get_ur_spec(name)
    text = ur_urdf(spec)
    assert text.startswith("<robot")
    original, parsed = describe_arm(spec), parse_urdf(text)
    assert [j.name for j in parsed.joints][:6] == list(JOINT_NAMES)
    # Joint origins are written with repr(), so they come back bit for bit.
    assert parsed.joints == original.joints
    for a, b in zip(original.links, parsed.links):
        assert a.name == b.name and a.inertial == b.inertial
        for ca, cb in zip(a.capsules, b.capsules, strict=True):
            # Capsule ends come back through rpy -> rotation, exact to float64 rounding.
            np.testing.assert_allclose(ca.p0, cb.p0, atol=1e-12)
            np.testing.assert_allclose(ca.p1, cb.p1, atol=1e-12)
            assert ca.radius_m == cb.radius_m


def test_every_moving_link_has_a_capsule_with_mass():
    desc = describe_arm(get_ur_spec("ur5e"))
    moving = [link for link in desc.links if link.name not in ("base", "flange")]
    assert len(moving) == 6
    for link in moving:
        assert link.inertial is not None and link.inertial.mass_kg > 0
        assert len(link.capsules) == 1 and 0.03 <= link.capsules[0].radius_m <= 0.1


def test_rpy_round_trip_including_gimbal_lock():
    rng = np.random.default_rng(3)
    for rpy in [*rng.uniform(-3, 3, size=(20, 3)), (0.3, PI / 2, -1.0), (0.0, -PI / 2, 2.0)]:
        R = rotation_from_rpy(tuple(rpy))
        np.testing.assert_allclose(rotation_from_rpy(rpy_from_rotation(R)), R, atol=1e-12)  # float64 rounding


def test_parse_urdf_rejects_what_it_cannot_read():
    with pytest.raises(InvalidInputError, match="not valid URDF"):
        parse_urdf("<robot")
    with pytest.raises(InvalidInputError, match="accepted: revolute, fixed"):
        parse_urdf(
            '<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="prismatic">'
            '<parent link="a"/><child link="b"/></joint></robot>'
        )
