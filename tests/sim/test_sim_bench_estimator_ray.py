"""`prompose-grasp bench` with each scene a Ray task on a real local cluster: the NOCS tables equal the
sequential run's (the per-image arrays cross the workers as JSON, float64 exactly)."""

from __future__ import annotations

import json

import pytest

from prompose_grasp.eval.bench_estimator import run_estimator_benchmark
from prompose_grasp.eval.sweep import RayExecutor
from sim.dataset import DatasetConfig, generate

pytestmark = [pytest.mark.sim, pytest.mark.slow]


def test_ray_estimator_bench_tables_equal_sequential(ray_local, tmp_path):
    # 10 scenes: 2 test scenes (20 %), 2 frames each, small images; the oracle-mask rows only (no grounding)
    data = tmp_path / "data"
    cfg = DatasetConfig(out=str(data), scenes=10, frames=2, seed=1, width=160, height=120, workers=1)
    generate(cfg, progress=False, executor=RayExecutor())
    methods = "ours_oracle_mask,obb_oracle_mask"
    seq = run_estimator_benchmark(data, methods=methods, progress=False)
    resume = tmp_path / "bench.sweep.jsonl"
    par = run_estimator_benchmark(
        data, methods=methods, progress=False, executor=RayExecutor(), resume_file=resume
    )
    assert seq["frames"] == par["frames"] == 4 and par["failed_scenes"] == []
    assert json.dumps(par["tables"], sort_keys=True) == json.dumps(seq["tables"], sort_keys=True)
    again = run_estimator_benchmark(data, methods=methods, progress=False, resume=True, resume_file=resume)
    assert json.dumps(again["tables"], sort_keys=True) == json.dumps(seq["tables"], sort_keys=True)
