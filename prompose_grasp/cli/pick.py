"""The commands that run the pick loop: `demo` (the MuJoCo stand-in), `run` (a real UR cell, or a dry run)
and `bench-pick` (the closed-loop benchmark)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from prompose_grasp.cli.arguments import (
    add_rerun,
    check_at_least,
    check_input_file,
    check_output_file,
    check_output_folder,
    check_scene_file,
    close_recorder,
    open_recorder,
    rerun_target,
)
from prompose_grasp.cli.exit_codes import exit_status


def add_demo(sub: argparse._SubParsersAction) -> None:
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
    add_rerun(p)
    p.add_argument(
        "--record", default=None, metavar="DIR", help="also write the episode as a LeRobot dataset into DIR"
    )
    p.set_defaults(func=_run_demo)


def _run_demo(args: argparse.Namespace) -> int:
    # The simulator lives in `sim`, which the library never imports: run it as its own process.
    import subprocess

    scene = args.scene or str(
        Path(__file__).resolve().parents[2] / "sim" / "scenes" / "tabletop_household.yaml"
    )
    check_scene_file(scene)
    check_output_folder(args.out, "--out")
    check_at_least(args.seed, "--seed", 0)
    rerun_target(args)
    cmd = [sys.executable, "-m", "sim", "pick", "--scene", scene, "--command", args.text, "--out", args.out,
           "--seed", str(args.seed)]  # fmt: skip
    if args.video:
        cmd.append("--video")
    if args.rerun is not None:
        cmd += ["--rerun", *args.rerun]
    if args.record is not None:
        check_output_folder(args.record, "--record")
        cmd += ["--record", args.record]
    return subprocess.call(cmd)


def add_run(sub: argparse._SubParsersAction) -> None:
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
    add_rerun(p)
    p.set_defaults(func=_run_run)


def _run_run(args: argparse.Namespace) -> int:
    check_output_file(args.json_out, "--json")
    check_input_file(args.calibration, "--calibration")
    check_input_file(args.places, "--places")
    target = rerun_target(args)
    import json

    from prompose_grasp.hardware.run import CellSpec, run_command
    from prompose_grasp.robot.interfaces import LinearCommand

    spec = CellSpec(
        args.robot, args.host, args.gripper, args.camera, args.calibration, args.dry_run, args.places
    )
    recorder = open_recorder(target)
    try:
        result = run_command(spec, args.text, recorder=recorder)
    finally:
        close_recorder(recorder, target)
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


def add_bench_pick(sub: argparse._SubParsersAction) -> None:
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

    check_output_file(args.json_out, "--json")
    if args.out is not None:
        check_output_folder(args.out, "--out")
    check_at_least(args.episodes, "--episodes", 1)
    check_at_least(args.seed0, "--seed0", 0)
    cmd = [sys.executable, "-m", "sim", "bench-pick", "--scenario", args.scenario,
           "--episodes", str(args.episodes), "--seed0", str(args.seed0)]  # fmt: skip
    for flag in ("oracle_mask", "real_meshes", "place"):
        if getattr(args, flag):
            cmd.append("--" + flag.replace("_", "-"))
    if args.resume:
        cmd.append("--resume")
    if args.record is not None:
        check_output_folder(args.record, "--record")
    for flag, value in (("--prompts", args.prompts), ("--json", args.json_out), ("--out", args.out),
                        ("--ray", args.ray), ("--record", args.record)):  # fmt: skip
        if value:
            cmd += [flag, value]
    return subprocess.call(cmd)
