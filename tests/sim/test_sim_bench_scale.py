"""`python -m sim.bench_scale`: the scale-out estimate's arithmetic, and a tiny dataset run on the local Ray
cluster that reports identical outputs and writes its JSON."""

from __future__ import annotations

import json

import pytest

from sim.bench_scale import estimate_wall_s, main


def test_estimate_is_exact_on_one_core_and_bounded_by_dispatch():
    # one core: the units one after the other, plus start-up and warm-up
    assert estimate_wall_s(10, 1, 2.0, 5.0, 0.0, 1.0, 3.0) == pytest.approx(10 * 2.0 + 1.0 + 3.0)
    # many cores: work / C plus Graham's tail (1 - 1/C) x longest unit
    assert estimate_wall_s(100, 10, 2.0, 5.0, 0.0, 0.0, 0.0) == pytest.approx(20.0 + 0.9 * 5.0)
    # more cores than units: each unit on its own core, the longest decides
    assert estimate_wall_s(4, 512, 2.0, 5.0, 0.0, 0.0, 0.0) == pytest.approx(2.0 + 0.75 * 5.0)
    # a driver that needs 10 ms per task caps 10,000 units of 1 s at 100 s whatever the core count
    assert estimate_wall_s(10_000, 512, 1.0, 1.0, 0.01, 0.0, 0.0) == pytest.approx(100.0)


@pytest.mark.sim
@pytest.mark.slow
def test_tiny_dataset_run_is_identical(ray_local, tmp_path):
    out = tmp_path / "scale.json"
    argv = ["--jobs", "dataset", "--scenes", "3", "--frames", "1", "--width", "64", "--height", "48",
            "--noop-tasks", "10", "--json", str(out)]  # fmt: skip
    assert main(argv) == 0
    report = json.loads(out.read_text())
    job = report["jobs"]["dataset"]
    assert job["identical"] and job["units"] == 3 and job["speedup"] > 0
    assert set(report["scale_out"]["dataset"]["wall_s"]) == {"1", "2", "64", "512"}
    walls = report["scale_out"]["dataset"]["wall_s"]
    assert walls["1"] >= walls["2"] >= walls["64"] >= walls["512"] > 0
