"""Benchmark of the ProM-Pose estimator on a synthetic dataset split, against the OBB baseline, same run.

    prompose-grasp bench --data DIR [--split test] [--max-frames N] [--methods A,B] [--json OUT]

Per frame of the split (a dataset written by `python -m sim.dataset`; test categories are unseen in training):

- `ours_oracle_mask`: `ProMPose.estimate(frame, prompt, mask=<ground-truth mask>)` per object. The *oracle*
  mask isolates the pose fit from grounding. The prior is generated on the object's first frame and reused.
  Ranked for the AP by the fit's `Estimate.coverage`.
- `obb_oracle_mask`: the baseline (`eval.baselines.obb_baseline`) on the same points and support plane.
- `ours`: `ProMPose.estimate_all(frame, category)` with our grounding: up to `--candidates` objects per
  category present in the frame, ranked by grounding score times coverage (false positives count, as in
  detection benchmarks).
- `obb`: the baseline on our grounding's masks.
- `ours_tracked`: `ProMPose.track` over each scene's frames for every object prompt of the scene; the
  camera pose `T_base_cam` is known (the world plays the robot base, as for a wrist camera with forward
  kinematics). Gives the tracking speed (frames after the first) and first-frame latency.
- `ours_tracked_oracle_mask`: `ProMPose.track(..., mask=<ground-truth mask of the first frame>)` for every
  test-category object of the scene's first frame: the tracker alone (later frames use no ground truth;
  a lost track is grounded again), to compare with `ours_oracle_mask` frame by frame.

The tracked rows are ranked for the AP as their track's first frame (the frame that restarted it, after a
loss): its grounding score times coverage, kept through the tracked updates, which have neither.

`--methods` (`methods=`) runs only the named rows (default: all); the rows not run are absent from the report
(e.g. the tracked rows alone on a long video-rate split, where the single-frame rows would cost most).

A frame's ground truth follows the standard CAMERA25 / REAL275 test protocol (`eval.synthetic.
evaluated_objects`): the test-category objects with at least 64 depth pixels in view. A hidden object is not
counted as missed, and no row is prompted for a category with none in view.

Every method is scored by `compute_nocs_map` in the three IoU modes (`exact` is the headline, see
docs/metrics.md). Only this script reads ground truth.
"""

from __future__ import annotations

import logging
import platform
import sys
import time
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError, PromposeError, UnknownNameError
from prompose_grasp.eval.baselines import obb_baseline
from prompose_grasp.eval.nocs import IOU_MODES
from prompose_grasp.eval.report import format_nocs_table
from prompose_grasp.eval.synthetic import evaluated_objects, nocs_image_result, nocs_tables
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.pointcloud import back_project
from prompose_grasp.perception.dataset import GroundTruthObject, SyntheticFrame, read_split, scene_frames
from prompose_grasp.perception.estimator import Estimate, ProMPose
from prompose_grasp.perception.priors import ShapePrior

__all__ = ["METHODS", "parse_methods", "run_estimator_benchmark"]

log = logging.getLogger(__name__)

METHODS = ("ours_oracle_mask", "obb_oracle_mask", "ours", "obb", "ours_tracked", "ours_tracked_oracle_mask")

#: Rows computed together: the oracle-mask OBB baseline uses the oracle-mask estimate's support plane, the
#: grounded OBB baseline the grounded estimate's masks.
_ORACLE_ROWS = frozenset({"ours_oracle_mask", "obb_oracle_mask"})
_GROUNDED_ROWS = frozenset({"ours", "obb"})


def _percentiles_ms(samples_s: list[float]) -> dict[str, float]:
    if not samples_s:
        return {"n": 0}
    a = 1e3 * np.asarray(samples_s)
    return {"n": len(a), "median_ms": float(np.median(a)), "p90_ms": float(np.percentile(a, 90)),
            "mean_ms": float(np.mean(a))}  # fmt: skip


def _per_second(samples_s: list[float], stat) -> float:
    """1 / `stat` of durations [s] (a rate per second), NaN without samples."""
    return float(1.0 / stat(samples_s)) if samples_s else float("nan")


def parse_methods(methods: str | Sequence[str] | None) -> tuple[str, ...]:
    """The benchmark rows to run, in `METHODS` order: None (or an empty string) is all of them; a string is a
    comma-separated list. Unknown names raise `UnknownNameError` listing the valid ones."""
    if methods is None:
        return METHODS
    names = [m.strip() for m in methods.split(",")] if isinstance(methods, str) else list(methods)
    names = [m for m in names if m]
    if not names:
        if isinstance(methods, str):
            return METHODS
        raise InvalidInputError(f"methods is empty; choose from {', '.join(METHODS)}")
    for m in names:
        if m not in METHODS:
            raise UnknownNameError("benchmark method", m, METHODS)
    return tuple(m for m in METHODS if m in names)


def run_estimator_benchmark(
    data: str | Path,
    split: str = "test",
    max_frames: int | None = None,
    candidates: int = 3,
    estimator: ProMPose | None = None,
    progress: bool = True,
    methods: str | Sequence[str] | None = None,
    *,
    ray: str | None = None,
    resume: bool = False,
    retries: int = 2,
    executor: Any = None,
    resume_file: str | Path | None = None,
) -> dict[str, Any]:
    """Run the methods (`parse_methods`; default every one) over the split; returns the report dict (tables
    per method run and IoU mode, timings).

    `ray` (a `--ray` value), `executor` (a `prompose_grasp.eval.sweep` executor) or `resume` run each scene
    (its frames, in order: the tracked rows need them in one process) as a sweep unit of one CPU, with
    `resume_file` (JSONL) keeping the finished scenes; the tables equal this process's loop's."""
    wanted = parse_methods(methods)
    data = Path(data)
    doc = read_split(data)
    if split not in doc:
        raise KeyError(f"split {split!r} not in {data / 'split.json'} (has {sorted(doc)})")
    categories = sorted(doc[split]["categories"])
    synsets = ["BG", *categories]
    scenes = list(doc[split]["scenes"])
    budgets = _frame_budgets(data, scenes, max_frames)
    per_image: dict[str, list[dict[str, Any]]] = {m: [] for m in wanted}
    times: dict[str, list[float]] = defaultdict(list)
    symmetry: dict[str, str] = {}
    frames_done = 0
    failed: list[dict[str, Any]] = []
    specs = [_SceneSpec(str(data), scene, n, tuple(categories), candidates, wanted) for scene, n in budgets]
    if ray is not None or executor is not None or resume:
        scene_results = _sweep_scenes(specs, ray, resume, retries, executor, resume_file, progress, failed)
    else:
        estimator = estimator or ProMPose.default()
        scene_results = _sequential_scenes(estimator, specs, progress)
    for result in scene_results:
        for m in wanted:
            per_image[m].extend(result["per_image"][m])
        for k, v in result["times"].items():
            times[k].extend(v)
        symmetry.update(result["symmetry"])
        frames_done += int(result["frames"])
    ysym = tuple(c for c, s in symmetry.items() if s == "y_continuous")
    tables = nocs_tables(per_image, synsets, ysym)
    track_s = times.get("track_update", [])
    oracle_s = times.get("track_oracle_update", [])
    return {
        "data": str(data),
        "split": split,
        "frames": frames_done,
        "categories": categories,
        "methods": list(wanted),
        "y_symmetric_classes": list(ysym),
        "tables": tables,
        "timing": {k: _percentiles_ms(v) for k, v in times.items()},
        "tracking_fps": _per_second(track_s, np.mean),
        # the typical frame (the mean holds the re-fits and re-groundings; docs/fit.md, temporal refinement)
        "tracking_fps_median": _per_second(track_s, np.median),
        # the same for the tracker alone (`ours_tracked_oracle_mask`: no re-grounding on frame 0)
        "tracking_oracle_mask_fps": _per_second(oracle_s, np.mean),
        "tracking_oracle_mask_fps_median": _per_second(oracle_s, np.median),
        "machine": {"platform": platform.platform(), "python": sys.version.split()[0]},
        "failed_scenes": failed,
    }


@dataclass(frozen=True)
class _SceneSpec:
    """One scene's share of the benchmark (a sweep unit): its first `frames` frames."""

    data: str
    scene: str
    frames: int
    categories: tuple[str, ...]
    candidates: int
    wanted: tuple[str, ...]


def _frame_budgets(data: Path, scenes: Sequence[str], max_frames: int | None) -> list[tuple[str, int]]:
    """(scene, frames to run) in split order, the scenes after `max_frames` frames left out."""
    out: list[tuple[str, int]] = []
    left = max_frames
    for scene in scenes:
        n = len(list((data / scene).glob("*-meta.json")))
        if left is not None:
            n = min(n, left)
            if n <= 0:
                break
            left -= n
        out.append((scene, n))
    return out


def _scene_result(estimator: ProMPose, spec: _SceneSpec) -> dict[str, Any]:
    """The per-image results (NOCS dicts per method), timings and symmetries of one scene's frames."""
    frames = list(scene_frames(spec.data, spec.scene, max_frames=spec.frames))
    categories, wanted = list(spec.categories), spec.wanted
    synsets = ["BG", *categories]
    times: dict[str, list[float]] = defaultdict(list)
    symmetry: dict[str, str] = {}
    per_image: dict[str, list[dict[str, Any]]] = {m: [] for m in wanted}
    preds_tracked: dict[str, list[list[tuple[int, Pose9D, float]]]] = {}
    if "ours_tracked" in wanted:
        preds_tracked["ours_tracked"] = _track_scene(estimator, frames, categories, times)
    if "ours_tracked_oracle_mask" in wanted:
        preds_tracked["ours_tracked_oracle_mask"] = _track_scene_oracle_mask(
            estimator, frames, categories, times
        )
    priors: dict[int, ShapePrior] = {}
    for k, sf in enumerate(frames):
        evaluated = evaluated_objects(sf, categories)
        gts = [(synsets.index(o.category), o.pose, o.handle_visible) for o in evaluated]
        for o in sf.ground_truth_objects:
            symmetry[o.category] = o.symmetry
        preds = _frame_predictions(estimator, sf, evaluated, synsets, spec.candidates, priors, times, wanted)
        for m, per_frame in preds_tracked.items():
            preds[m] = per_frame[k]
        for m in wanted:
            per_image[m].append(nocs_image_result(gts, preds[m]))
    return {"per_image": per_image, "times": dict(times), "symmetry": symmetry, "frames": len(frames)}


def _sequential_scenes(estimator: ProMPose, specs: Sequence[_SceneSpec], progress: bool):
    t_start = time.perf_counter()
    done = 0
    for i, spec in enumerate(specs):
        result = _scene_result(estimator, spec)
        done += result["frames"]
        if progress:
            log.warning("bench: scene %d/%d (%s), %d frames, %.0f s", i + 1, len(specs), spec.scene, done,
                        time.perf_counter() - t_start)  # fmt: skip
        yield result


#: This process's estimator for the sweep's scene units, built on the first and reused.
_ESTIMATOR: list[ProMPose] = []


def scene_unit(spec: _SceneSpec) -> dict[str, Any]:
    """One scene as a sweep unit: `_scene_result` with the NOCS arrays as JSON ({dtype, shape, data})."""
    if not _ESTIMATOR:
        _ESTIMATOR.append(ProMPose.default())
    result = _scene_result(_ESTIMATOR[0], spec)
    result["per_image"] = {
        m: [{k: _encode(v) for k, v in image.items()} for image in images]
        for m, images in result["per_image"].items()
    }
    return result


def _encode(a: np.ndarray) -> dict[str, Any]:
    # float64 and int64 survive JSON exactly (repr round trip), so the tables do not change
    return {"dtype": str(a.dtype), "shape": list(a.shape), "data": a.ravel().tolist()}


def _decode(d: dict[str, Any]) -> np.ndarray:
    return np.asarray(d["data"], dtype=d["dtype"]).reshape(d["shape"])


def _sweep_scenes(specs, ray, resume, retries, executor, resume_file, progress, failed):
    from prompose_grasp.eval.sweep import Unit, make_executor, run_sweep

    if resume and resume_file is None:
        raise InvalidInputError("resume needs a resume file (prompose-grasp bench: --json OUT)")
    sweep = run_sweep(
        scene_unit,
        [Unit(spec.scene, spec) for spec in specs],
        executor=executor or make_executor(ray),
        num_cpus=1,
        retries=retries,
        resume_file=resume_file,
        resume=resume,
        progress=progress,
        label="scenes",
    )
    failed.extend(f.as_row() for f in sweep.failures.values())
    for result in sweep.results.values():
        result["per_image"] = {
            m: [{k: _decode(v) for k, v in image.items()} for image in images]
            for m, images in result["per_image"].items()
        }
        yield result


def _confidence(grounding_score: float, coverage: float) -> float:
    """A prediction's detection score for the AP: the grounding score (1 for an oracle mask) times the fit's
    coverage (`Estimate.coverage`), as detection scores times pose quality rank 6D pose predictions. The
    baselines keep the grounding score alone: the coverage belongs to our fit."""
    return grounding_score * (coverage if np.isfinite(coverage) else 1.0)


def _track_confidence(est: Estimate, previous: float) -> float:
    """A tracked prediction's detection score: `_confidence` of the frame that (re)started the track, kept
    through the tracked updates after it (they have no grounding score nor coverage of their own)."""
    if np.isfinite(est.score) and np.isfinite(est.coverage):
        return _confidence(est.score, est.coverage)
    return previous


def _frame_predictions(
    estimator: ProMPose,
    sf: SyntheticFrame,
    evaluated: list[GroundTruthObject],
    synsets: list[str],
    candidates: int,
    priors: dict[int, ShapePrior],
    times: dict[str, list[float]],
    wanted: tuple[str, ...] = METHODS,
) -> dict[str, list[tuple[int, Pose9D, float]]]:
    """The single-frame rows of `wanted` (an oracle-mask or grounded pair is computed together) for the
    frame's ground truth `evaluated` (`evaluated_objects`)."""
    preds: dict[str, list[tuple[int, Pose9D, float]]] = defaultdict(list)
    frame = sf.frame
    oracle = not _ORACLE_ROWS.isdisjoint(wanted)
    for obj in evaluated if oracle else ():
        cls = synsets.index(obj.category)
        oracle_mask = sf.ground_truth_instance_mask == obj.instance_id
        points = back_project(frame.depth_m, frame.intrinsics, mask=oracle_mask)
        t0 = time.perf_counter()
        est = estimator.estimate(frame, obj.prompt, prior=priors.get(obj.instance_id), mask=oracle_mask)
        times["oracle_mask_estimate"].append(time.perf_counter() - t0)
        priors[obj.instance_id] = est.prior
        preds["ours_oracle_mask"].append((cls, est.pose, _confidence(1.0, est.coverage)))
        t0 = time.perf_counter()
        preds["obb_oracle_mask"].append((cls, obb_baseline(points, est.support_plane), 1.0))
        times["obb"].append(time.perf_counter() - t0)
    present = sorted({o.category for o in evaluated})
    for category in present if not _GROUNDED_ROWS.isdisjoint(wanted) else ():
        cls = synsets.index(category)
        t0 = time.perf_counter()
        estimates = estimator.estimate_all(frame, category, max_objects=candidates)
        times["grounded_estimate_all"].append(time.perf_counter() - t0)
        for est in estimates:
            preds["ours"].append((cls, est.pose, _confidence(est.score, est.coverage)))
            points = back_project(frame.depth_m, frame.intrinsics, mask=est.mask)
            preds["obb"].append((cls, obb_baseline(points, est.support_plane), est.score))
    return preds


def _track_scene(
    estimator: ProMPose, frames: list[SyntheticFrame], categories: list[str], times: dict[str, list[float]]
) -> list[list[tuple[int, Pose9D, float]]]:
    """Track each distinct prompt of the scene's ground truth (in any frame) through its frames; predictions
    per frame."""
    synsets = ["BG", *categories]
    in_view = {o.prompt: o.category for sf in frames for o in evaluated_objects(sf, categories)}
    prompts = sorted(in_view.items())
    per_frame: list[list[tuple[int, Pose9D, float]]] = [[] for _ in frames]
    for prompt, category in prompts:
        stream = estimator.track((sf.frame for sf in frames), prompt)
        confidence = 1.0
        for k in range(len(frames)):
            t0 = time.perf_counter()
            try:
                est = next(stream)
            except (
                PromposeError
            ) as exc:  # a lost, unrecoverable track ends this prompt's sequence, not the run
                log.info("tracking %r stopped at frame %d: %s", prompt, k, exc)
                break
            times["track_first_frame" if k == 0 else "track_update"].append(time.perf_counter() - t0)
            confidence = _track_confidence(est, confidence)
            per_frame[k].append((synsets.index(category), est.pose, confidence))
    return per_frame


def _track_scene_oracle_mask(
    estimator: ProMPose, frames: list[SyntheticFrame], categories: list[str], times: dict[str, list[float]]
) -> list[list[tuple[int, Pose9D, float]]]:
    """Track every ground-truth object of the first frame from its ground-truth mask (first frame only)."""
    synsets = ["BG", *categories]
    per_frame: list[list[tuple[int, Pose9D, float]]] = [[] for _ in frames]
    first = frames[0]
    for obj in evaluated_objects(first, categories):
        oracle_mask = first.ground_truth_instance_mask == obj.instance_id
        stream = estimator.track((sf.frame for sf in frames), obj.prompt, mask=oracle_mask)
        confidence = 1.0
        for k in range(len(frames)):
            t0 = time.perf_counter()
            try:
                est = next(stream)
            except PromposeError as exc:  # a lost, unrecoverable track ends this object's sequence
                log.info("tracking %r stopped at frame %d: %s", obj.prompt, k, exc)
                break
            times["track_oracle_update" if k else "track_oracle_first_frame"].append(time.perf_counter() - t0)
            confidence = _track_confidence(est, confidence)
            per_frame[k].append((synsets.index(obj.category), est.pose, confidence))
    return per_frame


def format_report(report: dict[str, Any]) -> str:
    """The report as text: one NOCS table per IoU mode with every method run, then timings."""
    cats = ", ".join(report["categories"])
    lines = [f"{report['frames']} frames of {report['data']} ({report['split']}: {cats})"]
    for mode in IOU_MODES:
        for m in (m for m in METHODS if m in report["tables"]):
            lines.append(format_nocs_table(report["tables"][m][mode], title=f"{m}  [iou_mode={mode}]"))
    lines.append("timing per call (median / p90 ms):")
    for k, v in report["timing"].items():
        if v.get("n"):
            lines.append(f"  {k:<24} {v['median_ms']:8.1f} / {v['p90_ms']:8.1f}   (n={v['n']})")
    speeds = (("tracking_fps", "tracking"), ("tracking_oracle_mask_fps", "tracking from the oracle mask"))
    for key, what in speeds:
        if np.isfinite(report.get(key, float("nan"))):
            lines.append(
                f"{what}: {report[key]:.1f} frames/s per object (mean over updates), "
                f"{report.get(key + '_median', float('nan')):.1f} (median update)"
            )
    return "\n".join(lines)
