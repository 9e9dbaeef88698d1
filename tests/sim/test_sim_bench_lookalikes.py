"""The pick benchmark's prompt styles, the `lookalikes` scenario and the outcome accounting.

Scenes are built (not run) and the accounting is fed hand-built rows; one short closed-loop episode checks
that a real row carries what the accounting needs."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sim import bench_pick
from sim.bench_accounting import (
    COLOUR_WORDS,
    bare_name,
    describe_prompt,
    fitting_objects,
    judge,
    tally,
    tally_by_kind,
)
from sim.bench_pick import _episode_plan, format_report, resolve_prompts, summarise
from sim.lookalikes import (
    CATALOGUE,
    COLOURS,
    GROUPS,
    MAX_TARGET_GRIP_M,
    lookalike_plan,
    lookalike_scene,
    tells_apart,
)

SHARED_OBJECTS = Path(__file__).resolve().parents[3] / "shared" / "data" / "objects"
CATALOGUE_BY_NAME = {p.name: p for p in CATALOGUE}

pytestmark = pytest.mark.sim


# ------------------------------------------------------------------------------------------------------------
# --prompts


@pytest.fixture
def fake_real_meshes(tmp_path, monkeypatch):
    """A stand-in for ../shared/data/objects: three small meshes and their objects.json."""
    items = []
    for name, prompt, ext in (
        ("banana", "banana", (0.18, 0.04, 0.05)),
        ("alarmclock", "alarm clock", (0.12, 0.05, 0.1)),
        ("mug", "mug", (0.1, 0.08, 0.1)),
    ):
        d = tmp_path / f"grab_{name}"
        d.mkdir()
        trimesh.creation.box(extents=ext).export(d / "model.obj")
        items.append({"dir": d.name, "name": name, "prompt": prompt, "extents_m": list(ext)})
    (tmp_path / "objects.json").write_text(json.dumps(items))
    monkeypatch.setattr(bench_pick, "REAL_MESHES_DIR", tmp_path)
    return items


def test_prompts_name_says_the_bare_object_name_and_keeps_the_scene_colours(fake_real_meshes):
    prompts = {o["prompt"] for o in fake_real_meshes}
    for seed in range(4):
        named = _episode_plan("real_meshes", seed, False, False, "name")
        coloured = _episode_plan("real_meshes", seed, False, False, "colour+name")
        assert named.target_object == coloured.target_object  # the same draw either way
        said = named.command.removeprefix("pick up the ")
        assert said in prompts and not set(said.split()) & COLOUR_WORDS
        colour, kind = coloured.command.removeprefix("pick up the ").split(" ", 1)
        assert colour in COLOUR_WORDS and kind == said
        # the scene objects keep their colours and coloured prompts (ground truth) with --prompts name
        scene = named.objects
        assert all(o["colour"] in COLOUR_WORDS and o["prompt"] == f"{o['colour']} {o['kind']}" for o in scene)
        assert named.fitting_objects == [named.target_object]
        doc = __import__("yaml").safe_load(named.scene.read_text())
        assert [o["prompt"] for o in doc["objects"]] == [o["prompt"] for o in scene]
        assert len({tuple(o["rgba"]) for o in doc["objects"]}) == len(doc["objects"])
    place = _episode_plan("real_meshes", 0, True, False, "name")
    assert place.command.startswith("put the ") and place.command.endswith(" in the bin")


def test_prompts_name_on_the_scene_file_scenarios():
    assert (
        _episode_plan("tabletop_household", 11, False, False, "colour+name").command == "pick up the red mug"
    )
    assert _episode_plan("tabletop_household", 11, False, False, "name").command == "pick up the mug"
    plans = [_episode_plan("tabletop_household", s, False, False, "name") for s in range(30)]
    said = {p.command.removeprefix("pick up the ") for p in plans}
    assert "mug" in said and "soda can" in said and not {w for s in said for w in s.split()} & COLOUR_WORDS
    assert all(p.fitting_objects == [p.target_object] for p in plans)
    logistics = _episode_plan("logistics_pallet", 0, False, False, "name")
    assert logistics.command == "put the carton on the conveyor"
    assert resolve_prompts("lookalikes", None) == "name"
    assert resolve_prompts("real_meshes", None) == "colour+name"
    from prompose_grasp.errors import InvalidInputError

    with pytest.raises(InvalidInputError):
        resolve_prompts("lookalikes", "colour+name")
    import argparse

    p = argparse.ArgumentParser()
    bench_pick.add_arguments(p)
    assert p.parse_args(["--scenario", "real_meshes", "--prompts", "name"]).prompts == "name"
    assert p.parse_args(["--scenario", "real_meshes"]).prompts is None
    with pytest.raises(SystemExit):
        p.parse_args(["--scenario", "real_meshes", "--prompts", "colour"])


@pytest.mark.shared_data
@pytest.mark.skipif(
    not (SHARED_OBJECTS / "objects.json").is_file(), reason="../shared/data/objects is absent"
)
def test_real_meshes_prompts_name_with_the_shared_meshes():
    entries = {e["name"]: e for e in json.loads((SHARED_OBJECTS / "objects.json").read_text())}
    for seed in range(3):
        plan = _episode_plan("real_meshes", seed, False, False, "name")
        assert plan.command == f"pick up the {entries[plan.target_object]['prompt']}"
        assert len(plan.objects) == 5 and plan.fitting_objects == [plan.target_object]


# ------------------------------------------------------------------------------------------------------------
# lookalikes: the catalogue and the scene builder


def test_catalogue_is_real_sized_and_each_target_has_lookalikes_that_differ():
    assert set(GROUPS) == {"box", "can", "bottle"}
    for p in CATALOGUE:
        assert p.name.split()[-1] == p.group  # the head noun is the group's
        assert all(c in COLOURS for c in p.colours)
        assert all(0.02 <= s <= 0.35 for s in p.size_m), p  # products, in metres
    # the sizes a shopper knows (general knowledge of the real products)
    assert CATALOGUE_BY_NAME["soda can"].size_m == pytest.approx((0.066, 0.122, 0.066))
    assert CATALOGUE_BY_NAME["tuna can"].size_m[1] < 0.05 < CATALOGUE_BY_NAME["tuna can"].size_m[0]
    assert CATALOGUE_BY_NAME["sugar box"].size_m == pytest.approx((0.089, 0.175, 0.038))
    for g in GROUPS:
        members = [p for p in CATALOGUE if p.group == g]
        for t in (p for p in members if p.grip_m <= MAX_TARGET_GRIP_M):
            for c in t.colours:
                apart = [p for p in members if p is not t and any(tells_apart(t, c, p, d) for d in p.colours)]
                assert len(apart) >= 3, (t.name, c)
    same = CATALOGUE_BY_NAME["soda can"]
    assert not tells_apart(same, "red", same, "silver")  # two soda cans: the name does not tell them apart


@pytest.mark.parametrize("seed", range(40))
def test_lookalike_plan_by_construction(seed):
    plan = lookalike_plan(seed)
    assert plan == lookalike_plan(seed)  # deterministic per seed
    objs = plan["objects"]
    said = plan["said"]
    target = CATALOGUE_BY_NAME[said]
    assert plan["command"] == f"pick up the {said}"
    assert target.grip_m <= MAX_TARGET_GRIP_M
    assert len({o["name"] for o in objs}) == len(objs)
    for o in objs:  # every object is a catalogue product at its catalogue size and one of its colours
        p = CATALOGUE_BY_NAME[o["kind"]]
        assert o["size_m"] == pytest.approx(p.size_m) and o["colour"] in p.colours
        assert o["prompt"] == f"{o['colour']} {o['kind']}" and o["group"] == p.group
    group = [o for o in objs if o["group"] == target.group]
    assert 3 <= len(group) <= 4 and 1 <= len(objs) - len(group) <= 2
    fit = [o for o in objs if o["kind"] == said]
    assert plan["fitting_objects"] == [o["name"] for o in fit]
    # the accounting's reading of the words agrees with the construction
    assert fitting_objects(plan["command"], objs) == plan["fitting_objects"]
    if seed % 2 == 0:
        assert plan["lookalike_kind"] == "implied"
        assert len(fit) == 1 and plan["target_object"] == fit[0]["name"]
        for o in group:  # every look-alike differs in size (>= 15 %) or colour
            if o is not fit[0]:
                assert tells_apart(target, fit[0]["colour"], CATALOGUE_BY_NAME[o["kind"]], o["colour"])
    else:
        assert plan["lookalike_kind"] == "not_implied"
        assert len(fit) == 2 and plan["target_object"] is None
        assert fit[0]["size_m"] == fit[1]["size_m"]
        assert not set(plan["command"].split()) & COLOUR_WORDS


def test_lookalike_kinds_cover_every_group():
    plans = [lookalike_plan(s) for s in range(60)]
    for kind in ("implied", "not_implied"):
        groups = {CATALOGUE_BY_NAME[p["said"]].group for p in plans if p["lookalike_kind"] == kind}
        assert groups == set(GROUPS)
    # not_implied: some pairs share a colour, some differ in colour only
    pairs = [
        {o["colour"] for o in p["objects"] if o["name"] in p["fitting_objects"]}
        for p in plans
        if p["lookalike_kind"] == "not_implied"
    ]
    assert any(len(c) == 1 for c in pairs) and any(len(c) == 2 for c in pairs)


@pytest.mark.parametrize("seed", [0, 1])
def test_lookalike_scene_builds_the_catalogue_objects(seed):
    from sim.scene_file import build_scene, parse_scene

    doc, plan = lookalike_scene(seed)
    with build_scene(parse_scene(doc), seed=seed, settle=False) as world:
        gt = {g.name: g for g in world.ground_truth("front")}
        assert [o.name for o in world.objects] == [o["name"] for o in plan["objects"]]
        table_top = world.T_world_obj(plan["objects"][0]["name"])[2, 3] - plan["objects"][0]["size_m"][1] / 2
        for o in plan["objects"]:
            np.testing.assert_allclose(gt[o["name"]].size_m, o["size_m"], atol=1e-4)
            assert gt[o["name"]].prompt == o["prompt"]
            T = world.T_world_obj(o["name"])
            assert T[2, 1] == pytest.approx(1.0, abs=1e-6)  # upright on the table: object +y is world up
            assert T[2, 3] - o["size_m"][1] / 2 == pytest.approx(table_top, abs=3e-3)
            x, y = T[0, 3], T[1, 3]  # inside the tabletop region of real_meshes
            assert -0.55 <= x <= 0.25 and -0.35 <= y <= 0.25
    assert plan["lookalike_kind"] == ("implied", "not_implied")[seed]


def test_lookalikes_episode_plan_hands_over_the_construction():
    plan = _episode_plan("lookalikes", 3, False, False, "name")
    lp = lookalike_plan(3)
    assert plan.command == lp["command"] and plan.lookalike_kind == "not_implied"
    assert plan.fitting_objects == lp["fitting_objects"] and plan.target_object is None
    assert [o["name"] for o in plan.objects] == [o["name"] for o in lp["objects"]]
    assert plan.scene.is_file()


# ------------------------------------------------------------------------------------------------------------
# the words and the objects they fit


def _obj(name, kind, colour=None, size=None):
    return {"name": name, "kind": kind, "colour": colour, "size_m": size}


def test_fitting_objects_reads_names_colours_and_sizes():
    objs = [
        _obj("a", "soda can", "red", (0.066, 0.122, 0.066)),
        _obj("b", "soda can", "silver", (0.066, 0.122, 0.066)),
        _obj("c", "tuna can", "silver", (0.085, 0.035, 0.085)),
        _obj("d", "sugar box", "white", (0.089, 0.175, 0.038)),
    ]
    assert fitting_objects("pick up the soda can", objs) == ["a", "b"]
    assert fitting_objects("pick up the red soda can", objs) == ["a"]
    assert fitting_objects("pick up the silver can", objs) == ["b", "c"]
    assert fitting_objects("pick up the can", objs) == ["a", "b", "c"]
    assert fitting_objects("pick up the tuna can", objs) == ["c"]
    assert fitting_objects("pick up the big can", objs) == ["a", "b"]  # by volume; the two are the same size
    assert fitting_objects("pick up the tall can", objs) == ["a", "b"]
    assert fitting_objects("pick up the small box", objs) == ["d"]
    assert fitting_objects("put the soda can in the bin", objs) == ["a", "b"]
    assert fitting_objects("pick up the banana", objs) == []
    # a scene file's objects: kind and colour come from the prompt
    assert fitting_objects("pick up the mug", [{"name": "mug", "prompt": "red mug"}]) == ["mug"]
    assert describe_prompt("blue paper cup") == ("blue", "paper cup")
    assert describe_prompt("tea box") == (None, "tea box")
    assert bare_name("red banana") == "banana" and bare_name("blue paper cup") == "paper cup"


# ------------------------------------------------------------------------------------------------------------
# the accounting, on hand-built rows


def test_judge_separates_wrong_object_successes_and_judges_refusals():
    one, two = ["tea_box"], ["soda_can_1", "soda_can_2"]
    assert judge("success", True, one, ["tea_box"])["reason"] == "success"
    v = judge("success", False, one, ["pudding_box"])
    assert v["reason"] == "wrong_object_success" and v["wrong_objects"] == ["pudding_box"]
    assert not v["success"]
    assert judge("success", False, one, [])["reason"] == "false_success"
    assert judge("ambiguous", False, two)["ambiguous"] == "correct"
    assert judge("ambiguous", False, one)["ambiguous"] == "wrong"
    assert judge("ambiguous", False, one)["reason"] == "ambiguous"
    assert judge("wrong_object", False, one, [])["reason"] == "wrong_object"
    assert judge("not_found", False, one)["reason"] == "not_found"
    # a place: the object that ended in the bin decides
    assert judge("success", False, one, [], ["gelatin_box"], place=True)["reason"] == "wrong_object_success"
    assert judge("success", False, one, ["tea_box"], [], place=True)["reason"] == "false_success"


def _row(seed, kind, loop_reason, gt_success, fitting, lifted=()):
    return {
        "seed": seed,
        "lookalike_kind": kind,
        "loop_reason": loop_reason,
        **judge(loop_reason, gt_success, fitting, list(lifted)),
        "sim_time_s": 5.0,
        "wall_time_s": 2.0,
    }


def test_the_report_counts_every_kind_of_outcome():
    one, two = ["tea_box"], ["soda_can_1", "soda_can_2"]
    rows = [
        _row(0, "implied", "success", True, one, ["tea_box"]),
        _row(2, "implied", "success", False, one, ["pudding_box"]),  # wrong-object success
        _row(4, "implied", "ambiguous", False, one),  # refused clear words
        _row(6, "implied", "wrong_object", False, one),  # caught and put back
        _row(8, "implied", "slipped", False, one),
        _row(1, "not_implied", "ambiguous", False, two),
        _row(3, "not_implied", "ambiguous", False, two),
        _row(5, "not_implied", "success", True, two, ["soda_can_2"]),  # picked one without asking
        _row(7, "not_implied", "success", False, two, ["tuna_can"]),  # wrong-object success
        _row(9, "not_implied", "success", False, two, []),  # false success
    ]
    t = tally(rows)
    assert t["wrong_object_success"] == 2 and t["false_success"] == 1 and t["wrong_object"] == 1
    assert t["ambiguous"] == {"total": 3, "correct": 2, "wrong": 1}
    assert t["other_failures"] == {"slipped": 1} and t["wrong_pick"] == 3
    k = tally_by_kind(rows)
    assert k["implied"]["top1"]["count"] == 1 and k["implied"]["wrong_pick"]["count"] == 2
    assert k["implied"]["ambiguous"] == 1
    assert k["not_implied"]["ambiguous"]["count"] == 2 and k["not_implied"]["picked_one"] == 1
    assert k["not_implied"]["wrong_pick"]["count"] == 1
    assert k["not_implied"]["ambiguous"]["rate"] == pytest.approx(0.4)
    lo, hi = k["not_implied"]["ambiguous"]["wilson95"]
    assert lo < 0.4 < hi
    r = summarise(rows, {"scenario": "lookalikes", "prompts": "name", "seed0": 0, "episodes": 10})
    assert r["successes"] == 2 and r["success_rate"] == pytest.approx(0.2)
    assert r["prompts"] == "name" and r["reasons"]["wrong_object_success"] == 2
    text = format_report(r)
    first = text.splitlines()[0]
    assert "2/10" in first and "wrong-object successes 2" in first
    assert "ambiguous 3 (correct 2, wrong 1)" in text and "slipped 1" in text
    assert "not_implied (5): ambiguous 2/5" in text
    json.dumps(r)  # the report is JSON-ready
    # scenarios without look-alike kinds: no per-kind table
    plain = summarise([{**rows[0], "lookalike_kind": None}], {"scenario": "tabletop_household"})
    assert plain["by_kind"] == {} and math.isclose(plain["success_rate"], 1.0)


# ------------------------------------------------------------------------------------------------------------
# one closed-loop episode: the row carries what the accounting needs


@pytest.mark.slow  # ~11 s on an idle 2-core machine, ~55 s while other jobs share it
def test_one_lookalikes_episode_is_accounted():
    report = bench_pick.run_benchmark("lookalikes", 1, seed0=1, progress=False)
    row = report["rows"][0]
    assert not row["reason"].startswith("crash"), row["message"]
    assert row["lookalike_kind"] == "not_implied" and len(row["fitting_objects"]) == 2
    assert {o["name"] for o in row["scene_objects"]} >= set(row["fitting_objects"])
    assert all(o["size_m"] is not None and o["kind"] for o in row["scene_objects"])
    assert isinstance(row["lifted_objects"], list)
    assert set(row["lifted_objects"]) <= {n for n, m in (row["moved"] or {}).items() if m["lift_m"] >= 0.05}
    if row["reason"] == "success":
        assert set(row["lifted_objects"]) & set(row["fitting_objects"])
    if row["loop_reason"] == "success" and row["reason"] != "success":
        assert row["reason"] in ("wrong_object_success", "false_success")
    assert row["reason"] != "ambiguous" or row["ambiguous"] == "correct"
    assert report["by_kind"]["not_implied"]["episodes"] == 1
