"""Soak benchmarks: does memory stay flat and time per step stay level over a long run in one process?

    python -m prompose_grasp.eval.soak --frames DIR --prompt "the blue box" --intrinsics FX FY CX CY \\
        [--depth-scale 0.001] [--n 10000] [--json OUT]

tracks one object over a recorded `NNNNNN-color.png` / `-depth.png` folder (`perception.frames_io`) played
back and forth until `--n` frames have been tracked: `ProMPose.track` really runs on every frame. The
simulator's soaks (`python -m sim soak-track`, a rendered orbit; `python -m sim soak-episodes`, back-to-back
pick episodes) use the same machinery (`run_soak`).

What is measured, at every `sample_every`-th step after a `gc.collect()`: the resident set size (RSS, from
`/proc/self/statm`: everything the process holds, C libraries and the allocator's slack included) and the
memory traced by `tracemalloc` (Python objects and numpy buffers; not MuJoCo's, torch's or OpenGL's own
allocations). Every step's wall and process-CPU time (CPU time counts every thread of the process; wall time
on a shared machine also counts the other jobs).

What "flat" means (`memory_verdict`): after the warm-up, a least-squares line through the samples of the
second half of the run; its slope per `per` steps with a 95 % t interval. Flat: the interval contains zero,
or lies within +-`tolerance_mib` per `per` steps (a leak too small to matter over a day: the tolerance is
stated with the numbers). The samples are serially correlated (a heap grows and shrinks in steps), so the
interval is narrower than an honest one would be: a flat verdict is the stronger for it, a growth verdict
wants a look at `top_growth` (the `tracemalloc` allocation sites that grew most between the end of the
warm-up and the end of the run).

"No slowdown" (`time_verdict`): the median per-step CPU time of the last window over that of the first window
after the warm-up, at most `max_slowdown` (1.10: ten per cent, above the spread of medians of a few hundred
steps on a quiet machine); the same ratio for wall time is reported beside it.
"""

from __future__ import annotations

import argparse
import gc
import json
import logging
import math
import os
import platform
import sys
import time
import tracemalloc
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError, PromposeError
from prompose_grasp.eval.trends import MIB, fit_slope, malloc_trim, memory_verdict, rss_bytes, time_verdict

__all__ = [
    "add_measurement_arguments",
    "format_soak",
    "measurement_options",
    "ping_pong",
    "run_soak",
    "soak_track",
]

log = logging.getLogger(__name__)

#: What the traced memory leaves out: tracemalloc's own allocations, the import system's, and those made on
#: the lines of the soak scripts themselves (`*/soak.py`: the samples and step facts they keep; the steps'
#: own work runs in other files and is traced).
_NOT_TRACED = (
    tracemalloc.Filter(False, tracemalloc.__file__),
    tracemalloc.Filter(False, "<frozen importlib*"),
    tracemalloc.Filter(False, "*/soak.py"),
)


def _traced_bytes() -> float:
    """Live traced memory now [bytes], less `_NOT_TRACED`."""
    return float(sum(t.size for t in tracemalloc.take_snapshot().filter_traces(_NOT_TRACED).traces))


def _own_frame(tb: tracemalloc.Traceback) -> tracemalloc.Frame:
    """The innermost frame of a traceback outside installed packages and the standard library (the code
    that asked numpy for the array), else the innermost frame."""
    frames = list(tb)  # oldest first
    for f in reversed(frames):
        if "site-packages" not in f.filename and not f.filename.startswith(
            ("<", sys.prefix, sys.base_prefix)
        ):
            return f
    return frames[-1]


def _top_growth(before: tracemalloc.Snapshot, after: tracemalloc.Snapshot, n: int = 12) -> list[dict]:
    """The allocation sites whose live traced memory changed most (by size) between the two snapshots:
    `site` the innermost frame, `caller` the innermost frame of this project's code (with `trace_frames`
    > 1; numpy's own lines say little)."""
    keep = list(_NOT_TRACED)
    diff = after.filter_traces(keep).compare_to(before.filter_traces(keep), "traceback")
    out = []
    for s in diff[:n]:
        site, caller = list(s.traceback)[-1], _own_frame(s.traceback)
        out.append(
            {
                "site": f"{site.filename}:{site.lineno}",
                "caller": f"{caller.filename}:{caller.lineno}",
                "size_diff_kib": s.size_diff / 1024.0,
                "count_diff": s.count_diff,
                "size_kib": s.size / 1024.0,
            }
        )
    return out


def run_soak(
    step: Callable[[int], dict[str, Any] | None],
    n: int,
    *,
    unit: str,
    per: float,
    warmup: int,
    sample_every: int,
    window: int,
    tolerance_mib: float,
    trace: bool = True,
    trace_frames: int = 1,
    trim: bool = False,
    progress: Callable[[str], object] | None = None,
    on_sample: Callable[[dict[str, Any]], None] | None = None,
    meta: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Run `step(i)` for i = 0 .. n - 1 and report memory and time (see the module's docstring).

    `step` returns a dict of facts about that step (kept in `steps`, e.g. an episode's outcome) or None.
    `unit`: "frame" | "episode"; `per`: the slopes' unit of steps (1000 frames, 100 episodes). `warmup`:
    steps left out of the slopes and of the time windows' comparison. `trace`: run `tracemalloc` (started
    here when it is not running; what was allocated before is not traced); `trace_frames`: frames kept per
    allocation (1 is cheapest; more name the caller of numpy in `top_growth`, for a leak hunt).
    `trim`: after each RSS sample, hand the allocator's free memory back to the system (glibc
    `malloc_trim(0)`) and sample the RSS again (`rss_trimmed_mib`, with its own slope): RSS that rises in
    steps and stays is either live memory or the heap's high-water mark, and the trimmed RSS tells them
    apart. It changes what it measures a little (the next step faults the pages in again).
    `progress`: a line per sample.
    `on_sample`: the report so far, after every sample (a long run writes it out and can be stopped).
    A step that raises stops the soak early; the report says so (`n_done`, `stopped`).
    """
    if n < 1 or sample_every < 1 or window < 1 or not 0 <= warmup < n:
        raise InvalidInputError(
            f"soak needs n >= 1, sample_every >= 1, window >= 1, 0 <= warmup < n; got n={n}, "
            f"sample_every={sample_every}, window={window}, warmup={warmup}"
        )
    samples: list[dict[str, Any]] = []
    steps: list[dict[str, Any]] = []
    # per-step times [s], allocated before tracing starts (a growing list would be a traced growth)
    wall_s, cpu_s = np.full(n, np.nan), np.full(n, np.nan)
    done = 0
    snap_warm = None
    top: list[dict] = []
    t_start = time.perf_counter()
    stopped = None

    def sample(i: int) -> None:
        gc.collect()
        traced = _traced_bytes() / MIB if trace else math.nan
        row = {
            "step": i,
            "rss_mib": rss_bytes() / MIB,
            "traced_mib": traced,
            "wall_s": time.perf_counter() - t_start,
        }
        if trim:
            row["rss_trimmed_mib"] = rss_bytes() / MIB if malloc_trim() else math.nan
        samples.append(row)

    def report() -> dict[str, Any]:
        return _report(
            samples,
            steps,
            wall_s[:done],
            cpu_s[:done],
            n,
            unit,
            per,
            warmup,
            window,
            tolerance_mib,
            trace,
            top,
            stopped,
            meta,
        )

    meta = {"trace_frames": trace_frames if trace else 0, **(meta or {})}
    started_tracing = trace and not tracemalloc.is_tracing()
    if started_tracing:
        tracemalloc.start(trace_frames)
    try:
        sample(0)
        for i in range(n):
            if i == warmup and trace:
                gc.collect()
                snap_warm = tracemalloc.take_snapshot()
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                facts = step(i)
            except Exception as exc:  # a soak reports what stopped it
                stopped = f"{type(exc).__name__}: {exc}"
                log.exception("soak stopped at %s %d", unit, i)
                break
            wall_s[i] = time.perf_counter() - t0
            cpu_s[i] = time.process_time() - c0
            done = i + 1
            if facts:
                steps.append({"step": i, **facts})
            if (i + 1) % sample_every == 0 or i + 1 == n:
                sample(i + 1)
                if progress is not None:
                    s = samples[-1]
                    progress(
                        f"[{i + 1}/{n} {unit}s] RSS {s['rss_mib']:.1f} MiB, "
                        f"traced {s['traced_mib']:.1f} MiB, "
                        f"last {unit} {1e3 * wall_s[i]:.0f} ms wall, {s['wall_s']:.0f} s so far"
                        + (f" ({facts['reason']})" if facts and "reason" in facts else "")
                    )
                if on_sample is not None:
                    on_sample(report())
        if trace and snap_warm is not None and done > warmup:
            gc.collect()
            top = _top_growth(snap_warm, tracemalloc.take_snapshot())
    finally:
        if started_tracing:
            tracemalloc.stop()
    return report()


def _report(
    samples, steps, wall_s, cpu_s, n, unit, per, warmup, window, tolerance_mib, trace, top, stopped, meta
) -> dict[str, Any]:
    done = len(wall_s)
    windows = []
    for a in range(0, done, window):
        w, c = np.asarray(wall_s[a : a + window]), np.asarray(cpu_s[a : a + window])
        windows.append(
            {
                "start": a,
                "end": a + len(w),
                "median_wall_ms": 1e3 * float(np.median(w)),
                "mean_wall_ms": 1e3 * float(np.mean(w)),
                "median_cpu_ms": 1e3 * float(np.median(c)),
                "mean_cpu_ms": 1e3 * float(np.mean(c)),
            }
        )
    # the slopes: the samples of the second half of the run, and never before the warm-up's end
    x0 = max(warmup, done // 2)
    fitted = [s for s in samples if s["step"] >= x0]
    memory: dict[str, Any] = {}
    for key in ("rss_mib", "rss_trimmed_mib", "traced_mib"):
        pts = [s for s in fitted if math.isfinite(s.get(key, math.nan))]
        if len(pts) >= 3 and pts[-1]["step"] > pts[0]["step"]:
            fit = fit_slope([s["step"] for s in pts], [s[key] for s in pts], per=per)
            memory[key.removesuffix("_mib")] = memory_verdict(fit, tolerance_mib)
    return {
        "unit": unit,
        "per": per,
        "n_planned": n,
        "n_done": done,
        "stopped": stopped,
        "warmup": warmup,
        "tracemalloc": trace,
        "samples": samples,
        "windows": windows,
        "memory": memory,
        "time": time_verdict(windows, warmup, per=per),
        "top_growth": top,
        "steps": steps,
        "machine": {
            "cpus": os.cpu_count(),
            "loadavg": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
            "python": platform.python_version(),
            "platform": platform.platform(),
        },
        **(meta or {}),
    }


def format_soak(r: dict[str, Any], max_rows: int = 12) -> str:
    """The report as text: memory at checkpoints, time per window, the slopes and verdicts."""
    unit = r["unit"]
    lines = [
        f"{r['n_done']}/{r['n_planned']} {unit}s" + (f" (stopped: {r['stopped']})" if r["stopped"] else "")
    ]
    trimmed = any("rss_trimmed_mib" in s for s in r["samples"])
    head = f"{unit + 's':>10} {'RSS MiB':>9} {'traced MiB':>11} {'elapsed s':>10}"
    lines.append(head + (f" {'trimmed RSS MiB':>16}" if trimmed else ""))
    samples = r["samples"]
    stride = max(1, math.ceil(len(samples) / max_rows))
    shown = samples[::stride] + ([samples[-1]] if (len(samples) - 1) % stride else [])
    for s in shown:
        row = f"{s['step']:>10} {s['rss_mib']:>9.1f} {s['traced_mib']:>11.2f} {s['wall_s']:>10.0f}"
        lines.append(row + (f" {s.get('rss_trimmed_mib', math.nan):>16.1f}" if trimmed else ""))
    lines.append(f"{'window':>13} {'median wall ms':>15} {'median CPU ms':>14} {'mean wall ms':>13}")
    wins = r["windows"]
    stride = max(1, math.ceil(len(wins) / max_rows))
    for w in wins[::stride] + ([wins[-1]] if (len(wins) - 1) % stride else []):
        lines.append(
            f"{w['start']:>6}-{w['end']:<6} {w['median_wall_ms']:>15.1f} {w['median_cpu_ms']:>14.1f} "
            f"{w['mean_wall_ms']:>13.1f}"
        )
    for key, m in r["memory"].items():
        verdict = "flat" if m["flat"] else ("GROWS" if m["slope_mib"] > 0 else "falls")
        lines.append(
            f"{key} slope {m['slope_mib']:+.3f} MiB per {m['per']:g} {unit}s (95 %: {m['lo_mib']:+.3f} .. "
            f"{m['hi_mib']:+.3f}; {m['points']} samples, {unit}s {m['fitted_steps'][0]:.0f}-"
            f"{m['fitted_steps'][1]:.0f}) -> {verdict}"
            f" (zero in interval: {m['zero_in_interval']}; "
            f"within +-{m['tolerance_mib']:g}: {m['within_tolerance']})"
        )
    t = r["time"]
    if t.get("level") is not None:
        lines.append(
            f"time: last window / first after warm-up: CPU x{t['cpu_ratio']:.2f}, "
            f"wall x{t['wall_ratio']:.2f} "
            f"-> {'level' if t['level'] else 'SLOWER'} (limit x{t['max_slowdown']:.2f})"
        )
    if "cpu_slope_ms" in t:
        b, lo, hi = t["cpu_slope_ms"]
        lines.append(
            f"time: windows' median CPU ms per {unit}, slope {b:+.2f} ms per {r['per']:g}"
            f" {unit}s (95 %: {lo:+.2f} .. {hi:+.2f})"
        )
    for g in r["top_growth"][:5]:
        at = g["site"] if g.get("caller", g["site"]) == g["site"] else f"{g['site']} (from {g['caller']})"
        lines.append(f"  traced {g['size_diff_kib']:+.1f} KiB ({g['count_diff']:+d} blocks) at {at}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------------------
# the track soak


def ping_pong(items: Sequence[Any]) -> Iterator[Any]:
    """0, 1, .., k-1, k-2, .., 1, 0, 1, .. forever: a short sequence played back and forth (no jump at the
    seam, as a camera sweeping to and fro)."""
    if not items:
        raise InvalidInputError("ping_pong needs at least one item")
    order = list(range(len(items))) + list(range(len(items) - 2, 0, -1))
    while True:
        for k in order:
            yield items[k]


def soak_track(
    estimator: Any,
    frames: Sequence[Any],
    prompt: str,
    n: int = 10_000,
    *,
    warmup: int = 500,
    sample_every: int = 100,
    window: int = 500,
    tolerance_mib: float = 1.0,
    trace: bool = True,
    trace_frames: int = 1,
    trim: bool = False,
    fps: float = 30.0,
    progress: Callable[[str], object] | None = None,
    on_sample: Callable[[dict[str, Any]], None] | None = None,
    meta: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Track `prompt` over `n` frames: `frames` (a short sequence of `RGBDFrame`) played back and forth, each
    re-stamped at `fps` so time runs on; `estimator.track` runs on every frame. A track that ends in an error
    (the object lost and not found again) is started again and counted (`restarts`).

    Slopes per 1000 frames; `tolerance_mib` per 1000 frames (default 1 MiB: 10 MiB over the 10,000 frames,
    a megabyte every 33 s at 30 frames/s). Each step records the tracker's re-groundings (`reinit`, the
    estimate of a (re)started track) only when they happen."""
    from dataclasses import replace

    source = ping_pong(list(frames))
    clock = iter(range(10**12))

    def stamped() -> Iterator[Any]:
        for f in source:
            yield replace(f, timestamp_s=next(clock) / fps)

    state: dict[str, Any] = {"stream": estimator.track(stamped(), prompt), "restarts": 0}

    def step(i: int) -> dict[str, Any] | None:
        try:
            est = next(state["stream"])
        except PromposeError as exc:
            state["restarts"] += 1
            state["stream"] = estimator.track(stamped(), prompt)
            log.info("track restarted at frame %d: %s", i, exc)
            est = next(state["stream"])
            return {"restart": str(exc)[:200]}
        if est.frame_index == 0 or math.isfinite(est.coverage):  # a grounded (re)start, not a tracked update
            return {"reinit": est.frame_index, "size_m": [round(float(v), 4) for v in est.pose.size]}
        return None

    report = run_soak(
        step,
        n,
        unit="frame",
        per=1000.0,
        warmup=warmup,
        sample_every=sample_every,
        window=window,
        tolerance_mib=tolerance_mib,
        trace=trace,
        trace_frames=trace_frames,
        trim=trim,
        progress=progress,
        on_sample=on_sample,
        meta={"prompt": prompt, "sequence_frames": len(frames), **(meta or {})},
    )
    report["track_restarts"] = state["restarts"]
    return report


def write_json(report: dict[str, Any], path: str | Path) -> None:
    """Write the report (the checks on the path happen before the run, in `check_output_path`)."""
    Path(path).write_text(json.dumps(report, indent=2, default=_jsonable))


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return asdict(o) if hasattr(o, "__dataclass_fields__") else str(o)


def check_output_path(path: str | Path | None) -> None:
    """Refuse an output file whose folder is missing or which is a folder, before hours of work."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir() or not p.parent.is_dir():
        raise InvalidInputError(f"--json {str(p)!r}: not a file in an existing folder")


def add_measurement_arguments(p: argparse.ArgumentParser) -> None:
    """The options every soak command shares: what is measured (`measurement_options`) and where it goes."""
    p.add_argument("--no-tracemalloc", action="store_true", help="RSS only (tracemalloc slows Python code)")
    p.add_argument(
        "--trace-frames", type=int, default=1, help="frames per traced allocation (1; more: a leak hunt)"
    )
    p.add_argument("--trim", action="store_true", help="also the RSS after glibc malloc_trim(0)")
    p.add_argument("--json", dest="json_out", default=None, help="write the report here")


def measurement_options(args: argparse.Namespace) -> dict[str, Any]:
    """`soak_track` / `run_soak` keywords from the options of `add_measurement_arguments`."""
    return {"trace": not args.no_tracemalloc, "trace_frames": args.trace_frames, "trim": args.trim}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m prompose_grasp.eval.soak", description=__doc__.splitlines()[0]
    )
    p.add_argument("--frames", required=True, help="folder of NNNNNN-color.png / NNNNNN-depth.png frames")
    p.add_argument("--prompt", required=True, help='the object to track, e.g. "the blue box"')
    p.add_argument("--intrinsics", nargs=4, type=float, required=True, metavar=("FX", "FY", "CX", "CY"))
    p.add_argument("--depth-scale", type=float, default=0.001, help="metres per depth unit (default 0.001)")
    p.add_argument("--n", type=int, default=10_000, help="frames to track (default 10000)")
    p.add_argument("--warmup", type=int, default=500)
    p.add_argument("--sample-every", type=int, default=100)
    p.add_argument("--window", type=int, default=500)
    add_measurement_arguments(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        from prompose_grasp.perception.estimator import ProMPose
        from prompose_grasp.perception.frames_io import list_sequence, load_rgbd

        check_output_path(args.json_out)
        frames = [
            load_rgbd(c, d, args.depth_scale, tuple(args.intrinsics))
            for _, c, d in list_sequence(args.frames)
        ]
        report = soak_track(
            ProMPose.default(),
            frames,
            args.prompt,
            args.n,
            warmup=args.warmup,
            sample_every=args.sample_every,
            window=args.window,
            **measurement_options(args),
            progress=lambda line: sys.stderr.write(line + "\n"),
            on_sample=(lambda r: write_json(r, args.json_out)) if args.json_out else None,
            meta={"frames_dir": str(args.frames)},
        )
    except PromposeError as exc:
        sys.stderr.write(f"error: {exc}\n")
        return 2
    sys.stdout.write(format_soak(report) + "\n")
    if args.json_out:
        write_json(report, args.json_out)
        sys.stdout.write(f"wrote {args.json_out}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
