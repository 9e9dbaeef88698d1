"""Trends over a long run: the process's memory (RSS), a least-squares slope with its confidence interval,
and the verdicts of the soak benchmarks (`prompose_grasp.eval.soak`): does memory stay flat, does time per
step stay level. The reasoning behind each verdict is in the soak module's docstring."""

from __future__ import annotations

import ctypes
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from prompose_grasp.errors import InvalidInputError

__all__ = ["MIB", "SlopeFit", "fit_slope", "malloc_trim", "memory_verdict", "rss_bytes", "time_verdict"]

MIB = 1024.0 * 1024.0


def malloc_trim() -> bool:
    """Hand the C heap's free pages back to the system (glibc `malloc_trim(0)`); False where there is no
    glibc (the soak then reports NaN for the trimmed RSS)."""
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.malloc_trim(0)  # returns 1 when memory was released, 0 when there was none to release
        return True
    except (OSError, AttributeError):
        return False


def rss_bytes() -> float:
    """The process's resident set size now [bytes] (Linux `/proc/self/statm`); NaN where there is no /proc
    (the soak then reports tracemalloc alone)."""
    try:
        with open("/proc/self/statm") as f:
            return float(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return math.nan


@dataclass(frozen=True)
class SlopeFit:
    """A least-squares line y = a + slope x; `slope`, `lo`, `hi`: the slope per `per` units of x and its
    two-sided `confidence` t interval; `n`: the points fitted; `x_from`, `x_to`: the range of x fitted."""

    slope: float
    lo: float
    hi: float
    n: int
    per: float
    confidence: float
    x_from: float
    x_to: float

    def contains_zero(self) -> bool:
        return self.lo <= 0.0 <= self.hi


def fit_slope(x: Sequence[float], y: Sequence[float], per: float = 1.0, confidence: float = 0.95) -> SlopeFit:
    """Ordinary least squares of y on x; the slope [y units per `per` x units] with its t interval
    (n - 2 degrees of freedom). Needs at least 3 points with distinct x."""
    xa, ya = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    if xa.shape != ya.shape or xa.ndim != 1 or len(xa) < 3:
        raise InvalidInputError(
            f"fit_slope needs two equal 1-D series of >= 3 points, got {xa.shape}, {ya.shape}"
        )
    dx = xa - xa.mean()
    sxx = float(dx @ dx)
    if sxx <= 0.0:
        raise InvalidInputError("fit_slope needs at least two distinct x values")
    slope = float(dx @ (ya - ya.mean())) / sxx
    resid = ya - ya.mean() - slope * dx
    se = math.sqrt(float(resid @ resid) / (len(xa) - 2) / sxx)
    half = float(stats.t.ppf(0.5 + confidence / 2.0, len(xa) - 2)) * se
    return SlopeFit(
        per * slope, per * (slope - half), per * (slope + half), len(xa), per, confidence, xa[0], xa[-1]
    )


def memory_verdict(fit: SlopeFit, tolerance_mib: float) -> dict[str, Any]:
    """{slope_mib, lo_mib, hi_mib (per `fit.per` steps), zero_in_interval, within_tolerance, flat, grows}."""
    within = max(abs(fit.lo), abs(fit.hi)) <= tolerance_mib
    return {
        "slope_mib": fit.slope,
        "lo_mib": fit.lo,
        "hi_mib": fit.hi,
        "per": fit.per,
        "points": fit.n,
        "fitted_steps": [fit.x_from, fit.x_to],
        "tolerance_mib": tolerance_mib,
        "zero_in_interval": fit.contains_zero(),
        "within_tolerance": within,
        "flat": fit.contains_zero() or within,
        # not flat and rising: a leak to look for (not flat and falling: memory handed back)
        "grows": not (fit.contains_zero() or within) and fit.slope > 0,
    }


def time_verdict(
    windows: list[dict[str, Any]], warmup: int, max_slowdown: float = 1.10, per: float = 1.0
) -> dict[str, Any]:
    """The last window's median step time over the first window's after the warm-up (CPU and wall); with
    three windows or more after the warm-up also `cpu_slope_ms`: a line through the windows' median CPU
    times [ms per step] against their middle step, its slope per `per` steps with the 95 % interval
    ([slope, lo, hi]; every window after the warm-up, not only the first and last)."""
    after = [w for w in windows if w["start"] >= warmup]
    if len(after) < 2:
        return {"cpu_ratio": math.nan, "wall_ratio": math.nan, "max_slowdown": max_slowdown, "level": None}
    first, last = after[0], after[-1]
    cpu = last["median_cpu_ms"] / first["median_cpu_ms"]
    wall = last["median_wall_ms"] / first["median_wall_ms"]
    out = {
        "first_window": [first["start"], first["end"]],
        "last_window": [last["start"], last["end"]],
        "cpu_ratio": cpu,
        "wall_ratio": wall,
        "max_slowdown": max_slowdown,
        "level": bool(cpu <= max_slowdown),
    }
    if len(after) >= 3:
        fit = fit_slope(
            [(w["start"] + w["end"]) / 2 for w in after], [w["median_cpu_ms"] for w in after], per
        )
        out["cpu_slope_ms"] = [fit.slope, fit.lo, fit.hi]
    return out
