"""Benchmark of the embedded grounder: time per 640x480 frame and top-1 mask accuracy on synthetic scenes.

    python -m prompose_grasp.perception.grounding.bench [--data DIR] [--scenes 4] [--frames 2] [--seed 0]
        [--json OUT.json]

Frames come from a synthetic dataset in the DESIGN.md layout (`<scene>/<frame>-color.png`, `-depth.png`,
`-mask.png`, `-meta.json`). Without `--data`, one is generated first by running `python -m sim.dataset` in a
subprocess (the library never imports `sim`). The dataset's scenes are CAMERA25-like: random table textures,
random object colours and textures, 3-6 objects standing close together, a camera orbiting them.

For every object with at least `--min-visible-px` visible pixels, two prompts are grounded:

- "category": the object's prompt from the metadata ("the mug"); when the scene holds several objects with
  that prompt, any of them counts;
- "colour + category": "the <colour> <category>", the colour named by this package's palette from the
  ground-truth pixels of the object (what a person looking at the image would say; benchmark-side only).

A prompt is a hit when the best candidate's mask has IoU >= 0.5 with the (a) ground-truth mask. Timing is
the wall time of `Grounder.ground` (median and 90th percentile over all calls after one warm-up call).

Also reported, per category and for the scenes of the dataset's test split (`split.json`: unseen test
categories with train-category distractors, the estimator benchmark's protocol) next to all scenes:

- recall: some candidate (not only the best) has IoU >= 0.5 with a target: the segmentation's share;
- confusion of category prompts: the category of the object the best mask matches (IoU >= 0.5), "bad
  mask" when it matches none (merged or split objects), "none" without candidates.

Confidence (`confidence_summary`): each frame is also asked for two prompts of objects it does not hold
(the right answer there is "none"). Every call records the candidates' score totals and which of them is
the prompt's object, so that `--fit-confidence R.json` fits the calibration and `--rescore R.json`
recomputes probabilities and contenders under today's one without grounding again; the report gives right
and wrong picks, correct and wrong ambiguity and "none" per prompt kind, and a reliability table
(`--reliability-svg` draws it).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from prompose_grasp.geometry.camera import CameraIntrinsics
from prompose_grasp.perception.grounding.confidence import (
    ConfidenceModel,
    contenders,
    fit_confidence,
    match_probabilities,
)
from prompose_grasp.perception.grounding.describe import dominant_colour
from prompose_grasp.perception.grounding.grounder import Grounder
from prompose_grasp.perception.grounding.language import parse_prompt
from prompose_grasp.perception.grounding.score import total_of_score
from prompose_grasp.perception.grounding.types import GroundingConfig

HIT_IOU = 0.5


def _generate(out: Path, scenes: int, frames: int, seed: int) -> None:
    cmd = [
        sys.executable,
        "-m",
        "sim.dataset",
        "--out",
        str(out),
        "--scenes",
        str(scenes),
        "--frames",
        str(frames),
    ]
    cmd += [
        "--seed",
        str(seed),
        "--width",
        "640",
        "--height",
        "480",
        "--noise",
        "realsense",
        "--workers",
        "1",
    ]
    cmd += ["--no-progress"]
    print("generating frames:", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})


def _test_scenes(data: Path) -> set[str]:
    split = data / "split.json"
    if not split.is_file():
        return set()
    return set(json.loads(split.read_text()).get("test", {}).get("scenes", []))


def _frames(data: Path, images: bool = True):
    for meta_path in sorted(data.glob("*/*-meta.json")):
        stem = str(meta_path)[: -len("-meta.json")]
        meta = json.loads(meta_path.read_text())
        if not images:
            yield meta_path.parent.name, None, None, None, None, meta["objects"]
            continue
        bgr = cv2.imread(f"{stem}-color.png", cv2.IMREAD_COLOR)
        raw = cv2.imread(f"{stem}-depth.png", cv2.IMREAD_UNCHANGED)
        if bgr is None or raw is None:
            raise SystemExit(f"cannot read the colour or depth image of {stem}")
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        depth = raw.astype(np.float32) * float(meta.get("depth_scale_m", 0.001))
        mask = cv2.imread(f"{stem}-mask.png", cv2.IMREAD_UNCHANGED)
        H, W = depth.shape
        yield (
            meta_path.parent.name,
            rgb,
            depth,
            mask,
            CameraIntrinsics.from_K(meta["K"], W, H),
            meta["objects"],
        )


def _torch_threads() -> int | None:
    try:
        import torch
    except ImportError:
        return None
    return int(torch.get_num_threads())


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def _confidence_record(result: Any, targets: list[np.ndarray]) -> dict[str, Any]:
    """What calibration needs of one grounding call: every candidate's score total (`total_of_score`),
    whether it is the prompt's object, the probabilities and contenders."""
    scores = np.clip([c.score for c in result.candidates], 1e-12, 1.0 - 1e-12)
    return {
        "totals": total_of_score(scores).tolist(),
        "right": [any(_iou(c.mask, t) >= HIT_IOU for t in targets) for c in result.candidates],
        "probabilities": [c.probability for c in result.candidates],
        "contenders": result.contenders,
    }


def confidence_summary(records: list[dict[str, Any]], bins: int = 10) -> dict[str, Any]:
    """Reliability of the best candidate's probability and the refusal rates, per prompt kind.

    A present-object prompt ends in one of: a pick (contenders 1), right or wrong (`wrong_pick`); `ambiguous`
    (contenders >= 2), correct when two or more candidates are the prompt's object (a category prompt in a
    scene with two mugs), else wrong; `none` (0), always wrong there. An absent-object prompt is right when
    it ends in `none`. The reliability table uses the prompts with at most one right candidate: with two
    mugs each holds about half the probability, and either is right.
    """
    out: dict[str, Any] = {}
    for kind in sorted({r["kind"] for r in records}):
        rs = [r for r in records if r["kind"] == kind and "totals" in r]
        if not rs:
            continue
        n = len(rs)
        right_first = [bool(r["right"]) and r["right"][0] for r in rs]
        multi = [sum(r["right"]) >= 2 for r in rs]
        k = [r["contenders"] for r in rs]
        row = {
            "n": n,
            "pick_right": sum(c == 1 and ok for c, ok in zip(k, right_first)) / n,
            "wrong_pick": sum(c == 1 and not ok for c, ok in zip(k, right_first)) / n,
            "ambiguous_correct": sum(c >= 2 and m for c, m in zip(k, multi)) / n,
            "ambiguous_wrong": sum(c >= 2 and not m for c, m in zip(k, multi)) / n,
            "none": sum(c == 0 for c in k) / n,
        }
        unique = [i for i, r in enumerate(rs) if sum(r["right"]) <= 1]
        if kind != "absent" and unique:
            p = np.array([rs[i]["probabilities"][0] if rs[i]["probabilities"] else 0.0 for i in unique])
            ok = np.array([right_first[i] for i in unique])
            edges = np.linspace(0.0, 1.0, bins + 1)
            idx = np.clip(np.digitize(p, edges) - 1, 0, bins - 1)
            row["reliability"] = [
                {
                    "bin": [float(edges[b]), float(edges[b + 1])],
                    "n": int(np.sum(idx == b)),
                    "mean_predicted": float(p[idx == b].mean()) if np.any(idx == b) else None,
                    "observed": float(ok[idx == b].mean()) if np.any(idx == b) else None,
                }
                for b in range(bins)
            ]
            row["expected_calibration_error"] = float(
                sum(np.sum(idx == b) * abs(p[idx == b].mean() - ok[idx == b].mean()) for b in range(bins)
                    if np.any(idx == b)) / len(unique)
            )  # fmt: skip
        out[kind] = row
    return out


def rescore(records: list[dict[str, Any]], model: ConfidenceModel | None = None) -> list[dict[str, Any]]:
    """The records with probabilities and contenders recomputed from their totals under `model` (default:
    the grounder's), so that a change of calibration is measured without grounding again."""
    model = model or ConfidenceModel()
    out = []
    for r in records:
        if "totals" not in r:
            out.append(r)
            continue
        p, p_none = match_probabilities(np.asarray(r["totals"], dtype=np.float64), model)
        out.append({**r, "probabilities": p.tolist(), "contenders": contenders(p, p_none, model)})
    return out


def _weighted(rows: list[tuple[str, dict[str, Any]]], b: int, key: str) -> float | None:
    """The count-weighted mean of `key` in bin `b` over several kinds' reliability tables."""
    cells = [c["reliability"][b] for _, c in rows if c["reliability"][b]["n"]]
    n = sum(cell["n"] for cell in cells)
    return sum(cell["n"] * cell[key] for cell in cells) / n if n else None


def _summary(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Hit rate, recall, mean IoU per prompt kind and per category; confusion of the category prompts."""
    out: dict[str, Any] = {}
    for kind in ("category", "colour + category"):
        rs = [r for r in records if r["kind"] == kind]
        if not rs:
            continue
        cats = sorted({r["category"] for r in rs})
        out[kind] = {
            "n": len(rs),
            "top1_iou_ge_0.5": float(np.mean([r["hit"] for r in rs])),
            "recall_iou_ge_0.5": float(np.mean([r["recall"] for r in rs])),
            "mean_top1_iou": float(np.mean([r["iou"] for r in rs])),
            "per_category": {
                c: {
                    "n": sum(r["category"] == c for r in rs),
                    "top1_iou_ge_0.5": float(np.mean([r["hit"] for r in rs if r["category"] == c])),
                    "recall_iou_ge_0.5": float(np.mean([r["recall"] for r in rs if r["category"] == c])),
                }
                for c in cats
            },
        }
        if kind == "category":
            confusion: dict[str, dict[str, int]] = {}
            for r in rs:
                row = confusion.setdefault(r["category"], {})
                row[r["predicted"]] = row.get(r["predicted"], 0) + 1
            out[kind]["confusion"] = confusion
    return out


def run(data: Path, min_visible_px: int, config: GroundingConfig) -> dict[str, Any]:
    grounder = Grounder(config)
    times: list[float] = []
    encode_times: list[float] = []
    warm_up_s = 0.0
    stages: dict[str, list[float]] = {"plane_s": [], "segment_s": [], "describe_s": [], "score_s": []}
    records: list[dict[str, Any]] = []
    test_scenes = _test_scenes(data)
    # prompts of objects that a frame does not hold (the right answer there is "none"), drawn in turn
    absent_prompts = sorted({o["prompt"] for *_, objs in _frames(data, images=False) for o in objs})
    warmed = False
    n_frames = 0
    for scene, rgb, depth, mask, K, objects in _frames(data):
        n_frames += 1
        if not warmed:  # loading MiniLM and embedding the description vocabulary happen once per process
            t0 = time.perf_counter()
            grounder.warm_up()
            warm_up_s = time.perf_counter() - t0
            warmed = True
        gts = {o["id"]: mask == o["id"] for o in objects}
        for obj in objects:
            gt = gts[obj["id"]]
            if gt.sum() < min_visible_px:
                continue
            same = [gts[o["id"]] for o in objects if o["prompt"] == obj["prompt"]]
            colour, _, _ = dominant_colour(rgb[gt])
            for kind, prompt, targets in (
                ("category", f"the {obj['prompt']}", same),
                ("colour + category", f"the {colour} {obj['prompt']}", [gt]),
            ):
                # a prompt seen for the first time costs one MiniLM batch of its phrases (cached afterwards)
                parsed = parse_prompt(prompt)
                t0 = time.perf_counter()
                grounder.text_encoder.encode([t for t in (parsed.text, parsed.noun) if t])
                encode_times.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                result = grounder.ground(rgb, depth, K, prompt)
                times.append(time.perf_counter() - t0)
                for key in stages:
                    stages[key].append(getattr(result.timing, key))
                best = (
                    max((_iou(result.candidates[0].mask, t) for t in targets), default=0.0)
                    if result.candidates
                    else 0.0
                )
                recall = any(_iou(c.mask, t) >= HIT_IOU for c in result.candidates for t in targets)
                predicted = "none"
                if result.candidates:
                    top = result.candidates[0].mask
                    match = max(objects, key=lambda o: _iou(top, gts[o["id"]]))
                    predicted = match["category"] if _iou(top, gts[match["id"]]) >= HIT_IOU else "bad mask"
                records.append(
                    {
                        "scene": scene,
                        "test_split": scene in test_scenes,
                        "category": obj["category"],
                        "kind": kind,
                        "prompt": prompt,
                        "iou": best,
                        "hit": best >= HIT_IOU,
                        "recall": recall,
                        "predicted": predicted,
                        **_confidence_record(result, targets),
                    }
                )
        present = {o["prompt"] for o in objects}
        for prompt in [p for p in absent_prompts if p not in present][:2]:
            result = grounder.ground(rgb, depth, K, f"the {prompt}")
            records.append(
                {
                    "scene": scene,
                    "test_split": scene in test_scenes,
                    "category": prompt,
                    "kind": "absent",
                    "prompt": f"the {prompt}",
                    **_confidence_record(result, []),
                }
            )
            absent_prompts.append(absent_prompts.pop(absent_prompts.index(prompt)))  # rotate through all
    if not times:
        raise SystemExit(f"no frames with objects of >= {min_visible_px} visible pixels under {data}")
    ms = 1e3 * np.asarray(times)
    summary = _summary(records)
    return {
        "frames": n_frames,
        "prompts": len(times),
        "resolution": "640x480",
        "time_ms": {
            "median": float(np.median(ms)),
            "p90": float(np.percentile(ms, 90)),
            "max": float(ms.max()),
        },
        "new_prompt_encode_ms": {
            "median": float(1e3 * np.median(encode_times)),
            "p90": float(1e3 * np.percentile(encode_times, 90)),
        },
        "warm_up_s": warm_up_s,
        "torch_threads": _torch_threads(),
        "stage_median_ms": {k: float(1e3 * np.median(v)) for k, v in stages.items()},
        "top1_iou_ge_0.5": {k: v["top1_iou_ge_0.5"] for k, v in summary.items()},
        "mean_top1_iou": {k: v["mean_top1_iou"] for k, v in summary.items()},
        "per_kind_count": {k: v["n"] for k, v in summary.items()},
        "all_scenes": summary,
        "test_split": _summary([r for r in records if r["test_split"]]),
        "confidence": confidence_summary(records),
        "records": records,
        "machine": {
            "platform": platform.platform(),
            "python": platform.python_version(),
            "cpu_count": os.cpu_count(),
            "affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        },
    }


def _print_summary(title: str, summary: dict[str, Any]) -> None:
    for kind, v in summary.items():
        print(
            f"\n{title}, {kind!r} prompts: top-1 {100 * v['top1_iou_ge_0.5']:.1f} % "
            f"(recall {100 * v['recall_iou_ge_0.5']:.1f} %, mean IoU {v['mean_top1_iou']:.3f}, n={v['n']})"
        )
        for c, pc in v["per_category"].items():
            conf = ""
            if "confusion" in v:
                wrong = {k: n for k, n in v["confusion"][c].items() if k != c}
                conf = ", ".join(f"{k} {n}" for k, n in sorted(wrong.items(), key=lambda x: -x[1]))
            print(
                f"  {c:8} n={pc['n']:3}  top-1 {100 * pc['top1_iou_ge_0.5']:5.1f} %  "
                f"recall {100 * pc['recall_iou_ge_0.5']:5.1f} %  {('-> ' + conf) if conf else ''}"
            )


def fit_confidence_from_records(records: list[dict[str, Any]]) -> ConfidenceModel:
    """The maximum-likelihood `ConfidenceModel` of a benchmark's records (`confidence.fit_confidence`)."""
    prompts = [
        (np.asarray(r["totals"]), np.asarray(r["right"], dtype=bool))
        for r in records
        if r["kind"] != "absent" and r.get("totals")
    ]
    return fit_confidence(prompts)


def reliability_svg(reliability: list[dict[str, Any]], title: str) -> str:
    """A reliability diagram (predicted probability of the best candidate against how often it was right,
    per bin; bar width ~ the bin's count) as a standalone SVG."""
    size, pad = 360, 48
    plot = size - 2 * pad

    def xy(p: float, q: float) -> tuple[float, float]:
        return pad + p * plot, size - pad - q * plot

    n_max = max((b["n"] for b in reliability), default=1) or 1
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{size}" height="{size}" font-family="sans-serif" '
        'font-size="11">',
        f'<rect width="{size}" height="{size}" fill="white"/>',
        f'<text x="{size / 2}" y="20" text-anchor="middle" font-size="13">{title}</text>',
        '<line x1="{}" y1="{}" x2="{}" y2="{}" stroke="#999" stroke-dasharray="4 3"/>'.format(
            *xy(0, 0), *xy(1, 1)
        ),
        f'<rect x="{pad}" y="{pad}" width="{plot}" height="{plot}" fill="none" stroke="black"/>',
    ]
    for b in reliability:
        if not b["n"]:
            continue
        lo, hi = b["bin"]
        x0, y0 = xy(lo, b["observed"])
        w = (hi - lo) * plot * (0.3 + 0.7 * b["n"] / n_max)
        parts.append(
            f'<rect x="{x0 + ((hi - lo) * plot - w) / 2:.1f}" y="{y0:.1f}" width="{w:.1f}" '
            f'height="{size - pad - y0:.1f}" fill="#4a7fc1" fill-opacity="0.75"/>'
        )
        cx, cy = xy(b["mean_predicted"], b["observed"])
        parts.append(f'<circle cx="{cx:.1f}" cy="{cy:.1f}" r="3" fill="#c1414a"/>')
        parts.append(f'<text x="{cx:.1f}" y="{cy - 6:.1f}" text-anchor="middle">{b["n"]}</text>')
    for v in (0.0, 0.5, 1.0):
        x, y = xy(v, 0)
        parts.append(f'<text x="{x}" y="{y + 14}" text-anchor="middle">{v:g}</text>')
        x, y = xy(0, v)
        parts.append(f'<text x="{x - 6}" y="{y + 4}" text-anchor="end">{v:g}</text>')
    parts.append(
        f'<text x="{size / 2}" y="{size - 12}" text-anchor="middle">predicted probability of the best</text>'
    )
    parts.append(
        f'<text x="14" y="{size / 2}" text-anchor="middle" transform="rotate(-90 14 {size / 2})">'
        "observed share right</text>"
    )
    parts.append("</svg>")
    return "\n".join(parts) + "\n"


def _print_confidence(conf: dict[str, Any]) -> None:
    print(
        "\nconfidence (a pick: contenders 1; ambiguous: >= 2, correct when two or more are the object; "
        "none: 0):"
    )
    head = ("kind", "n", "right pick", "wrong pick", "amb. correct", "amb. wrong", "none", "ECE")
    print(f"  {head[0]:18} {head[1]:>5} " + " ".join(f"{h:>12}" for h in head[2:]))
    for kind, c in conf.items():
        ece = c.get("expected_calibration_error")
        cells = [c["pick_right"], c["wrong_pick"], c["ambiguous_correct"], c["ambiguous_wrong"], c["none"]]
        print(
            f"  {kind:18} {c['n']:5d} "
            + " ".join(f"{100 * v:11.1f}%" for v in cells)
            + ("" if ece is None else f" {ece:12.3f}")
        )


def _write_reliability(res: dict[str, Any], path: Path) -> None:
    rows = [(k, c) for k, c in res["confidence"].items() if "reliability" in c]
    merged = [
        {
            "bin": rows[0][1]["reliability"][b]["bin"],
            "n": sum(c["reliability"][b]["n"] for _, c in rows),
            "mean_predicted": _weighted(rows, b, "mean_predicted"),
            "observed": _weighted(rows, b, "observed"),
        }
        for b in range(len(rows[0][1]["reliability"]))
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(reliability_svg(merged, f"grounding confidence, {Path(res['data']).name}"))
    print(f"wrote {path}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=Path, default=None, help="dataset folder (default: generate one)")
    parser.add_argument("--scenes", type=int, default=4, help="scenes to generate without --data")
    parser.add_argument("--frames", type=int, default=2, help="frames per generated scene")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--min-visible-px", type=int, default=1500)
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    parser.add_argument(
        "--fit-confidence",
        type=Path,
        default=None,
        metavar="RESULTS.json",
        help="fit the match-probability calibration to an earlier run's records and print it (no grounding)",
    )
    parser.add_argument(
        "--rescore",
        type=Path,
        default=None,
        metavar="RESULTS.json",
        help="recompute an earlier run's probabilities and contenders under today's calibration "
        "(no grounding)",
    )
    parser.add_argument(
        "--reliability-svg", type=Path, default=None, help="draw the reliability diagram of this run here"
    )
    args = parser.parse_args(argv)
    if args.fit_confidence is not None:
        model = fit_confidence_from_records(json.loads(args.fit_confidence.read_text())["records"])
        print(f"fitted on {args.fit_confidence}: {model}")
        return
    if args.rescore is not None:
        res = json.loads(args.rescore.read_text())
        res["records"] = rescore(res["records"])
        res["confidence"] = confidence_summary(res["records"])
        print(f"{args.rescore} rescored with {ConfidenceModel()}")
        _print_confidence(res["confidence"])
        if args.reliability_svg:
            _write_reliability(res, args.reliability_svg)
        return
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data
        if data is None:
            data = Path(tmp) / "frames"
            _generate(data, args.scenes, args.frames, args.seed)
        res = run(data, args.min_visible_px, GroundingConfig())
    res["data"] = str(args.data) if args.data else f"generated: {args.scenes} scenes x {args.frames} frames"
    res["seed"] = args.seed
    print(f"\ngrounding benchmark: {res['frames']} frames, {res['prompts']} prompts, 640x480")
    print(f"{'metric':34} {'value':>10}")
    t = res["time_ms"]
    print(f"{'time per call, median [ms]':34} {t['median']:10.1f}")
    print(f"{'time per call, p90 [ms]':34} {t['p90']:10.1f}")
    e = res["new_prompt_encode_ms"]
    print(f"{'+ new prompt MiniLM, median [ms]':34} {e['median']:10.1f}")
    print(f"{'+ new prompt MiniLM, p90 [ms]':34} {e['p90']:10.1f}")
    print(f"{'one-off warm-up (load + vocab) [s]':34} {res['warm_up_s']:10.2f}")
    for k, v in res["stage_median_ms"].items():
        print(f"{'  stage ' + k[:-2] + ' median [ms]':34} {v:10.1f}")
    for k in res["top1_iou_ge_0.5"]:
        n = res["per_kind_count"][k]
        print(f"{'top-1 IoU>=0.5, ' + k:34} {100 * res['top1_iou_ge_0.5'][k]:9.1f}% (n={n})")
        print(f"{'mean top-1 IoU, ' + k:34} {res['mean_top1_iou'][k]:10.3f}")
    _print_summary("all scenes", res["all_scenes"])
    if res["test_split"]:
        _print_summary("test split (unseen categories + distractors)", res["test_split"])
    _print_confidence(res["confidence"])
    if args.reliability_svg:
        _write_reliability(res, args.reliability_svg)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res, indent=2))
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
