"""The command validator against an independent oracle of its documented limits, on generated commands.

The oracle here is written from the docstrings of `ValidatorConfig`, `CommandValidator` and
`robot.real_numbers`, not from the validator's code: it reads the limits from the config's fields and
decides each command by the documented rules (its own forward kinematics from the DH table, its own path
sampling, the accelerations in the second-divided-difference form of the docstring). Per command it says

- ACCEPT: the validator must return the command unchanged (the speed lowered to the cap with clip_speed);
- REFUSE: the validator must raise `UnsafeCommandError`;
- INVALID: an argument is malformed (type, dtype, shape); the validator must raise `InvalidInputError`;
- EITHER: only where the documented discretisation decides (see the margins below); any PromposeError
  subclass of the two, or acceptance, is fine, and nothing else.

Any other exception is a failure. Margins where the oracle says EITHER:

- workspace along a joint line: the validator samples so that no joint moves more than X =
  `workspace_step_rad` between samples and documents that the TCP can be off by (X/2) sum_j r_j between
  them; the oracle samples 4 times more densely. A command whose oracle clearance (the smallest distance of
  the sampled TCP to the nearest face of the box, negative outside) lies in [-(X/2) L - 1 um, (X/8) L + 1 um)
  with L = sum_j r_j (1.33 cm wide for this arm) is EITHER. Generators make most paths clear that band.
- speeds and accelerations of trajectories: within a relative 1e-9 of the documented threshold
  cap * (1 + RATE_ROUNDING) (the two compute the same finite differences in different orders).

Everything else is compared exactly (joint limits, steps, the start tolerance, speed arguments, the box of a
linear move: both sides compare the same float values). Generators put values on and next to those
boundaries on purpose (offsets down to 1e-12).

Hypothesis draws each case's structure (which argument is encoded how or malformed how, which limit a value
sits at and how far from it, the path's shape, the timing) and a seed from which numpy draws the vectors of
VARIANTS commands of that structure; `derandomize=True` makes every run the same set of cases.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
import time
from collections import Counter

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from prompose_grasp.errors import InvalidInputError, PromposeError, UnsafeCommandError
from prompose_grasp.robot import HOME_Q, CommandValidator, JointTrajectory, ValidatorConfig, load_robot

ROBOT = load_robot("ur5e", tcp_offset=[0.0, 0.0, 0.15])
# A box that cuts through the arm's reach around HOME_Q, so that workspace decisions are frequent.
CONFIG = ValidatorConfig.for_robot(
    ROBOT, workspace_min_m=(-0.75, -0.75, 0.0), workspace_max_m=(0.75, 0.75, 0.9)
)
VALIDATORS = {
    (fk, clip): CommandValidator(dataclasses.replace(CONFIG, clip_speed=clip), ROBOT.fk_tcp if fk else None)
    for fk in (False, True)
    for clip in (False, True)
}
# Long trajectory segments, so that the workspace between waypoints decides (0.2 rad steps stray < 7 mm).
WIDE_STEP_RAD = np.pi
WIDE_VALIDATOR = CommandValidator(
    dataclasses.replace(CONFIG, max_waypoint_step_rad=WIDE_STEP_RAD), ROBOT.fk_tcp
)

# ---------------------------------------------------------------------------------- the documented limits
LOWER, UPPER = np.array(CONFIG.joint_lower_rad), np.array(CONFIG.joint_upper_rad)
VMAX = np.array(CONFIG.max_joint_speed_rad_s)
AMAX = CONFIG.max_joint_accel_rad_s2
MOVE_STEP, WAYPOINT_STEP = CONFIG.max_move_step_rad, CONFIG.max_waypoint_step_rad
START_TOL = CONFIG.start_tolerance_rad
BOX_MIN, BOX_MAX = np.array(CONFIG.workspace_min_m), np.array(CONFIG.workspace_max_m)
X_STEP = CONFIG.workspace_step_rad
RATE_ROUNDING = 1e-6  # the docstring's relative allowance on trajectory speeds and accelerations
RIGID_TOL = 1e-6  # the docstring's tolerance of a rigid transform
RATE_BAND = 1e-9  # EITHER within this relative distance of the rate threshold

# The oracle's forward kinematics: standard DH Rz(theta) Tz(d) Tx(a) Rx(alpha) from the arm's table.
_D, _A, _ALPHA = (
    np.asarray(v, dtype=np.float64) for v in (ROBOT.spec.d_m, ROBOT.spec.a_m, ROBOT.spec.alpha_rad)
)
_TOOL = np.asarray(ROBOT.T_flange_tcp, dtype=np.float64)
# sum_j r_j: the link lengths beyond joint j (a_j on, d_j excluded: it runs along joint j's own axis) + tool.
REACH_SUM_M = sum(
    float(np.sum(np.abs(_A[j:])) + np.sum(np.abs(_D[j + 1 :])) + np.linalg.norm(_TOOL[:3, 3]))
    for j in range(6)
)
MARGIN_OUT_M = 0.5 * X_STEP * REACH_SUM_M + 1e-6
MARGIN_IN_M = 0.125 * X_STEP * REACH_SUM_M + 1e-6


def tcp_positions(Q: np.ndarray) -> np.ndarray:
    """(M, 3) TCP positions [m] at joint configurations Q (M, 6), batched."""
    T = np.broadcast_to(np.eye(4), (len(Q), 4, 4)).copy()
    ca, sa = np.cos(_ALPHA), np.sin(_ALPHA)
    for j in range(6):
        ct, st_ = np.cos(Q[:, j]), np.sin(Q[:, j])
        A = np.zeros((len(Q), 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st_ * ca[j], st_ * sa[j], _A[j] * ct
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st_, ct * ca[j], -ct * sa[j], _A[j] * st_
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa[j], ca[j], _D[j]
        A[:, 3, 3] = 1.0
        T = T @ A
    return (T @ _TOOL)[:, :3, 3]


def box_clearance(P: np.ndarray) -> float:
    """Smallest distance of the points P (M, 3) to the nearest face of the box [m]; negative outside."""
    return float(np.min(np.minimum(P - BOX_MIN, BOX_MAX - P)))


def path_clearance(nodes: np.ndarray) -> float:
    """Box clearance of the TCP along the joint-space polyline through nodes (K, 6), both ends included,
    sampled 4 times more densely than the validator."""
    samples = [nodes[:1]]
    for q0, q1 in itertools.pairwise(nodes):
        m = max(1, math.ceil(float(np.max(np.abs(q1 - q0))) / (0.25 * X_STEP)))
        samples.append(q0 + np.linspace(0.0, 1.0, m + 1)[1:, None] * (q1 - q0))
    return box_clearance(tcp_positions(np.vstack(samples)))


ACCEPT, REFUSE, INVALID, EITHER = "accept", "refuse", "invalid", "either"


def workspace_verdict(nodes: np.ndarray) -> str:
    clearance = path_clearance(nodes)
    if clearance < -MARGIN_OUT_M:
        return REFUSE
    return ACCEPT if clearance >= MARGIN_IN_M else EITHER


def rate_verdict(ratio: float) -> str:
    """A trajectory's peak speed or acceleration over its cap, against the documented threshold."""
    threshold = 1.0 + RATE_ROUNDING
    if abs(ratio / threshold - 1.0) <= RATE_BAND:
        return EITHER
    return REFUSE if ratio > threshold else ACCEPT


def combine(*verdicts: str) -> str:
    if REFUSE in verdicts:
        return REFUSE
    return EITHER if EITHER in verdicts else ACCEPT


def speed_argument(value: float, cap: float, clip: bool) -> tuple[str, float]:
    """A speed or acceleration argument: finite and > 0, at most the cap (or lowered to it with clip)."""
    if not (math.isfinite(value) and value > 0):
        return REFUSE, value
    if value > cap:
        return (ACCEPT, cap) if clip else (REFUSE, value)
    return ACCEPT, value


# ---------------------------------------------------------------------------------- argument encodings
MALFORMED = object()  # the decoded value of a malformed argument

VEC_VALID = ("f64", "f64", "f64", "list", "tuple", "f32", "int", "intlist")
VEC_BAD = ("str", "strlist", "bool", "boollist", "boolmix", "complex", "complexlist", "none", "dict",
           "zero_d", "short", "row", "object", "ragged", "scalar")  # fmt: skip
NUM_VALID = ("float", "float", "float", "np64", "np32", "int", "npint")
NUM_BAD = (
    "str",
    "none",
    "list",
    "dict",
    "zero_d",
    "one_d",
    "bool",
    "npbool",
    "complex",
    "npcomplex",
    "bigint",
)


def encode_array(x: np.ndarray, how: str) -> tuple[object, object]:
    """(argument, the float64 array it stands for, or MALFORMED)."""
    if how == "f64":
        return x.copy(), x.copy()
    if how == "list":
        return x.tolist(), x.copy()
    if how == "tuple":
        return tuple(x.tolist()), x.copy()
    if how == "f32":
        y = x.astype(np.float32)
        return y, y.astype(np.float64)
    if how == "int":
        y = np.rint(np.nan_to_num(x, nan=0.0, posinf=9.0, neginf=-9.0)).astype(np.int64)
        return y, y.astype(np.float64)
    if how == "intlist":
        y = np.rint(np.nan_to_num(x, nan=0.0, posinf=9.0, neginf=-9.0)).astype(np.int64)
        return y.tolist(), y.astype(np.float64)
    bad = {
        "str": lambda: "0.5",
        "strlist": lambda: np.vectorize(str)(x).tolist(),
        "bool": lambda: x > 0,
        "boollist": lambda: (x > 0).tolist(),
        "boolmix": lambda: [True, *x.tolist()[1:]],
        "complex": lambda: x.astype(np.complex128),
        "complexlist": lambda: [complex(x.flat[0], 0.0), *x.tolist()[1:]],
        "none": lambda: None,
        "dict": lambda: {"q": x.tolist()},
        "zero_d": lambda: np.array(float(x.flat[0])),
        "short": lambda: x.reshape(-1)[:-1],
        "row": lambda: x[None],
        "object": lambda: x.astype(object),
        "ragged": lambda: [x.tolist(), x.tolist()[:-1]],
        "scalar": lambda: float(x.flat[0]),
    }
    return bad[how](), MALFORMED


def encode_number(x: float, how: str) -> tuple[object, object]:
    """(argument, the float it stands for, or MALFORMED)."""
    if how == "float":
        return float(x), float(x)
    if how == "np64":
        return np.float64(x), float(x)
    if how == "np32":
        return np.float32(x), float(np.float32(x))
    if how in ("int", "npint"):
        k = 7 if not math.isfinite(x) else round(x)
        return (k if how == "int" else np.int64(k)), float(k)
    bad = {
        "str": lambda: str(x),
        "none": lambda: None,
        "list": lambda: [x],
        "dict": lambda: {"speed": x},
        "zero_d": lambda: np.array(x),
        "one_d": lambda: np.array([x]),
        "bool": lambda: True,
        "npbool": lambda: np.True_,
        "complex": lambda: complex(x, 0.0),
        "npcomplex": lambda: np.complex128(x),
        "bigint": lambda: 10**400,
    }
    return bad[how](), MALFORMED


def pick_encodings(bad_argument: int, kinds: tuple[str, ...], rng: np.random.Generator) -> list[str]:
    """One encoding per argument (kinds: "vec" or "num"): valid ones at random, and a malformed one for
    argument `bad_argument` (-1: none)."""
    pools = {"vec": (VEC_VALID, VEC_BAD), "num": (NUM_VALID, NUM_BAD)}
    return [str(rng.choice(pools[k][int(i == bad_argument)])) for i, k in enumerate(kinds)]


def bad_argument(n_arguments: int):
    """Which argument is malformed: none about 3 times in 4."""
    return st.sampled_from((-1,) * (3 * n_arguments) + tuple(range(n_arguments)))


def boundary_offset(exponent: int, rng: np.random.Generator) -> float:
    """An offset from a boundary: 0 (exactly on it) for exponent -13, else +-10**(exponent + U(0, 1))."""
    return 0.0 if exponent <= -13 else float(rng.choice([-1.0, 1.0]) * 10 ** (exponent + rng.uniform()))


OFFSET_EXPONENTS = st.sampled_from((-13,) * 4 + tuple(range(-12, -1)))  # exactly on the boundary 4 in 15


def rate_value(kind: str, cap: float, rng: np.random.Generator, delta: float) -> float:
    return {
        "ok": cap * rng.uniform(0.01, 1.0),
        "cap": cap,
        "near": cap * (1.0 + delta),
        "over": cap * rng.uniform(1.01, 10.0),
        "zero": 0.0,
        "negative": -cap * rng.uniform(0.01, 1.0),
        "nan": math.nan,
        "inf": math.inf,
    }[kind]


RATE_KINDS = ("ok",) * 20 + ("cap", "near", "near", "over", "zero", "negative", "nan", "inf")


# ---------------------------------------------------------------------------------- running one case
def run_case(call, verdict: str, check_result, counts: Counter) -> None:
    """Run `call()`; check the outcome against the oracle's verdict; count it."""
    try:
        result = call()
    except UnsafeCommandError as exc:
        assert verdict in (REFUSE, EITHER), f"UnsafeCommandError where the oracle says {verdict}: {exc}"
        counts[f"{verdict}->refused"] += 1
        return
    except InvalidInputError as exc:
        assert verdict == INVALID, f"InvalidInputError where the oracle says {verdict}: {exc}"
        counts["invalid->invalid"] += 1
        return
    except PromposeError as exc:  # a PromposeError of the wrong kind is a failure too
        raise AssertionError(f"unexpected {type(exc).__name__} (oracle: {verdict}): {exc}") from exc
    assert verdict in (ACCEPT, EITHER), f"accepted a command the oracle says is {verdict}"
    check_result(result)
    counts[f"{verdict}->accepted"] += 1


def swing(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(from, to): the arm stretched out (the TCP 0.6 .. 1 m from the base axis) and turned about the base
    by 0.8 .. 1.8 rad: the TCP's arc is inside the square box near its diagonals and outside it near the
    axes, so that the path, not the ends, often decides."""
    q_from = near_home(rng, 0.3)
    q_from[0] = rng.uniform(-np.pi, np.pi)
    q_from[1], q_from[2] = rng.uniform(-1.2, -0.4), rng.uniform(0.2, 1.0)
    q_to = q_from.copy()
    q_to[0] += rng.choice([-1.0, 1.0]) * rng.uniform(0.8, 1.8)
    return q_from, q_to


def near_home(rng: np.random.Generator, spread: float) -> np.ndarray:
    return np.clip(HOME_Q + rng.uniform(-spread, spread, 6), LOWER + 0.01, UPPER - 0.01)


@pytest.fixture(autouse=True)
def _quiet_clipping(caplog):
    """clip_speed logs every lowered speed: thousands of warnings here, none of interest."""
    caplog.set_level(logging.ERROR, logger="prompose_grasp.robot.validator")


SETTINGS = dict(derandomize=True, deadline=None, database=None, suppress_health_check=list(HealthCheck))
# Commands per kind and run (21,000 in all). Each hypothesis example is one case structure checked on
# VARIANTS numeric draws (seeds (seed, 0), (seed, 1), ...): hypothesis's own cost per example (~0.6 ms)
# would otherwise be most of the run.
N_JOINT, N_LINEAR, N_TRAJECTORY = 8000, 6000, 7000
VARIANTS = 4


def variants(c: dict) -> list[dict]:
    return [{**c, "seed": (c["seed"], v)} for v in range(VARIANTS)]


def report(kind: str, counts: Counter, refusals: Counter, t0: float) -> None:
    total = sum(counts.values())
    print(f"\n{kind}: {total} commands in {time.perf_counter() - t0:.1f} s: {dict(sorted(counts.items()))}")
    print(f"  refused by: {dict(refusals.most_common())}")


# ---------------------------------------------------------------------------------- joint moves
# The strategies are built once: one built per draw costs more than the draw.
JOINT_CASES = st.fixed_dictionaries(
    {
        "seed": st.integers(0, 2**32 - 1),
        "current": st.sampled_from(("home", "home", "wide", "edge")),
        "target": st.sampled_from(
            ("small", "small", "small", "large", "swing", "limit", "step", "nonfinite", "same")
        ),
        "offset": OFFSET_EXPONENTS,
        "speed": st.sampled_from(RATE_KINDS),
        "accel": st.sampled_from(RATE_KINDS),
        "bad": bad_argument(4),
        "fk": st.booleans(),
        "clip": st.booleans(),
    }
)


def build_joint_case(c) -> tuple[list[object], list[object]]:
    rng = np.random.default_rng(c["seed"])
    delta = boundary_offset(c["offset"], rng)
    enc = pick_encodings(c["bad"], ("vec", "vec", "num", "num"), rng)
    j = int(rng.integers(6))
    if c["current"] == "home":
        current = near_home(rng, 0.6)
    elif c["current"] == "wide":
        current = rng.uniform(LOWER * 0.5, UPPER * 0.5)
    else:  # one joint at its limit, give or take
        current = near_home(rng, 0.6)
        current[j] = (LOWER if rng.random() < 0.5 else UPPER)[j] + delta
    target = current.copy()
    kind = c["target"]
    if kind == "small":
        target = current + rng.uniform(-1, 1, 6) * 10 ** rng.uniform(-4, -0.3)
    elif kind == "swing":
        current, target = swing(rng)
    elif kind == "large":
        target = current + rng.uniform(-1, 1, 6) * rng.uniform(0.5, 3.5)
    elif kind == "limit":
        target = current + rng.uniform(-0.05, 0.05, 6)
        target[j] = (LOWER if rng.random() < 0.5 else UPPER)[j] + delta
    elif kind == "step":  # one joint a move step (pi) away, give or take; a joint whose range is +-2 pi
        j = int(rng.choice([0, 1, 3, 4, 5]))
        current[j] = rng.uniform(-2.5, 2.5)
        target = current + rng.uniform(-0.01, 0.01, 6)
        target[j] = current[j] + np.sign(rng.uniform(-1, 1)) * (MOVE_STEP + delta)
    elif kind == "nonfinite":
        target[j] = rng.choice([math.nan, math.inf, -math.inf])
    speed = rate_value(c["speed"], float(np.min(VMAX)), rng, delta)
    accel = rate_value(c["accel"], AMAX, rng, delta)
    encoded = [
        encode_array(target, enc[0]),
        encode_array(current, enc[1]),
        encode_number(speed, enc[2]),
        encode_number(accel, enc[3]),
    ]
    return [e[0] for e in encoded], [e[1] for e in encoded]


def joint_oracle(q, current, speed, accel, fk: bool, clip: bool):
    """(verdict, the command expected back, the rule that decides) by the documented rules of
    `validate_joint_move`."""
    if any(v is MALFORMED for v in (q, current, speed, accel)):
        return INVALID, None, "type"
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(current))):
        return REFUSE, None, "nan"
    if np.any((q < LOWER) | (q > UPPER)):
        return REFUSE, None, "limits"
    if np.max(np.abs(q - current)) > MOVE_STEP:
        return REFUSE, None, "step"
    v_verdict, v_sent = speed_argument(speed, float(np.min(VMAX)), clip)
    a_verdict, a_sent = speed_argument(accel, AMAX, clip)
    if REFUSE in (v_verdict, a_verdict):
        return REFUSE, None, "speed"
    if not fk:
        return ACCEPT, (q, v_sent, a_sent), None
    verdict = workspace_verdict(np.array([current, q]))
    ends_inside = box_clearance(tcp_positions(np.array([current, q]))) >= MARGIN_IN_M
    return verdict, (q, v_sent, a_sent), "workspace on the way" if ends_inside else "workspace at an end"


def test_joint_moves_match_the_oracle():
    counts: Counter = Counter()
    refusals: Counter = Counter()  # by the rule that refuses, for the report
    t0 = time.perf_counter()

    @settings(max_examples=N_JOINT // VARIANTS, **SETTINGS)
    @given(JOINT_CASES)
    def check(case):
        for c in variants(case):
            check_one(c)

    def check_one(c):
        args, values = build_joint_case(c)
        verdict, expected, rule = joint_oracle(*values, fk=c["fk"], clip=c["clip"])
        if verdict == REFUSE:
            refusals[rule] += 1
        validator = VALIDATORS[(c["fk"], c["clip"])]

        def check_result(command):
            q, speed, accel = expected
            np.testing.assert_array_equal(command.q, q)
            assert command.q.dtype == np.float64
            assert (command.speed_rad_s, command.accel_rad_s2) == (speed, accel)

        q, current, speed, accel = args
        run_case(
            lambda: validator.validate_joint_move(q, speed, accel, current), verdict, check_result, counts
        )

    check()
    report("joint moves", counts, refusals, t0)
    assert sum(counts.values()) >= N_JOINT
    assert counts["accept->accepted"] > 0.15 * N_JOINT and counts["refuse->refused"] > 0.15 * N_JOINT
    assert counts["either->accepted"] + counts["either->refused"] < 0.05 * N_JOINT


# ---------------------------------------------------------------------------------- linear moves
LINEAR_CASES = st.fixed_dictionaries(
    {
        "seed": st.integers(0, 2**32 - 1),
        "rotation": st.sampled_from(
            ("random",) * 16
            + ("perm", "perm", "near_scale", "near_row", "scaled", "sheared", "mirrored", "row", "nan")
        ),
        "position": st.sampled_from(("inside",) * 4 + ("outside", "face", "face")),
        "offset": OFFSET_EXPONENTS,
        "speed": st.sampled_from(RATE_KINDS),
        "accel": st.sampled_from(RATE_KINDS),
        "bad": bad_argument(3),
        "clip": st.booleans(),
    }
)


def build_linear_case(c) -> tuple[list[object], list[object]]:
    rng = np.random.default_rng(c["seed"])
    delta = boundary_offset(c["offset"], rng)
    enc = pick_encodings(c["bad"], ("vec", "num", "num"), rng)
    T = np.eye(4)
    kind = c["rotation"]
    if kind == "perm":  # a signed permutation with det +1: exact in any encoding
        R = np.eye(3)[rng.permutation(3)] * rng.choice([-1.0, 1.0], 3)
        T[:3, :3] = R * np.sign(np.linalg.det(R))
    else:
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    if kind == "scaled":
        T[:3, :3] *= rng.choice([0.9, 1.1])
    elif kind == "sheared":
        T[0, 1] += rng.choice([-0.05, 0.05])
    elif kind == "mirrored":
        T[:3, 2] *= -1.0
    elif kind == "row":
        T[3, rng.integers(4)] += rng.choice([-0.1, 0.1])
    elif kind in ("near_scale", "near_row"):  # off rigid by RIGID_TOL (1 +- 1e-5 .. 0.5)
        off = RIGID_TOL * (1.0 + rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(-5, -0.3))
        if kind == "near_scale":  # (1 + e)^2 - 1 = off
            T[:3, :3] *= math.sqrt(1.0 + off)
        else:
            T[3, rng.integers(4)] += rng.choice([-1.0, 1.0]) * off
    elif kind == "nan":
        T[rng.integers(3), rng.integers(4)] = rng.choice([math.nan, math.inf])
    if c["position"] == "inside":
        T[:3, 3] = rng.uniform(BOX_MIN, BOX_MAX)
    elif c["position"] == "outside":
        T[:3, 3] = rng.uniform(BOX_MIN - 0.5, BOX_MAX + 0.5)
    else:
        T[:3, 3] = rng.uniform(BOX_MIN, BOX_MAX)
        a = int(rng.integers(3))
        T[a, 3] = (BOX_MIN if rng.random() < 0.5 else BOX_MAX)[a] + delta
    speed = rate_value(c["speed"], CONFIG.max_tcp_speed_m_s, rng, delta)
    accel = rate_value(c["accel"], CONFIG.max_tcp_accel_m_s2, rng, delta)
    encoded = [
        encode_array(T, enc[0]),
        encode_number(speed, enc[1]),
        encode_number(accel, enc[2]),
    ]
    return [e[0] for e in encoded], [e[1] for e in encoded]


def linear_oracle(T, speed, accel, clip: bool):
    """(verdict, the command expected back, the rule that decides) by the documented rules of
    `validate_linear_move`."""
    if any(v is MALFORMED for v in (T, speed, accel)):
        return INVALID, None, "type"
    if not np.all(np.isfinite(T)):
        return REFUSE, None, "nan"
    R = T[:3, :3]
    off = max(float(np.max(np.abs(R.T @ R - np.eye(3)))), float(np.max(np.abs(T[3] - [0, 0, 0, 1]))))
    if abs(off - RIGID_TOL) <= 1e-6 * RIGID_TOL:  # rounding of R^T R is ~1e-16
        rigid = EITHER
    else:
        rigid = ACCEPT if off <= RIGID_TOL and np.linalg.det(R) > 0 else REFUSE
    inside = ACCEPT if np.all((T[:3, 3] >= BOX_MIN) & (T[:3, 3] <= BOX_MAX)) else REFUSE
    v_verdict, v_sent = speed_argument(speed, CONFIG.max_tcp_speed_m_s, clip)
    a_verdict, a_sent = speed_argument(accel, CONFIG.max_tcp_accel_m_s2, clip)
    rule = next(
        (
            r
            for r, v in (("rigid", rigid), ("box", inside), ("speed", v_verdict), ("speed", a_verdict))
            if v == REFUSE
        ),
        None,
    )
    return combine(rigid, inside, v_verdict, a_verdict), (T, v_sent, a_sent), rule


def test_linear_moves_match_the_oracle():
    counts: Counter = Counter()
    refusals: Counter = Counter()  # by the rule that refuses, for the report
    t0 = time.perf_counter()

    @settings(max_examples=N_LINEAR // VARIANTS, **SETTINGS)
    @given(LINEAR_CASES)
    def check(case):
        for c in variants(case):
            check_one(c)

    def check_one(c):
        args, values = build_linear_case(c)
        verdict, expected, rule = linear_oracle(*values, clip=c["clip"])
        if verdict == REFUSE:
            refusals[rule] += 1
        validator = VALIDATORS[(True, c["clip"])]

        def check_result(command):
            T, speed, accel = expected
            np.testing.assert_array_equal(command.T_base_tcp, T)
            assert (command.speed_m_s, command.accel_m_s2) == (speed, accel)

        run_case(lambda: validator.validate_linear_move(*args), verdict, check_result, counts)

    check()
    report("linear moves", counts, refusals, t0)
    assert sum(counts.values()) >= N_LINEAR
    assert counts["accept->accepted"] > 0.15 * N_LINEAR and counts["refuse->refused"] > 0.15 * N_LINEAR
    assert counts["either->accepted"] + counts["either->refused"] < 0.01 * N_LINEAR


# ---------------------------------------------------------------------------------- trajectories
PROFILES = ("trapezoid", "trapezoid", "smoothstep", "cosine", "constant", "wander")
STARTS = ("after",) * 6 + ("t0_exact", "t0_within", "t0_edge", "t0_beyond")
PERTURBATIONS = ("none",) * 10 + ("nan", "limit", "step", "kick")
MALFORMED_TRAJECTORY = ("none",) * 16 + ("not_trajectory", "current", "t_repeated", "t_nan", "t_negative",
                                        "q_complex", "q_shape", "t_str", "q_bool")  # fmt: skip


TRAJECTORY_CASES = st.fixed_dictionaries(
    {
        "seed": st.integers(0, 2**32 - 1),
        "n": st.integers(1, 30),
        "profile": st.sampled_from(PROFILES),
        "irregular": st.booleans(),
        "start": st.sampled_from(STARTS),
        "rate": st.sampled_from(("below", "below", "below", "edge", "edge", "above")),
        "rate_offset": st.integers(-8, -3),
        "offset": OFFSET_EXPONENTS,
        "perturb": st.sampled_from(PERTURBATIONS),
        "malformed": st.sampled_from(MALFORMED_TRAJECTORY),
        "fk": st.sampled_from((False, False, True)),
        "as_lists": st.booleans(),
        "wide": st.sampled_from((False, False, True)),
    }
)


def profile(kind: str, u: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """s(u) for normalised times u in [0, 1], s(0) = 0, s(1) = 1."""
    if kind == "trapezoid":  # rest to rest: constant acceleration for a fraction f, cruise, deceleration
        f = rng.uniform(0.05, 0.5)
        peak = 1.0 / (1.0 - f)  # the cruise speed covering s = 1
        acc = peak / f
        return np.where(
            u < f,
            0.5 * acc * u**2,
            np.where(u <= 1 - f, 0.5 * acc * f**2 + peak * (u - f), 1.0 - 0.5 * acc * (1.0 - u) ** 2),
        )
    if kind == "smoothstep":
        return 3 * u**2 - 2 * u**3
    if kind == "cosine":
        return 0.5 * (1.0 - np.cos(np.pi * u))
    return u  # "constant": full speed from the first sample (not at rest)


def trajectory_nodes(t_s: np.ndarray, Q: np.ndarray, current: np.ndarray):
    """The documented nodes (P, t) of a trajectory, or REFUSE when a waypoint at t = 0 is off the start."""
    if t_s[0] == 0.0:
        if np.max(np.abs(Q[0] - current)) > START_TOL:
            return None
        return Q, t_s
    return np.vstack([current, Q]), np.concatenate([[0.0], t_s])


def peak_rates(P: np.ndarray, t: np.ndarray) -> tuple[float, float]:
    """(largest |v| / vmax, largest |a| / amax) by the docstring's formulas: segment mean speeds, and twice
    the second divided differences with the start and the end as double nodes (at rest)."""
    if len(P) < 2:
        return 0.0, 0.0
    dt = t[1:] - t[:-1]
    v = (P[1:] - P[:-1]) / dt[:, None]
    a = [2.0 * (P[1] - P[0]) / t[1] ** 2]
    for k in range(1, len(P) - 1):
        a.append(2.0 * (v[k] - v[k - 1]) / (t[k + 1] - t[k - 1]))
    a.append(-2.0 * (P[-1] - P[-2]) / dt[-1] ** 2)
    return float(np.max(np.abs(v) / VMAX)), float(np.max(np.abs(np.array(a)))) / AMAX


def trajectory_oracle(t_s, Q, current, fk: bool, max_step: float) -> tuple[str, str | None]:
    """(verdict, the rule that decides) by the documented rules of `validate_trajectory`."""
    if not (np.all(np.isfinite(Q)) and np.all(np.isfinite(current))):
        return REFUSE, "nan"
    nodes = trajectory_nodes(t_s, Q, current)
    if nodes is None:
        return REFUSE, "start tolerance"
    P, t = nodes
    if np.any((Q < LOWER) | (Q > UPPER)):
        return REFUSE, "limits"
    if np.any(np.max(np.abs(np.diff(P, axis=0)), axis=1, initial=0) > max_step):
        return REFUSE, "step"
    speed, accel = peak_rates(P, t)
    rules = {"speed": rate_verdict(speed), "acceleration": rate_verdict(accel)}
    if fk and REFUSE not in rules.values():
        waypoints = box_clearance(tcp_positions(P))
        rules["workspace on the way" if waypoints >= MARGIN_IN_M else "workspace at a waypoint"] = (
            workspace_verdict(P)
        )
    return combine(*rules.values()), next((r for r, v in rules.items() if v == REFUSE), None)


def build_trajectory_case(c):
    """(trajectory argument, q_current argument, (t_s, Q, current) for the oracle or None if malformed)."""
    rng = np.random.default_rng(c["seed"])
    delta = boundary_offset(c["offset"], rng)
    rate_delta = 10 ** (c["rate_offset"] + rng.uniform())  # 1e-8 .. 1e-2
    current = near_home(rng, 0.5)
    j_start = int(rng.integers(6))
    n = 1 + c["n"] % 4 if c["wide"] else c["n"]  # wide: a few long segments, checked along their lines
    u = np.sort(rng.uniform(0, 1, n)) if c["irregular"] else np.arange(1, n + 1) / n
    u[-1] = 1.0
    u = np.maximum.accumulate(np.maximum(u, 1e-3))
    u = u + np.arange(n) * 1e-9  # strictly increasing
    u = u / u[-1]
    # Mostly within the waypoint step; the path short where the workspace is checked (it costs FK calls).
    swung = c["wide"] and c["profile"] in ("trapezoid", "smoothstep")  # one long base turn
    if swung:
        current, q_end = swing(rng)
        travel = float(np.max(np.abs(q_end - current)))
    elif c["wide"]:
        travel = rng.uniform(0.0, 1.2)
    else:
        travel = rng.uniform(0.0, 0.35 if c["fk"] else 1.0) * min(1.0, 0.18 * n)
    if c["start"] == "t0_edge":  # |q_first - current| on that joint is then the offset exactly
        current[j_start] = 0.0
    goal = q_end - current if swung else rng.uniform(-1, 1, 6) * travel * (rng.random(6) < 0.7)
    if c["profile"] == "wander":
        steps = rng.uniform(-1, 1, (n, 6)) * travel / max(1, n) * 2.0
        Q = current + np.cumsum(steps, axis=0)
    else:
        Q = current + profile(c["profile"], u, rng)[:, None] * goal
    start = c["start"]
    if start != "after":
        offset = {
            "t0_exact": 0.0,
            "t0_within": START_TOL * rng.uniform(0.0, 0.99),
            "t0_edge": START_TOL + delta * 1e-3,
            "t0_beyond": START_TOL * rng.uniform(1.5, 200.0),
        }[start]
        q_first = current.copy()
        q_first[j_start] += offset * rng.choice([-1.0, 1.0])
        Q = np.vstack([q_first, Q])
        u = np.concatenate([[0.0], u])
    # The time scale k that puts the peak rate ratio at the target: speeds scale as 1/k, accelerations 1/k^2.
    nodes = trajectory_nodes(u, Q, current)
    P, t = nodes if nodes is not None else (Q, u)  # refused at the start anyway: time it as if it were not
    rv, ra = peak_rates(P, t)
    threshold = 1.0 + RATE_ROUNDING
    target = {
        "below": threshold * rng.uniform(0.02, 0.98),
        "edge": threshold * (1.0 + rng.choice([-1.0, 1.0]) * rate_delta),
        "above": threshold * rng.uniform(1.05, 5.0),
    }[c["rate"]]
    k = max(rv / target, math.sqrt(ra / target), 1e-3)
    t_s = u * k
    j, w = int(rng.integers(6)), int(rng.integers(len(Q)))
    match c["perturb"]:
        case "nan":
            Q[w, j] = rng.choice([math.nan, math.inf])
        case "limit":  # the path shifted on joint j so that its extreme sits at a limit, give or take
            if rng.random() < 0.5:
                shift = LOWER[j] + delta - np.min(Q[:, j])
            else:
                shift = UPPER[j] + delta - np.max(Q[:, j])
            Q[:, j] += shift
            current[j] += shift
        case "step":
            prev = current if w == 0 else Q[w - 1]
            Q[w, j] = prev[j] + rng.choice([-1.0, 1.0]) * (
                (WIDE_STEP_RAD if c["wide"] else WAYPOINT_STEP) + delta
            )
        case "kick":
            Q[w] += rng.uniform(-0.03, 0.03, 6)
    if c["as_lists"]:
        trajectory = JointTrajectory(t_s=t_s.tolist(), q=Q.tolist())
    else:
        trajectory = JointTrajectory(t_s=t_s, q=Q)
    judged: tuple | None = (trajectory.t_s.copy(), trajectory.q.copy(), current)
    current_arg: object = current.copy()
    match c["malformed"]:
        case "not_trajectory":
            others = [None, {"t_s": t_s, "q": Q}, (t_s, Q), [t_s, Q], "trajectory", Q]
            trajectory = others[int(rng.integers(len(others)))]
            judged = None
        case "current":
            current_arg, _ = encode_array(current, str(rng.choice(VEC_BAD)))
            judged = None
        case "t_repeated" if n >= 2:
            trajectory.t_s[-1] = trajectory.t_s[-2]  # the arrays stay writable after construction
            judged = None
        case "t_nan":
            trajectory.t_s[rng.integers(len(trajectory))] = math.nan
            judged = None
        case "t_negative":
            trajectory.t_s[0] = -abs(trajectory.t_s[0]) - 1e-3
            judged = None
        case "q_complex":
            object.__setattr__(trajectory, "q", trajectory.q.astype(np.complex128))
            judged = None
        case "q_shape":
            object.__setattr__(trajectory, "q", trajectory.q[:, :5])
            judged = None
        case "t_str":
            object.__setattr__(trajectory, "t_s", trajectory.t_s.astype(str))
            judged = None
        case "q_bool":
            object.__setattr__(trajectory, "q", trajectory.q > 0)
            judged = None
    return trajectory, current_arg, judged


def test_trajectories_match_the_oracle():
    counts: Counter = Counter()
    refusals: Counter = Counter()  # by the rule that refuses, for the report
    t0 = time.perf_counter()

    @settings(max_examples=N_TRAJECTORY // VARIANTS, **SETTINGS)
    @given(TRAJECTORY_CASES)
    def check(case):
        for c in variants(case):
            check_one(c)

    def check_one(c):
        trajectory, current, judged = build_trajectory_case(c)
        fk = c["fk"] or c["wide"]
        step = WIDE_STEP_RAD if c["wide"] else WAYPOINT_STEP
        verdict, rule = (
            (INVALID, None) if judged is None else trajectory_oracle(*judged, fk=fk, max_step=step)
        )
        if verdict == REFUSE:
            refusals[rule] += 1
        validator = WIDE_VALIDATOR if c["wide"] else VALIDATORS[(c["fk"], False)]

        def check_result(sent):
            np.testing.assert_array_equal(sent.t_s, judged[0])
            np.testing.assert_array_equal(sent.q, judged[1])

        run_case(lambda: validator.validate_trajectory(trajectory, current), verdict, check_result, counts)

    check()
    report("trajectories", counts, refusals, t0)
    assert sum(counts.values()) >= N_TRAJECTORY
    assert (
        counts["accept->accepted"] > 0.15 * N_TRAJECTORY and counts["refuse->refused"] > 0.15 * N_TRAJECTORY
    )
    assert counts["either->accepted"] + counts["either->refused"] < 0.05 * N_TRAJECTORY


# ---------------------------------------------------------------------------------- the oracle's own parts
def test_oracle_kinematics_match_the_robot_model():
    rng = np.random.default_rng(0)
    Q = rng.uniform(LOWER / 2, UPPER / 2, (50, 6))
    expected = np.array([ROBOT.fk_tcp(q)[:3, 3] for q in Q])
    np.testing.assert_allclose(tcp_positions(Q), expected, atol=1e-12)  # the same DH chain: rounding only
    assert 4.0 < REACH_SUM_M < 4.3  # the docstring's bound for a UR5e with a 15 cm tool


@pytest.mark.parametrize("how", VEC_VALID + VEC_BAD)
def test_encodings_are_what_they_claim(how):
    argument, value = encode_array(HOME_Q, how)
    if value is MALFORMED:
        with pytest.raises(InvalidInputError):
            VALIDATORS[(False, False)].validate_joint_move(argument, 1.0, 1.0, HOME_Q)
    else:
        assert VALIDATORS[(False, False)].validate_joint_move(argument, 1.0, 1.0, value).q.tolist() == list(
            value
        )
