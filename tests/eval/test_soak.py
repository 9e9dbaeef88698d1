"""The soak machinery (`prompose_grasp.eval.soak`): the slope and its interval on series known by
construction, the verdicts, and `run_soak` itself on steps that leak and steps that do not (seconds)."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.eval.soak import format_soak, ping_pong, run_soak, write_json
from prompose_grasp.eval.trends import fit_slope, memory_verdict, rss_bytes, time_verdict


def test_slope_of_an_exact_line_is_exact_with_a_zero_width_interval():
    x = np.arange(0, 10_000, 100)
    fit = fit_slope(x, 3.0 + 0.002 * x, per=1000.0)
    # no residual: the interval collapses onto the slope (to rounding of a 100-point sum)
    assert fit.slope == pytest.approx(2.0, rel=1e-12)
    assert fit.hi - fit.lo == pytest.approx(0.0, abs=1e-9)
    assert (fit.n, fit.per, fit.x_from, fit.x_to) == (100, 1000.0, 0, 9900)


def test_interval_covers_the_true_slope_about_95_percent_of_the_time():
    # Monte-Carlo check of the t interval on independent Gaussian noise: 4000 seeded series, coverage
    # 0.95 +- 0.011 (three binomial sd at n = 4000)
    rng = np.random.default_rng(0)
    x = np.arange(30, dtype=float)
    hits = 0
    for _ in range(4000):
        fit = fit_slope(x, 0.5 * x + rng.normal(0.0, 2.0, x.size))
        hits += fit.lo <= 0.5 <= fit.hi
    assert abs(hits / 4000 - 0.95) < 0.011


def test_flat_and_growing_series_are_told_apart():
    rng = np.random.default_rng(1)
    x = np.arange(5000, 10_001, 100)
    flat = fit_slope(x, 900.0 + rng.normal(0.0, 0.5, x.size), per=1000.0)
    growing = fit_slope(x, 900.0 + 0.004 * x + rng.normal(0.0, 0.5, x.size), per=1000.0)
    assert flat.contains_zero() and memory_verdict(flat, tolerance_mib=1.0)["flat"]
    # 4 MiB per 1000 steps, noise 0.5 MiB on 51 points: the interval is ~+-0.2 wide around it
    assert growing.lo > 3.5 and growing.hi < 4.5
    v = memory_verdict(growing, tolerance_mib=1.0)
    assert not v["zero_in_interval"] and not v["within_tolerance"] and not v["flat"]
    assert v["grows"]
    falling = memory_verdict(fit_slope(x, 900.0 - 0.004 * x, per=1000.0), tolerance_mib=1.0)
    assert not falling["flat"] and not falling["grows"]  # memory handed back is no leak
    # a growth within the stated tolerance is flat though the interval excludes zero
    small = fit_slope(x, 900.0 + 1e-4 * x, per=1000.0)
    assert not small.contains_zero() and memory_verdict(small, tolerance_mib=1.0)["flat"]


def test_fit_slope_refuses_too_few_or_degenerate_points():
    with pytest.raises(InvalidInputError, match=">= 3 points"):
        fit_slope([1, 2], [1, 2])
    with pytest.raises(InvalidInputError, match="distinct x"):
        fit_slope([1, 1, 1], [1, 2, 3])


def test_time_verdict_compares_the_last_window_with_the_first_after_warm_up():
    def win(start, ms):
        return {"start": start, "end": start + 10, "median_cpu_ms": ms, "median_wall_ms": 2 * ms}

    windows = [win(0, 100.0), win(10, 10.0), win(20, 10.5), win(30, 12.0)]
    v = time_verdict(windows, warmup=10)
    assert v["first_window"] == [10, 20] and v["last_window"] == [30, 40]
    assert v["cpu_ratio"] == pytest.approx(1.2) and v["level"] is False
    assert time_verdict(windows[:3], warmup=10)["level"] is True  # 10.5 / 10: within 10 %
    # the windows' medians 10, 10.5, 12 ms at steps 15, 25, 35: slope 0.1 ms per step (least squares)
    slope, lo, hi = time_verdict(windows, warmup=10, per=10.0)["cpu_slope_ms"]
    assert slope == pytest.approx(1.0) and lo < slope < hi
    assert time_verdict(windows[:1], warmup=10)["level"] is None  # nothing to compare


def test_ping_pong_plays_a_sequence_back_and_forth_without_a_jump():
    assert list(itertools.islice(ping_pong("abcd"), 10)) == list("abcdcbabcd")
    assert list(itertools.islice(ping_pong("a"), 3)) == list("aaa")
    with pytest.raises(InvalidInputError):
        next(ping_pong([]))


def test_rss_is_read_on_linux():
    # the test machines are Linux; the value is the process's resident size, tens of MiB at least
    assert rss_bytes() > 10 * 2**20


LEAK_LINE = next(i for i, line in enumerate(open(__file__), 1) if line.rstrip().endswith("(LEAK_LINE)"))


@pytest.mark.parametrize("leak_kib", [0, 64])
def test_run_soak_sees_a_leak_and_no_leak(tmp_path, leak_kib):
    kept = []  # the leak lives in this file (the traced memory leaves out allocations made in */soak.py)

    def step(i):
        np.linalg.svd(np.ones((20, 20)))  # some work that frees what it allocates
        if leak_kib:
            kept.append(np.ones(leak_kib * 128))  # leak_kib KiB of float64 per step (LEAK_LINE)
        return {"i": i} if i % 10 == 0 else None

    r = run_soak(
        step,
        40,
        unit="frame",
        per=1000.0,
        warmup=10,
        sample_every=5,
        window=15,
        tolerance_mib=1.0,
        trace_frames=8,
    )
    assert r["n_done"] == r["n_planned"] == 40 and r["stopped"] is None
    assert [s["step"] for s in r["samples"]] == list(range(0, 41, 5))
    assert [(w["start"], w["end"]) for w in r["windows"]] == [(0, 15), (15, 30), (30, 40)]
    assert [s["step"] for s in r["steps"]] == [0, 10, 20, 30]
    traced = r["memory"]["traced"]
    assert traced["fitted_steps"] == [20, 40]  # the second half of the run
    # per 1000 steps: 64 KiB a step is 62.5 MiB; the array headers add ~0.1 KiB a step
    expected = leak_kib * 1000 / 1024
    assert traced["slope_mib"] == pytest.approx(expected, abs=0.3)
    assert traced["flat"] is (leak_kib == 0)
    if leak_kib:  # the leak is the top allocation site that grew
        top = r["top_growth"][0]
        assert top["caller"].endswith(f"test_soak.py:{LEAK_LINE}") and "numpy" in top["site"]
    for key in ("rss", "traced"):
        assert {"slope_mib", "lo_mib", "hi_mib", "per", "flat", "tolerance_mib"} <= set(r["memory"][key])
    assert set(r["time"]) >= {"cpu_ratio", "wall_ratio", "level"}
    assert r["machine"]["cpus"] >= 1
    path = tmp_path / "soak.json"
    write_json(r, path)
    assert json.loads(path.read_text())["n_done"] == 40
    text = format_soak(r)
    assert "traced slope" in text and ("GROWS" in text) is bool(leak_kib)


def test_run_soak_reports_a_step_that_raised_and_keeps_what_ran():
    def step(i):
        if i == 7:
            raise RuntimeError("boom")

    r = run_soak(step, 20, unit="episode", per=100.0, warmup=2, sample_every=1, window=5, tolerance_mib=5.0)
    assert r["n_done"] == 7 and r["stopped"] == "RuntimeError: boom"
    assert len(r["samples"]) == 8 and math.isfinite(r["samples"][-1]["rss_mib"])
    assert "stopped: RuntimeError: boom" in format_soak(r)


def test_run_soak_refuses_bad_settings():
    with pytest.raises(InvalidInputError, match="warmup"):
        run_soak(
            lambda i: None, 10, unit="frame", per=1.0, warmup=10, sample_every=1, window=1, tolerance_mib=1.0
        )


def test_run_soak_samples_the_trimmed_rss_when_asked():
    r = run_soak(
        lambda i: None,
        6,
        unit="frame",
        per=1000.0,
        warmup=1,
        sample_every=1,
        window=2,
        tolerance_mib=1.0,
        trace=False,
        trim=True,
    )
    assert all(math.isfinite(s["rss_trimmed_mib"]) for s in r["samples"])  # glibc on the test machines
    assert {"rss", "rss_trimmed"} == set(r["memory"])  # no tracing: no traced slope
    assert "trimmed RSS MiB" in format_soak(r)
