"""The sweep fan-out (`prompose_grasp.eval.sweep`): the sequential executor and a real local Ray cluster
give the same results in the units' order; a worker killed mid-unit is survived by a retry; a unit that
always raises ends as its typed failure while the others finish; an interrupted sweep resumes without
redoing finished units."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from sweep_units import always_dies_unit, dies_once_unit, raising_unit, seeded_unit, threads_unit

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.eval.sweep import (
    RayExecutor,
    Unit,
    UnitFailure,
    parse_ray_address,
    read_resume_file,
    run_sweep,
)


def _units(n: int, **extra) -> list[Unit]:
    return [Unit(f"u{i:03d}", {"seed": i, **extra}) for i in range(n)]


def test_parse_ray_address():
    assert parse_ray_address("local:2") == {"num_cpus": 2}
    assert parse_ray_address("auto") == {"address": "auto"}
    assert parse_ray_address("10.0.0.5:6379") == {"address": "10.0.0.5:6379"}
    for bad in ("", "local:x", "local:0"):
        with pytest.raises(InvalidInputError):
            parse_ray_address(bad)


def test_sequential_sweep_keeps_unit_order_and_retries_then_fails(tmp_path):
    units = [*_units(3), Unit("bad", {"seed": 99, "fail": True})]
    sweep = run_sweep(raising_unit, units, retries=1, resume_file=tmp_path / "r.jsonl", progress=False)
    assert list(sweep.results) == ["u000", "u001", "u002"]
    assert sweep.failures == {"bad": UnitFailure("bad", "KeyError", "'unit 99 has no such key'", 2)}
    assert [uid for uid, _ in sweep.rows()] == ["u000", "u001", "u002", "bad"]
    with pytest.raises(InvalidInputError, match="unique"):
        run_sweep(seeded_unit, _units(2) + _units(1), progress=False)


def test_ray_results_equal_sequential_bytes(ray_local, tmp_path):
    units = _units(6)
    seq = run_sweep(seeded_unit, units, resume_file=tmp_path / "seq.jsonl", progress=False)
    par = run_sweep(
        seeded_unit, units, executor=RayExecutor(), resume_file=tmp_path / "ray.jsonl", progress=False
    )
    assert list(par.results) == [u.id for u in units]  # the units' order, not the finish order
    assert json.dumps(par.results) == json.dumps(seq.results)
    assert par.executor.startswith("ray")
    # the resume file holds every unit's result once, in any order
    assert {k: v["result"] for k, v in read_resume_file(tmp_path / "ray.jsonl").items()} == seq.results


def test_ray_unit_threads_are_pinned(ray_local):
    sweep = run_sweep(threads_unit, _units(1), executor=RayExecutor(), num_cpus=1, progress=False)
    assert sweep.results["u000"] == {"OMP_NUM_THREADS": "1", "LP_NUM_THREADS": "1", "MUJOCO_GL": "egl"}


def test_ray_survives_a_killed_worker_and_reports_a_raising_unit(ray_local, tmp_path):
    marker = tmp_path / "died_once"
    units = [Unit("dies", {"seed": 0, "marker": str(marker)})]
    sweep = run_sweep(dies_once_unit, units, executor=RayExecutor(), retries=2, progress=False)
    assert marker.exists()  # the first attempt ran and its process ended
    assert sweep.failures == {}
    assert sweep.results["dies"] == seeded_unit({"seed": 0})

    units = [*_units(3), Unit("bad", {"seed": 9, "fail": True})]
    sweep = run_sweep(raising_unit, units, executor=RayExecutor(), retries=1, progress=False)
    assert list(sweep.results) == ["u000", "u001", "u002"]
    assert sweep.failures["bad"].error == "KeyError" and sweep.failures["bad"].attempts == 2

    # a worker that dies on every attempt: the unit's typed failure after its attempts, not a crash
    sweep = run_sweep(always_dies_unit, _units(1), executor=RayExecutor(), retries=1, progress=False)
    assert sweep.failures["u000"].error == "worker_died" and sweep.failures["u000"].attempts == 2


def test_interrupted_sweep_resumes_without_rerunning(tmp_path):
    resume = tmp_path / "sweep.jsonl"
    units = _units(4)
    first = run_sweep(seeded_unit, units[:2], resume_file=resume, progress=False)
    with resume.open("a") as f:
        f.write('{"unit": "u002", "ok": tr')  # the driver was killed while writing a line
    calls = []

    def counting(payload):
        calls.append(payload["seed"])
        return seeded_unit(payload)

    again = run_sweep(counting, units, resume_file=resume, resume=True, progress=False)
    assert calls == [2, 3] and again.resumed == ("u000", "u001")
    full = run_sweep(seeded_unit, units, progress=False)
    assert json.dumps(again.results) == json.dumps(full.results)
    assert {k: first.results[k] for k in first.results} == {k: again.results[k] for k in first.results}


def test_without_ray_nothing_imports_it():
    # a fresh interpreter: the sequential sweep and the entry points' modules leave Ray unimported
    code = (
        "import sys; from prompose_grasp.eval.sweep import Unit, run_sweep; "
        "import sim.dataset, sim.bench_pick, prompose_grasp.eval.bench_estimator; "
        "run_sweep(len, [Unit('a', 'xy')], progress=False); assert 'ray' not in sys.modules, 'ray imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).resolve().parents[2])


def test_bad_ray_values_fail_before_any_work(tmp_path, capsys):
    from prompose_grasp.cli import main as cli_main
    from sim.dataset import main as dataset_main

    out = tmp_path / "never"
    assert dataset_main(["--out", str(out), "--ray", "local:x"]) == 2
    assert not out.exists()  # not even split.json
    assert dataset_main(["--out", str(out), "--ray", "local:1", "--retries", "-1"]) == 2
    assert cli_main(["bench", "--data", str(tmp_path), "--ray", ""]) == 2
    assert cli_main(["bench", "--data", str(tmp_path), "--resume"]) == 2  # no --json to keep scenes in
    assert "--ray" in capsys.readouterr().err
