"""The `prompose-grasp` command. Argument parsing lives here and nowhere else in the library.

Exit status, every command:

- 0: done (`run`: the command succeeded).
- 1: `run` (and `demo`) ended in a typed outcome that is neither a success nor a device fault (nothing
  matched, no feasible grasp, slipped, ambiguous, ...); the outcome's reason and message are printed.
- 2: bad input: a missing or malformed file or flag, refused before any work; one line on stderr.
- 3: a device fault: the arm, the gripper or a link failed (a protective or emergency stop, a lost
  connection, a refused or unfinished move, a gripper fault), as the outcome of `run` / `demo`
  (`pipeline.outcome.DEVICE_FAULT_REASONS`, after the loop's stop path) or raised while connecting (one line
  on stderr). A person should look at the cell.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import prompose_grasp
from prompose_grasp.errors import DeviceFault, InvalidInputError, PromposeError

if TYPE_CHECKING:  # the estimator loads torch: imported where a command needs it, so --help stays fast
    from prompose_grasp.perception.estimator import Estimate
    from prompose_grasp.viz.rerun_recorder import RerunRecorder
    from prompose_grasp.viz.target import RerunTarget


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="prompose-grasp",
        description="Language-commanded pick-and-place from RGB-D frames (ProM-Pose perception, "
        "python-fcl grasping, Pinocchio/mink IK, MuJoCo and UR execution).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {prompose_grasp.__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-v, -vv)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_demo(sub)
    _add_estimate(sub)
    _add_track(sub)
    _add_eval_nocs(sub)
    _add_bench(sub)
    _add_run(sub)
    _add_bench_pick(sub)
    _add_serve(sub)
    # `train` parses its own arguments (prompose_grasp.perception.train) so that torch loads only when used.
    sub.add_parser("train", help="train the ProM-Pose network on a synthetic dataset (see: train --help)")
    return parser


# ------------------------------------------------------------------------------------------------------------
# Argument checks. Every command checks its arguments first, before a model loads or a frame is read: a bad
# one ends the command with exit status 2 and one line on stderr (`main`), never after the work.

#: Extensions `--overlay` may have: the image formats OpenCV writes (`cv2.imwrite` picks it by extension).
_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def _check_output_file(path: str | None, flag: str, suffixes: Sequence[str] = ()) -> None:
    """`path` (when given) can be written as a file: not a folder, its folder exists and is writable (and
    the file, when it exists), its extension one of `suffixes` when given."""
    if path is None:
        return
    p = Path(path)
    if p.is_dir() or path.endswith(("/", os.sep)):
        raise InvalidInputError(f"{flag} {path}: is a folder; give a file path")
    if suffixes and p.suffix.lower() not in suffixes:
        suffix = p.suffix or "(none)"
        raise InvalidInputError(
            f"{flag} {path}: unknown image extension {suffix!r}; use one of {', '.join(suffixes)}"
        )
    folder = p.parent
    if not folder.is_dir():
        raise InvalidInputError(f"{flag} {path}: folder {str(folder)!r} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise InvalidInputError(f"{flag} {path}: not writable")


def _check_output_folder(path: str, flag: str) -> None:
    """`path` is a folder, or can be made one: no file there, and its nearest existing parent is a writable
    folder."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InvalidInputError(f"{flag} {path}: exists and is not a folder; give a folder to write into")
    parent = p
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise InvalidInputError(f"{flag} {path}: {str(parent)!r} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InvalidInputError(f"{flag} {path}: {str(parent)!r} is not writable")


def _check_input_file(path: str | None, flag: str) -> None:
    if path is not None and not Path(path).is_file():
        raise InvalidInputError(f"{flag} {path}: no such file")


def _check_at_least(value: int | None, flag: str, minimum: int) -> None:
    if value is not None and value < minimum:
        raise InvalidInputError(f"{flag} must be >= {minimum}, got {value}")


def _add_rerun(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--rerun",
        nargs="+",
        default=None,
        metavar="TARGET",
        help="record the run for the rerun viewer: FILE.rrd | spawn | connect [URL] (extra viz; "
        "docs/recording.md)",
    )


def _rerun_target(args: argparse.Namespace) -> RerunTarget | None:
    """The `--rerun` target, checked before any work (None without the flag)."""
    if getattr(args, "rerun", None) is None:
        return None
    from prompose_grasp.viz.target import RerunTarget

    return RerunTarget.parse(args.rerun)


def _open_recorder(target: RerunTarget | None) -> RerunRecorder | None:
    """A `RerunRecorder` for `target` (imports rerun), or None."""
    if target is None:
        return None
    from prompose_grasp.viz.rerun_recorder import RerunRecorder

    return RerunRecorder.open(target)


def _close_recorder(recorder: RerunRecorder | None, target: RerunTarget | None) -> None:
    if recorder is not None:
        recorder.close()
        print(f"rerun recording: {target}", file=sys.stderr)


def _check_scene_file(path: str) -> None:
    """The scene file exists and parses as YAML / JSON into a mapping; the simulator checks its keys when it
    loads it (`sim.scene_file.load_scene`), before anything else."""
    import json

    import yaml

    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"--scene {path}: no such file")
    if p.suffix.lower() not in (".yaml", ".yml", ".json"):
        raise InvalidInputError(f"--scene {path}: a scene file is .yaml, .yml or .json")
    try:
        text = p.read_text(encoding="utf-8")
        doc = json.loads(text) if p.suffix.lower() == ".json" else yaml.safe_load(text)
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError) as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        why = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InvalidInputError(f"--scene {path}: not a readable scene file{at}: {why}") from None
    if not isinstance(doc, dict):
        raise InvalidInputError(f"--scene {path}: a scene file holds a mapping, got {type(doc).__name__}")


def _add_bench(sub: argparse._SubParsersAction) -> None:
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

    _check_output_file(args.json_out, "--json")
    _check_at_least(args.max_frames, "--max-frames", 1)
    _check_at_least(args.candidates, "--candidates", 1)
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


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="a closed-loop language pick-and-place episode in MuJoCo (the main job)",
        description="Build a MuJoCo scene, say what to pick, and watch the loop run: observe, estimate the "
        "9-DoF pose, plan collision-free grasps, execute on the simulated UR arm, verify. Writes "
        "summary.json, overlay PNGs (estimate green, ground truth red) and, with --video, episode.mp4.",
    )
    p.add_argument("--command", dest="text", default="pick up the green bottle", help="what to do, in words")
    p.add_argument("--scene", default=None, help="scene file (default: sim/scenes/tabletop_household.yaml)")
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--seed", type=int, default=0, help="scene and sensor-noise seed (default 0)")
    p.add_argument("--video", action="store_true", help="also record episode.mp4 (slower)")
    _add_rerun(p)
    p.add_argument(
        "--record", default=None, metavar="DIR", help="also write the episode as a LeRobot dataset into DIR"
    )
    p.set_defaults(func=_run_demo)


def _run_demo(args: argparse.Namespace) -> int:
    # The simulator lives in `sim`, which the library never imports: run it as its own process.
    import subprocess

    scene = args.scene or str(
        Path(__file__).resolve().parents[1] / "sim" / "scenes" / "tabletop_household.yaml"
    )
    _check_scene_file(scene)
    _check_output_folder(args.out, "--out")
    _check_at_least(args.seed, "--seed", 0)
    _rerun_target(args)
    cmd = [sys.executable, "-m", "sim", "pick", "--scene", scene, "--command", args.text, "--out", args.out,
           "--seed", str(args.seed)]  # fmt: skip
    if args.video:
        cmd.append("--video")
    if args.rerun is not None:
        cmd += ["--rerun", *args.rerun]
    if args.record is not None:
        _check_output_folder(args.record, "--record")
        cmd += ["--record", args.record]
    return subprocess.call(cmd)


def _add_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="a language command on a real UR arm, gripper and camera (or its dry run)",
        description="Observe with the camera, estimate, plan and execute the command on a UR arm over RTDE "
        "with a Robotiq or suction gripper; every move passes the command validator first. --dry-run plans "
        "everything the same way and prints the moves without sending any (start with it). "
        "Set-up, calibration and safety: docs/hardware.md.",
    )
    p.add_argument("--robot", default="ur5e", help="UR model: ur3e, ur5e, ur10e, ur16e, ur5 (default ur5e)")
    p.add_argument(
        "--host",
        default=None,
        help="the controller's IP address (required unless --dry-run; with --dry-run the start joints are "
        "read from it over a receive-only link)",
    )
    p.add_argument("--gripper", required=True, choices=("robotiq", "suction"), help="robotiq | suction")
    p.add_argument(
        "--camera",
        required=True,
        help="realsense | kinect | a folder of NNNNNN-color.png / NNNNNN-depth.png with intrinsics.json",
    )
    p.add_argument("--command", dest="text", required=True, help='what to do, e.g. "pick up the red mug"')
    p.add_argument(
        "--calibration", required=True, help="hand-eye file (YAML/JSON) with T_base_cam or T_flange_cam [m]"
    )
    p.add_argument(
        "--places",
        default=None,
        help="place-target file (YAML/JSON: bin, table, pallet, conveyor in the base frame [m]; "
        "docs/hardware.md) for commands such as 'put the red mug in the bin'",
    )
    p.add_argument("--dry-run", action="store_true", help="plan and print the moves; send nothing")
    p.add_argument("--json", dest="json_out", default=None, help="also write the outcome and moves here")
    _add_rerun(p)
    p.set_defaults(func=_run_run)


def _run_run(args: argparse.Namespace) -> int:
    _check_output_file(args.json_out, "--json")
    _check_input_file(args.calibration, "--calibration")
    _check_input_file(args.places, "--places")
    target = _rerun_target(args)
    import json

    from prompose_grasp.hardware.run import CellSpec, run_command
    from prompose_grasp.robot.interfaces import LinearCommand

    spec = CellSpec(
        args.robot, args.host, args.gripper, args.camera, args.calibration, args.dry_run, args.places
    )
    recorder = _open_recorder(target)
    try:
        result = run_command(spec, args.text, recorder=recorder)
    finally:
        _close_recorder(recorder, target)
    outcome = result.outcome
    print("dry run: moves planned, none sent" if result.dry_run else "moves sent")
    for k, line in enumerate(result.moves, 1):
        print(f"  {k:2d}. {line}")
    print(f"outcome: {outcome.reason}: {outcome.message}")
    if args.json_out:
        doc = {
            "dry_run": result.dry_run,
            "outcome": outcome.to_dict(),
            "moves": list(result.moves),
            "grasp_T_base_tcp": None if outcome.grasp is None else outcome.grasp.T_base_tcp.tolist(),
            "linear_moves_tcp_xyz_m": [
                c.T_base_tcp[:3, 3].tolist() for c in result.arm_commands if isinstance(c, LinearCommand)
            ],
        }
        with open(args.json_out, "w") as f:
            json.dump(doc, f, indent=2)
    return exit_status(outcome.reason)


#: Exit status of a `run` that ended in a typed outcome that is neither a success nor a device fault ...
EXIT_FAILED = 1
#: ... of bad input (`main`) ...
EXIT_BAD_INPUT = 2
#: ... and of a device fault (module docstring).
EXIT_DEVICE_FAULT = 3


def exit_status(reason: str) -> int:
    """The exit status of a `run` outcome with this reason (module docstring)."""
    from prompose_grasp.pipeline.outcome import DEVICE_FAULT_REASONS

    if reason == "success":
        return 0
    return EXIT_DEVICE_FAULT if reason in DEVICE_FAULT_REASONS else EXIT_FAILED


def _add_bench_pick(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench-pick",
        help="closed-loop pick-and-place success rate in MuJoCo over seeded episodes",
        description="Run N seeded closed-loop episodes of a scenario (objects placed at random per seed) and "
        "report the success rate with a Wilson 95 %% interval, failure reasons and mean cycle time (sim and "
        "wall seconds); --oracle-mask uses the simulator's mask of the target (benchmark only) to separate "
        "perception from grasping failures; --real-meshes uses ../shared/data/objects.",
    )
    p.add_argument(
        "--scenario",
        required=True,
        help="tabletop_household | logistics_pallet | logistics_palletise | real_meshes | lookalikes",
    )
    p.add_argument("--episodes", type=int, default=20, help="seeded episodes (default 20)")
    p.add_argument("--seed0", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--oracle-mask", action="store_true", help="ORACLE: the sim's mask instead of grounding")
    p.add_argument("--real-meshes", action="store_true", help="tabletop with the ../shared meshes")
    p.add_argument("--place", action="store_true", help="tabletop: 'put the X in the bin'")
    p.add_argument(
        "--prompts",
        choices=("colour+name", "name"),
        default=None,
        help="what the command says: 'the red banana' (colour+name) or 'the banana' (name)",
    )
    p.add_argument("--json", dest="json_out", default=None, help="write the report here")
    p.add_argument("--out", default=None, help="also write each episode's summary and overlay under DIR")
    p.add_argument(
        "--ray", default=None, metavar="ADDRESS", help="episodes as Ray tasks: local:N | auto | HOST:PORT"
    )
    p.add_argument("--resume", action="store_true", help="skip the episodes JSON.sweep.jsonl lists as done")
    p.add_argument(
        "--record", default=None, metavar="DIR", help="also write the episodes as a LeRobot dataset into DIR"
    )
    p.set_defaults(func=_run_bench_pick)


def _run_bench_pick(args: argparse.Namespace) -> int:
    # The simulator lives in `sim`, which the library never imports: run it as its own process.
    import subprocess

    _check_output_file(args.json_out, "--json")
    if args.out is not None:
        _check_output_folder(args.out, "--out")
    _check_at_least(args.episodes, "--episodes", 1)
    _check_at_least(args.seed0, "--seed0", 0)
    cmd = [sys.executable, "-m", "sim", "bench-pick", "--scenario", args.scenario,
           "--episodes", str(args.episodes), "--seed0", str(args.seed0)]  # fmt: skip
    for flag in ("oracle_mask", "real_meshes", "place"):
        if getattr(args, flag):
            cmd.append("--" + flag.replace("_", "-"))
    if args.resume:
        cmd.append("--resume")
    if args.record is not None:
        _check_output_folder(args.record, "--record")
    for flag, value in (("--prompts", args.prompts), ("--json", args.json_out), ("--out", args.out),
                        ("--ray", args.ray), ("--record", args.record)):  # fmt: skip
        if value:
            cmd += [flag, value]
    return subprocess.call(cmd)


def _add_frame_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--depth-scale", type=float, default=0.001, help="metres per depth unit (default 0.001)")
    p.add_argument(
        "--intrinsics", type=float, nargs=4, required=True, metavar=("FX", "FY", "CX", "CY"), help="pixels"
    )
    p.add_argument("--prompt", required=True, help='the object, e.g. "mustard bottle"')
    p.add_argument("--json", dest="json_out", default=None, help="write the result here (default: stdout)")
    _add_rerun(p)


def _add_estimate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "estimate",
        help="9-DoF pose of the object named by a prompt in one RGB-D frame",
        description="Ground the prompt, generate the shape prior and fit the metric 9-DoF box in one frame. "
        "Prints (or writes) JSON: {prompt, objects: [{R, t, size, score, mask_pixels, prior}], timing_ms}, "
        "objects best first; an empty list when nothing matches.",
    )
    p.add_argument("--rgb", required=True, help="colour image (PNG/JPEG)")
    p.add_argument("--depth", required=True, help="registered depth, 16-bit PNG")
    _add_frame_args(p)
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


def _add_track(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "track",
        help="9-DoF poses over a recorded RGB-D sequence (one JSON line a frame)",
        description="Track the object named by a prompt through a folder of NNNNNN-color.png / "
        "NNNNNN-depth.png frames; writes one JSON line a frame: "
        "{frame, R, t, size, score, mask_pixels, prior}.",
    )
    p.add_argument("--sequence", required=True, help="folder of NNNNNN-color.png / NNNNNN-depth.png")
    _add_frame_args(p)
    p.set_defaults(func=_run_track)


#: The per-stage timings of the estimate JSON contract (DESIGN.md).
_STAGES = ("grounding", "prior", "pose", "total")


def _write_text(path: str | None, text: str) -> None:
    if path is None:
        print(text)
    else:
        with open(path, "w") as f:
            f.write(text + "\n")


def _run_estimate(args: argparse.Namespace) -> int:
    _check_at_least(args.max_objects, "--max-objects", 1)
    _check_output_file(args.json_out, "--json")
    _check_output_file(args.overlay, "--overlay", _IMAGE_SUFFIXES)
    target = _rerun_target(args)
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
    recorder = _open_recorder(target)
    try:
        estimator = ProMPose.default(recorder=recorder)
        estimates = estimator.estimate_all(frame, args.prompt, max_objects=args.max_objects)
    finally:
        _close_recorder(recorder, target)
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
    _write_text(args.json_out, json.dumps(result, indent=2))
    if args.overlay:
        best = estimates[:1]
        image = draw_poses(
            frame.rgb,
            frame.intrinsics,
            [e.pose for e in best],
            labels=[_overlay_label(args.prompt, e) for e in best],
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
    _check_output_file(args.json_out, "--json")
    target = _rerun_target(args)
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
    recorder = _open_recorder(target)
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
        _close_recorder(recorder, target)
    return 0


def _add_eval_nocs(sub: argparse._SubParsersAction) -> None:
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

    _check_output_file(args.json_out, "--json")
    results = load_nocs_results(args.results)
    kwargs = {} if args.synsets is None else {"synset_names": args.synsets}
    table = compute_nocs_map(results, iou_mode=args.iou_mode, **kwargs)
    print(format_nocs_table(table, title=f"NOCS mAP ({len(results)} images, iou_mode={args.iou_mode})"))
    if args.json_out:
        with open(args.json_out, "w") as f:
            json.dump(table, f, indent=2)
        print(f"wrote {args.json_out}")
    return 0


# ------------------------------------------------------------------------------------------------------------
# The perception service (`prompose_grasp.service`): `serve`, and `estimate --server URL` as its client.


def _add_serve(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "serve",
        help="keep the estimator loaded and answer estimate / track / health over HTTP (extra `serve`)",
        description="A local perception service (FastAPI + uvicorn): POST /v1/estimate, POST /v1/track, "
        "GET /v1/health; the OpenAPI schema at /openapi.json. See docs/service.md.",
    )
    p.add_argument(
        "--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)"
    )
    p.add_argument("--port", type=int, default=8765, help="TCP port (default 8765; 0 picks a free one)")
    p.add_argument(
        "--token", default=None, help="require this bearer token (default: $PROMPOSE_GRASP_TOKEN when set)"
    )
    p.add_argument("--max-body-mb", type=float, default=32.0, help="largest request body [MiB] (default 32)")
    p.add_argument(
        "--max-queue", type=int, default=32, help="requests that may wait (default 32); more get 503"
    )
    p.add_argument("--device", default="cpu", help="torch device of the estimator (default cpu)")
    p.set_defaults(func=_run_serve)


def _run_serve(args: argparse.Namespace) -> int:
    from prompose_grasp.service.app import ServiceConfig, serve

    _check_at_least(args.max_queue, "--max-queue", 1)
    if not args.max_body_mb > 0:
        raise InvalidInputError(f"--max-body-mb must be > 0, got {args.max_body_mb}")
    config = ServiceConfig(
        host=args.host,
        port=args.port,
        token=args.token or os.environ.get("PROMPOSE_GRASP_TOKEN") or None,
        max_body_bytes=int(args.max_body_mb * 2**20),
        max_queue=args.max_queue,
        device=args.device,
    )

    def ready(url: str) -> None:
        print(f"prompose-grasp serve: listening on {url}", file=sys.stderr, flush=True)

    serve(config, ready=ready)
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
    _write_text(args.json_out, json.dumps(doc, indent=2))
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


def _overlay_label(prompt: str, est: Estimate) -> str:
    """`prompt (prior, NN% seen)`: the share of the box's facing surface the mask shows (`Estimate.coverage`)
    tells a person looking at the overlay how much of the box rests on the prior alone."""
    seen = f", {est.coverage:.0%} seen" if math.isfinite(est.coverage) else ""
    return f"{prompt} ({est.prior.name}{seen})"


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["train"]:
        from prompose_grasp.perception import train

        return train.main(argv[1:])
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=[logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)],
        format="%(levelname)s %(name)s: %(message)s",
    )
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return int(args.func(args))
    except DeviceFault as exc:  # raised outside the loop's own handling (connecting, disconnecting)
        message = " ".join(str(exc).split())
        print(f"prompose-grasp {args.command}: device fault: {message}", file=sys.stderr)
        return EXIT_DEVICE_FAULT
    except PromposeError as exc:
        message = " ".join(str(exc).split())  # one line, whatever the message holds
        print(f"prompose-grasp {args.command}: error: {message}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
