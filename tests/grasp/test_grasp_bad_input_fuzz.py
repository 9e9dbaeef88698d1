"""Seeded malformed input to `plan_grasps` and to the values it takes (`ObjectModel`, `Pose9D`): every case
ends in a `PromposeError` with a one-line message, before any candidate is generated.

Each case changes one argument of a valid call to something malformed by construction (a wrong type, shape,
non-finite or non-rotation value, an unknown name); values that are valid but unusual (a target out of reach,
points with NaN rows, which are dropped) are left out: they are answers, not errors.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from prompose_grasp.errors import PromposeError
from prompose_grasp.geometry import Pose9D
from prompose_grasp.grasp import ObjectModel, ParallelJawGeometry, Plane, plan_grasps
from prompose_grasp.grasp import planner as planner_module
from prompose_grasp.robot import HOME_Q, load_robot

N_CASES = 250
R_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # object +y -> base +z
JAW = ParallelJawGeometry()
ROBOT = load_robot("ur5e", tcp_offset=JAW.T_flange_tcp)
TARGET = ObjectModel("box", Pose9D(R_UP, [-0.5, 0.1, 0.03], [0.05, 0.06, 0.06]))


def _bad_pose(rng: np.random.Generator) -> tuple[str, object]:
    """A Pose9D call with one malformed field: no rotation, non-finite, wrong shape, size <= 0, text."""
    R, t, size = R_UP.copy(), np.array([-0.5, 0.1, 0.03]), np.array([0.05, 0.06, 0.06])
    field = int(rng.integers(3))
    if field == 0:
        choices = [rng.normal(size=(3, 3)), 2.0 * R_UP, -R_UP, np.full((3, 3), np.nan), np.eye(4), "eye"]
        R = choices[rng.integers(len(choices))]
    elif field == 1:
        t = [np.array([np.nan, 0.0, 0.0]), np.array([0.0, np.inf, 0.0]), np.zeros(2), "origin", None][
            rng.integers(5)
        ]
    else:
        size = [-size, np.zeros(3), np.array([0.05, np.nan, 0.06]), np.ones(4), "small", [[0.1], [0.1, 0.2]]][
            rng.integers(6)
        ]
    return f"Pose9D field {field}", lambda: Pose9D(R, t, size)


def _bad_object(rng: np.random.Generator) -> tuple[str, object]:
    """An ObjectModel call with one malformed field."""
    kind = int(rng.integers(4))
    if kind == 0:
        pose = [None, np.eye(4), (R_UP, [0, 0, 0], [0.1] * 3), "pose"][rng.integers(4)]
        return "ObjectModel.pose", lambda: ObjectModel("box", pose)
    if kind == 1:
        mass = [-1.0, 0.0, math.nan, math.inf, "1 kg", True][rng.integers(6)]
        return f"ObjectModel.mass_kg {mass!r}", lambda: ObjectModel("box", TARGET.pose, mass_kg=mass)
    if kind == 2:
        what = ["thing", "", "Object", None, 5][rng.integers(5)]
        return f"ObjectModel.kind {what!r}", lambda: ObjectModel("box", TARGET.pose, kind=what)

    class NotAMesh:
        def __init__(self):
            self.vertices = [[0.0, 0.0], [1.0, 1.0]]  # (V, 2): no triangle mesh
            self.faces = [[0, 1]]

    mesh = [NotAMesh(), "mesh.obj", np.zeros((4, 3))][rng.integers(3)]
    return "ObjectModel.mesh", lambda: ObjectModel("box", TARGET.pose, mesh=mesh)


def _bad_plan_call(rng: np.random.Generator) -> tuple[str, object]:
    """(label, a plan_grasps call) with one malformed argument."""
    kw = {
        "target": TARGET,
        "robot": ROBOT,
        "gripper": JAW,
        "obstacles": [],
        "support": Plane.horizontal(0.0),
        "points_base": None,
        "q_seed": HOME_Q,
    }
    kind = int(rng.integers(9))
    if kind == 0:
        kw["target"] = [None, TARGET.pose, {"name": "box"}, "box", [TARGET]][rng.integers(5)]
    elif kind == 1:
        kw["robot"] = [None, "ur5e", 5, ROBOT.spec][rng.integers(4)]
    elif kind == 2:
        kw["gripper"] = ["magnet", "", "Parallel Jaw", 5, None, ["suction"]][rng.integers(6)]
    elif kind == 3:
        kw["obstacles"] = [5, [None], [TARGET.pose], TARGET, ["box"], "boxes"][rng.integers(6)]
    elif kind == 4:
        kw["support"] = ["table", 5, np.array([0.0, 0.0, 1.0]), {"normal": [0, 0, 1]}][rng.integers(4)]
    elif kind == 5:
        n = int(rng.integers(1, 50))
        kw["points_base"] = [
            rng.normal(size=(n, 2)),
            rng.normal(size=(n, 3, 1)),
            rng.normal(size=3),
            "points",
            [[0.0, 0.0, 0.0], [1.0, 2.0]],
        ][rng.integers(5)]
    elif kind == 6:
        inf = np.array([0, 0, np.inf, 0, 0, 0])
        q = [np.zeros(5), np.zeros(7), np.full(6, np.nan), inf, "home", [[0.0] * 6]]
        kw["q_seed"] = q[rng.integers(len(q))]
    elif kind == 7:
        kw["config"] = [{"max_grasps": 4}, "default", 5][rng.integers(3)]
    else:
        kw["scene"] = ["scene", 5, {"support": None}][rng.integers(3)]
    return f"plan_grasps arg kind {kind}", lambda: plan_grasps(**kw)


def test_malformed_grasp_planning_input_is_refused_before_any_work(monkeypatch):
    def no_candidates(*args, **kwargs):
        raise AssertionError("candidates were generated for malformed input")

    monkeypatch.setattr(planner_module, "generate_candidates", no_candidates)
    rng = np.random.default_rng(20272)
    failures: list[str] = []
    t0 = time.perf_counter()
    for k in range(N_CASES):
        pick = rng.random()
        label, call = (
            _bad_pose(rng) if pick < 0.2 else _bad_object(rng) if pick < 0.35 else _bad_plan_call(rng)
        )
        try:
            call()
        except PromposeError as exc:
            if not str(exc).strip() or "\n" in str(exc):
                failures.append(f"case {k} ({label}): message is not one line: {exc!s}")
        except Exception as exc:  # the point of the test: no foreign exception escapes
            failures.append(f"case {k} ({label}): {type(exc).__name__}: {exc}")
        else:
            failures.append(f"case {k} ({label}): accepted")
    assert not failures, "\n".join(failures[:20])
    assert time.perf_counter() - t0 < 20.0  # validation only


@pytest.mark.parametrize("bad", [[object()] * 6, "0 0 0 0 0 0"])
def test_a_joint_vector_given_as_text_or_objects_is_refused(bad):
    with pytest.raises(PromposeError, match="joint vector"):
        ROBOT.fk(bad)
