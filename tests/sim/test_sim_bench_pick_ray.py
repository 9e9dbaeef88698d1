"""bench-pick on a real local Ray cluster: the rows and the summary equal a sequential run's (wall times
aside), in seed order; an interrupted sweep resumes without rerunning the finished episodes."""

from __future__ import annotations

import json

import pytest

from prompose_grasp.eval.sweep import RayExecutor
from sim.bench_pick import deterministic_view, run_benchmark, sweep_file

pytestmark = [pytest.mark.sim, pytest.mark.slow]


def _same(a: dict, b: dict) -> bool:
    # JSON text: the resumed rows come back from the resume file, tuples as lists
    return json.dumps(deterministic_view(a), sort_keys=True) == json.dumps(
        deterministic_view(b), sort_keys=True
    )


def test_ray_bench_pick_rows_equal_sequential_and_resume(ray_local, tmp_path):
    seq = run_benchmark("tabletop_household", 2, seed0=0, progress=False)
    out = tmp_path / "ray.json"
    par = run_benchmark(
        "tabletop_household", 2, seed0=0, progress=False, json_out=out, executor=RayExecutor()
    )
    assert [r["seed"] for r in par["rows"]] == [0, 1]
    assert par["executor"].startswith("ray")
    assert _same(seq, par)

    lines = sweep_file(out).read_text().splitlines()
    assert len(lines) == 2
    sweep_file(out).write_text(lines[0] + "\n")  # the second episode was in flight when stopped
    again = run_benchmark(
        "tabletop_household", 2, seed0=0, progress=False, json_out=out, resume=True, executor=RayExecutor()
    )
    assert len(sweep_file(out).read_text().splitlines()) == 2  # one episode run again, appended
    assert _same(seq, again)
