"""The perception commands: `estimate` (one frame; or through a `serve` process with `--server`), `track`
(a recorded sequence), `bench` (the estimator benchmark) and `eval-nocs` (NOCS metrics of result files)."""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from prompose_grasp.cli.arguments import (
    IMAGE_SUFFIXES,
    add_rerun,
    check_at_least,
    check_output_file,
    close_recorder,
    open_recorder,
    rerun_target,
    write_text,
)
from prompose_grasp.errors import InvalidInputError

if TYPE_CHECKING:  # the estimator loads torch: imported where a command needs it, so --help stays fast
    from prompose_grasp.perception.estimator import Estimate


def add_frame_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--depth-scale", type=float, default=0.001, help="metres per depth unit (default 0.001)")
    p.add_argument(
        "--intrinsics", type=float, nargs=4, required=True, metavar=("FX", "FY", "CX", "CY"), help="pixels"
    )
    p.add_argument("--prompt", required=True, help='the object, e.g. "mustard bottle"')
    p.add_argument("--json", dest="json_out", default=None, help="write the result here (default: stdout)")
    add_rerun(p)


def add_estimate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "estimate",
        help="9-DoF pose of the object named by a prompt in one RGB-D frame",
        description="Ground the prompt, generate the shape prior and fit the metric 9-DoF box in one frame. "
        "Prints (or writes) JSON: {prompt, objects: [{R, t, size, score, mask_pixels, prior}], timing_ms}, "
        "objects best first; an empty list when nothing matches.",
    )
    p.add_argument("--rgb", required=True, help="colour image (PNG/JPEG)")
    p.add_argument("--depth", required=True, help="registered depth, 16-bit PNG")
    add_frame_args(p)
    p.add_argument("--max-objects", type=int, default=3, help="candidates to report (default 3)")
    p.add_argument("--overlay", default=None, help="also draw the estimated box and mask into this PNG")
    p.add_argument(
        "--server",
        default=None,
        metavar="URL",
        help="ask a running `prompose-grasp serve` (e.g. http://127.0.0.1:8765) instead of loading the "
        "estimator here",
    )
    p.add_argument("--token", default=None, help="the server's bearer token (default: $PROMPOSE_GRASP_TOKEN)")
    p.set_defaults(func=_run_estimate)


def add_track(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "track",
        help="9-DoF poses over a recorded RGB-D sequence (one JSON line a frame)",
        description="Track the object named by a prompt through a folder of NNNNNN-color.png / "
        "NNNNNN-depth.png frames; writes one JSON line a frame: "
        "{frame, R, t, size, score, mask_pixels, prior}.",
    )
    p.add_argument("--sequence", required=True, help="folder of NNNNNN-color.png / NNNNNN-depth.png")
    add_frame_args(p)
    p.set_defaults(func=_run_track)


#: The per-stage timings of the estimate JSON contract (DESIGN.md).
_STAGES = ("grounding", "prior", "pose", "total")


def _run_estimate(args: argparse.Namespace) -> int:
    check_at_least(args.max_objects, "--max-objects", 1)
    check_output_file(args.json_out, "--json")
    check_output_file(args.overlay, "--overlay", IMAGE_SUFFIXES)
    target = rerun_target(args)
    if args.server is not None:
        if target is not None:
            raise InvalidInputError("--rerun records the estimator run here; it cannot record --server")
        return _estimate_via_server(args)
    import json

    import cv2

    from prompose_grasp.perception.estimator import ProMPose
    from prompose_grasp.perception.frames_io import load_rgbd
    from prompose_grasp.perception.grounding.language import check_prompt
    from prompose_grasp.perception.overlay import draw_poses

    check_prompt(args.prompt, "--prompt")
    frame = load_rgbd(args.rgb, args.depth, args.depth_scale, tuple(args.intrinsics))
    recorder = open_recorder(target)
    try:
        estimator = ProMPose.default(recorder=recorder)
        estimates = estimator.estimate_all(frame, args.prompt, max_objects=args.max_objects)
    finally:
        close_recorder(recorder, target)
    timing = dict(estimates[0].timings_ms) if estimates else {}
    result = {
        "prompt": args.prompt,
        # 1: the first object is the one named; >= 2: that many fit the words about equally; 0: none does
        "contenders": int(estimates[0].contenders) if estimates else 0,
        "objects": [e.to_dict() for e in estimates],
        "timing_ms": {
            k: round(float(timing.get(k, 0.0)), 3) for k in ("grounding", "prior", "pose", "total")
        },
    }
    write_text(args.json_out, json.dumps(result, indent=2))
    if args.overlay:
        best = estimates[:1]
        image = draw_poses(
            frame.rgb,
            frame.intrinsics,
            [e.pose for e in best],
            labels=[overlay_label(args.prompt, e) for e in best],
            masks=[e.mask for e in best],
        )
        if not cv2.imwrite(args.overlay, image[..., ::-1]):
            raise InvalidInputError(f"--overlay {args.overlay}: the image could not be written")
        print(f"wrote {args.overlay}", file=sys.stderr)
    if estimates and estimates[0].contenders >= 2:
        n = estimates[0].contenders
        print(
            f"{n} objects fit {args.prompt!r} about equally (the first {min(n, len(estimates))} in the "
            "JSON); name the one you mean more narrowly",
            file=sys.stderr,
        )
    elif estimates and estimates[0].contenders == 0:
        print(
            f"nothing in the frame clearly fits {args.prompt!r}; the objects listed are guesses",
            file=sys.stderr,
        )
    return 0


def _run_track(args: argparse.Namespace) -> int:
    check_output_file(args.json_out, "--json")
    target = rerun_target(args)
    import itertools
    import json

    from prompose_grasp.perception.estimator import ProMPose
    from prompose_grasp.perception.frames_io import list_sequence, load_rgbd
    from prompose_grasp.perception.grounding.language import check_prompt

    check_prompt(args.prompt, "--prompt")
    frames = list_sequence(args.sequence)

    def load(k: int, rgb: Path, depth: Path):
        return load_rgbd(rgb, depth, args.depth_scale, tuple(args.intrinsics), timestamp_s=float(k))

    first = load(*frames[0])  # the intrinsics, the depth scale and the images are checked before any work
    recorder = open_recorder(target)
    estimator = ProMPose.default(recorder=recorder)
    stream = itertools.chain([first], (load(*f) for f in frames[1:]))
    out = sys.stdout if args.json_out is None else open(args.json_out, "w")
    try:
        for (index, _, _), est in zip(frames, estimator.track(stream, args.prompt)):
            out.write(json.dumps({"frame": index, **est.to_dict()}) + "\n")
            out.flush()
    finally:
        if out is not sys.stdout:
            out.close()
        close_recorder(recorder, target)
    return 0


def _estimate_via_server(args: argparse.Namespace) -> int:
    """`estimate --server URL`: the same checks, JSON and messages, with the estimator in the service."""
    import json

    from prompose_grasp.perception.grounding.language import check_prompt
    from prompose_grasp.service.client import PerceptionClient

    if args.overlay:
        raise InvalidInputError(
            "--overlay draws the mask, which stays in the server; drop --overlay or --server"
        )
    check_prompt(args.prompt, "--prompt")
    client = PerceptionClient(args.server, token=args.token or os.environ.get("PROMPOSE_GRASP_TOKEN"))
    doc = client.estimate_files(
        args.rgb, args.depth, tuple(args.intrinsics), args.prompt, args.depth_scale, args.max_objects
    )
    write_text(args.json_out, json.dumps(doc, indent=2))
    n, shown = doc["contenders"], len(doc["objects"])
    if shown and n >= 2:
        print(
            f"{n} objects fit {args.prompt!r} about equally (the first {min(n, shown)} in the JSON); name "
            "the one you mean more narrowly",
            file=sys.stderr,
        )
    elif shown and n == 0:
        print(
            f"nothing in the frame clearly fits {args.prompt!r}; the objects listed are guesses",
            file=sys.stderr,
        )
    return 0


def overlay_label(prompt: str, est: Estimate) -> str:
    """`prompt (prior, NN% seen)`: the share of the box's facing surface the mask shows (`Estimate.coverage`)
    tells a person looking at the overlay how much of the box rests on the prior alone."""
    seen = f", {est.coverage:.0%} seen" if math.isfinite(est.coverage) else ""
    return f"{prompt} ({est.prior.name}{seen})"


def add_bench(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench",
        help="accuracy and speed of the estimator on a synthetic dataset split, against the OBB baseline",
        description="NOCS tables (three IoU modes) of the estimator with an oracle mask and with its own "
        "grounding, the oriented-bounding-box baseline on the same masks, tracking speed and first-frame "
        "latency, all from one run over a dataset written by `python -m sim.dataset`.",
    )
    p.add_argument("--data", required=True, help="dataset folder (with split.json)")
    p.add_argument("--split", default="test", help="split to evaluate (default: test, the unseen categories)")
    p.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    p.add_argument("--candidates", type=int, default=3, help="grounded candidates per category and frame")
    p.add_argument(
        "--methods",
        default=None,
        help="comma-separated rows to run (default: all): ours_oracle_mask, obb_oracle_mask, ours, obb, "
        "ours_tracked, ours_tracked_oracle_mask; the others are left out of the report",
    )
    p.add_argument("--json", dest="json_out", default=None, help="also write the full report here")
    p.add_argument(
        "--ray",
        default=None,
        metavar="ADDRESS",
        help="run each scene as a Ray task: local:N (a local cluster of N CPUs), auto (the cluster of "
        "`ray start`), or HOST:PORT (extra `cluster`; docs/scale.md)",
    )
    p.add_argument(
        "--resume", action="store_true", help="skip the scenes JSON.sweep.jsonl lists as done (needs --json)"
    )
    p.set_defaults(func=_run_bench)


def _run_bench(args: argparse.Namespace) -> int:
    from prompose_grasp.eval.bench_estimator import format_report, parse_methods, run_estimator_benchmark
    from prompose_grasp.eval.report import write_report_json

    check_output_file(args.json_out, "--json")
    check_at_least(args.max_frames, "--max-frames", 1)
    check_at_least(args.candidates, "--candidates", 1)
    methods = parse_methods(args.methods)  # a bad name fails before the estimator loads
    if args.resume and not args.json_out:
        raise InvalidInputError("--resume needs --json OUT: the finished scenes are kept in OUT.sweep.jsonl")
    if args.ray is not None:
        from prompose_grasp.eval.sweep import parse_ray_address

        parse_ray_address(args.ray)
    resume_file = None
    if args.json_out and (args.ray or args.resume):
        out = Path(args.json_out)
        resume_file = out.with_name(out.stem + ".sweep.jsonl")
    report = run_estimator_benchmark(
        args.data, args.split, args.max_frames, args.candidates, methods=methods,
        ray=args.ray, resume=args.resume, resume_file=resume_file,
    )  # fmt: skip
    for row in report.get("failed_scenes", []):
        print(
            f"FAILED scene {row['unit']}: {row['error']} after {row['attempts']} attempts: {row['message']}"
        )
    print(format_report(report))
    if args.json_out:
        write_report_json(report, args.json_out)
        print(f"wrote {args.json_out}")
    return 0


def add_eval_nocs(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval-nocs",
        help="NOCS mAP table from per-image result pickles (NOCS / SPD format)",
        description="Compute the NOCS mAP table (3D IoU and n-degree m-cm) from the per-image result dicts "
        "written by the public NOCS / SPD evaluation code.",
    )
    p.add_argument("results", nargs="+", help="result .pkl files, or folders searched for *.pkl")
    p.add_argument("--iou-mode", default="nocs", help="nocs | aligned | exact (see docs/metrics.md)")
    p.add_argument("--synsets", nargs="+", default=None, help="class names, index 0 being background")
    p.add_argument("--json", dest="json_out", default=None, help="also write the table as JSON here")
    p.set_defaults(func=_run_eval_nocs)


def _run_eval_nocs(args: argparse.Namespace) -> int:
    import json

    from prompose_grasp.eval import compute_nocs_map, format_nocs_table, load_nocs_results

    check_output_file(args.json_out, "--json")
    results = load_nocs_results(args.results)
    kwargs = {} if args.synsets is None else {"synset_names": args.synsets}
    table = compute_nocs_map(results, iou_mode=args.iou_mode, **kwargs)
    print(format_nocs_table(table, title=f"NOCS mAP ({len(results)} images, iou_mode={args.iou_mode})"))
    if args.json_out:
        with open(args.json_out, "w") as f:
            json.dump(table, f, indent=2)
        print(f"wrote {args.json_out}")
    return 0
