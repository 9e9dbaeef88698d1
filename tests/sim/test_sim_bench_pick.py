"""The pick benchmark's statistics and the logistics cell's layout (reach), without running episodes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sim.bench_accounting import wilson_interval

SCENES = Path(__file__).resolve().parents[2] / "sim" / "scenes"


@pytest.mark.parametrize(
    ("k", "n", "lo", "hi"),
    [
        # Known answers (Wilson 1927 score interval, z = 1.96; e.g. statsmodels proportion_confint(method=
        # "wilson")), to 4 decimals:
        (0, 10, 0.0, 0.2775),
        (10, 10, 0.7225, 1.0),
        (48, 50, 0.8654, 0.9889),
        (50, 50, 0.9287, 1.0),
        (5, 10, 0.2366, 0.7634),
    ],
)
def test_wilson_interval_known_answers(k, n, lo, hi):
    got = wilson_interval(k, n)
    assert got == pytest.approx((lo, hi), abs=1e-4)  # the reference values are rounded to 4 decimals


def test_wilson_interval_contains_the_rate_and_narrows():
    for n in (5, 20, 80):
        lo, hi = wilson_interval(int(0.8 * n), n)
        assert lo <= 0.8 <= hi
    widths = [np.subtract(*wilson_interval(int(0.8 * n), n)[::-1]) for n in (5, 20, 80)]
    assert widths[0] > widths[1] > widths[2]
    assert wilson_interval(0, 0) == (0.0, 1.0)
    assert all(math.isfinite(v) for v in wilson_interval(3, 7))


@pytest.mark.sim
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_logistics_cell_reaches_every_carton_top_and_the_conveyor(seed):
    # The depalletising cell is laid out for reach: a top-down suction grasp on every carton's top face
    # (pre-grasp 10 cm above) and the conveyor's centre 30 cm above the belt have closed-form IK solutions.
    from prompose_grasp.geometry.se3 import invert_T, make_T
    from sim.scene_file import load_world

    with load_world(SCENES / "logistics_pallet.yaml", seed=seed, settle=False) as world:
        robot = world.robot.robot
        T_base_world = invert_T(world.T_world_base)
        R_down = np.diag([1.0, -1.0, -1.0])  # tcp z (approach) along base -z
        cartons = [o for o in world.objects if o.name.startswith("carton")]
        assert len(cartons) == 12
        sizes = {g.name: g.size_m for g in world.ground_truth("overhead")}
        for o in cartons:
            T = world.T_world_obj(o.name)
            top_world = T[:3, 3] + np.array([0.0, 0.0, sizes[o.name][1] / 2.0])  # object +y is up
            for lift in (0.0, 0.10):
                p_base = (T_base_world @ np.append(top_world + np.array([0.0, 0.0, lift]), 1.0))[:3]
                assert robot.ik(make_T(R_down, p_base), frame="tcp").success, (o.name, lift)
        conveyor = world.place_targets["conveyor"]
        p = (T_base_world @ np.append(conveyor.T_world_surface[:3, 3] + np.array([0.0, 0.0, 0.3]), 1.0))[:3]
        assert robot.ik(make_T(R_down, p), frame="tcp").success


def test_a_unit_that_fails_after_its_retries_is_a_crash_row(monkeypatch, tmp_path):
    # the sweep path (--resume without --ray): an episode whose unit keeps failing ends as a typed crash row
    # counted as a failure, in seed order, while the others are accounted as usual
    import sim.bench_pick as bp
    from prompose_grasp.eval.sweep import SequentialExecutor

    def flaky(spec):
        if spec.seed == 1:
            raise MemoryError("out of memory while rendering")
        return {"seed": spec.seed, "command": "pick up the x", "success": True, "reason": "success",
                "sim_time_s": 1.0, "wall_time_s": 1.0}  # fmt: skip

    monkeypatch.setattr(bp, "episode_unit", flaky)
    out = tmp_path / "r.json"
    report = bp.run_benchmark("tabletop_household", 3, progress=False, executor=SequentialExecutor(),
                              retries=1, json_out=out)  # fmt: skip
    rows = report["rows"]
    assert [r["seed"] for r in rows] == [0, 1, 2]
    assert rows[1]["reason"] == "crash:MemoryError" and rows[1]["unit_attempts"] == 2
    assert rows[1]["command"] == bp._episode_plan("tabletop_household", 1, False, False).command
    assert report["successes"] == 2 and report["episodes"] == 3
    assert len(bp.sweep_file(out).read_text().splitlines()) == 3  # each unit's end, the failure included


def test_the_judged_target_of_a_run_that_found_nothing_among_like_things():
    # "the brown carton" names no scene prompt whole ("cardboard carton"); with nothing estimated and
    # nothing moved, any carton was the command's: the judge names one instead of failing the episode, and a
    # command whose noun names no object at all is still an error.
    from types import SimpleNamespace

    from prompose_grasp.errors import InvalidInputError
    from sim.pick import _target_name

    T = {f"carton_{i}": np.eye(4) for i in range(3)} | {"pallet_wrap": np.eye(4)}
    objects = [SimpleNamespace(name=n, prompt="cardboard carton") for n in T if n.startswith("carton")]
    world = SimpleNamespace(objects=[*objects, SimpleNamespace(name="pallet_wrap", prompt="stretch wrap")])
    world.T_world_obj = lambda name: T[name]
    start = {n: np.eye(4) for n in T}
    assert _target_name(world, "put the brown carton on the conveyor", None, start) == "carton_0"
    # the one that moved is the one the loop acted on
    T["carton_2"] = np.eye(4)
    T["carton_2"][:3, 3] = (0.0, 0.0, 0.3)
    assert _target_name(world, "put the brown carton on the conveyor", None, start) == "carton_2"
    with pytest.raises(InvalidInputError, match="nothing was estimated"):
        _target_name(world, "put the blue sack on the conveyor", None, start)
