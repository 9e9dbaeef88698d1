"""`python -m sim view --scene FILE --out img.png`: render a scenario for a person to look at.

Each camera gives a row: colour (with ground-truth boxes and names when --boxes) and colourised depth after
the camera's noise model.

`python -m sim pick --scene FILE --command "..." --out DIR --seed N [--video] [--rerun FILE.rrd | spawn |
connect URL] [--record DATASET]`: one closed-loop language pick-and-place episode (`sim.pick`), writing
DIR/summary.json, overlay_0.png and optionally episode.mp4, a rerun recording (extra `viz`) and the episode
as a LeRobot dataset (extra `record`; both in docs/recording.md).

`python -m sim bench-pick --scenario tabletop_household|logistics_pallet|logistics_palletise|real_meshes|
lookalikes --episodes N [--oracle-mask] [--real-meshes] [--place] [--prompts colour+name|name] [--json OUT]
[--record DATASET [--record-fps 20] [--record-size 160x120]]`: the closed-loop success rate over seeded
episodes, with wrong-object successes and ambiguous refusals accounted (`sim.bench_pick`); --record writes
the episodes as a LeRobot v3.0 dataset (docs/recording.md).

`python -m sim soak-track [--n 10000] [--json OUT]` and `python -m sim soak-episodes [--episodes 200]
[--json OUT]`: memory (RSS, tracemalloc) and time per step over a 10,000-frame track and over back-to-back
pick episodes in one process (`sim.soak`).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import cv2
import numpy as np

from prompose_grasp.errors import PromposeError


def _view(args: argparse.Namespace) -> int:
    from prompose_grasp.perception.overlay import colorize_depth, distinct_colors, draw_poses
    from sim.scene_file import load_world
    from sim.viz import tile

    rng = np.random.default_rng(args.seed)
    with load_world(args.scene, seed=args.seed) as world:
        cameras = [args.camera] if args.camera else list(world.cameras)
        images = []
        for name in cameras:
            frame = world.render(name, rng=rng)
            color = frame.rgb
            if args.boxes:
                gts = [g for g in world.ground_truth(name) if g.t_cam_obj_m[2] > 0]
                poses = [g.as_pose9d() for g in gts]
                labels = [g.name for g in gts]
                color = draw_poses(
                    color, frame.intrinsics, poses, distinct_colors(len(gts)), labels, thickness=1
                )
            images += [color, colorize_depth(frame.depth_m)]
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(out), tile(images)[..., ::-1])
        print(f"wrote {out} ({len(cameras)} camera(s): {', '.join(cameras)}; {len(world.objects)} objects)")
    return 0


def _pick(args: argparse.Namespace) -> int:
    from prompose_grasp.pipeline.outcome import DEVICE_FAULT_REASONS
    from sim.pick import run_episode

    def show(event) -> None:
        print(f"[{100 * event.fraction:3.0f}%] {event.stage:8s} {event.message}", flush=True)

    from prompose_grasp.cli.arguments import open_recorder, rerun_target
    from sim.bench_pick import record_config_from_args

    target = rerun_target(args)  # checked before the scene loads
    record = record_config_from_args(args)
    sink = None
    if record is not None:
        from sim.record_dataset import EpisodeSink

        sink = EpisodeSink(args.record, record)  # checks the folder before anything runs
    recorder = open_recorder(target)
    try:
        result = run_episode(
            args.scene, args.command, args.out, seed=args.seed, video=args.video, on_event=show,
            recorder=recorder, record=record,
        )  # fmt: skip
    finally:
        if recorder is not None:
            recorder.close()
            print(f"rerun recording: {target}")
    if sink is not None:
        s = result.summary
        sink.add(result.recording, args.command, s["success"], s["outcome"]["reason"], args.seed, args.scene)
        sink.close()
        print(f"recorded the episode ({result.recording.num_frames} frames) into {args.record}")
    if result.summary["outcome"]["reason"] == "not_understood":
        print(f"command not understood: {result.summary['outcome']['message']}", file=sys.stderr)
        return 2
    s = result.summary
    print(
        f"{'success' if s['success'] else 'FAILED'}: {s['outcome']['reason']} ({s['outcome']['message']}); "
        f"lift {100 * s['lift_height_m']:.1f} cm; sim {s['sim_time_s']:.1f} s in "
        f"{s['timings_s']['episode_wall']:.1f} s wall; wrote {args.out}/summary.json"
    )
    if s["success"]:
        return 0
    # the `prompose-grasp` exit codes: 3 a device fault (a protective stop from contact), else 1
    return 3 if s["outcome"]["reason"] in DEVICE_FAULT_REASONS else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="subcommand", required=True)
    view = sub.add_parser("view", help="render a scene file to a PNG")
    view.add_argument("--scene", required=True, help="scene file (.yaml/.yml/.json)")
    view.add_argument("--out", required=True, help="output PNG")
    view.add_argument("--camera", default=None, help="one camera (default: all)")
    view.add_argument(
        "--seed", type=int, default=None, help="placement/appearance/noise seed (default: file's)"
    )
    view.add_argument("--boxes", action="store_true", help="overlay ground-truth 9-DoF boxes")
    pick = sub.add_parser("pick", help="run one closed-loop language pick-and-place episode")
    pick.add_argument("--scene", required=True, help="scene file (.yaml/.yml/.json) with a robot and gripper")
    pick.add_argument("--command", required=True, help='free text, e.g. "pick up the red mug"')
    pick.add_argument("--out", required=True, help="output folder (summary.json, overlay_0.png, episode.mp4)")
    pick.add_argument("--seed", type=int, default=None, help="scene/noise seed (default: file's)")
    pick.add_argument("--video", action="store_true", help="also write episode.mp4")
    from prompose_grasp.cli.arguments import add_rerun
    from sim.bench_pick import add_arguments, add_record_arguments

    add_rerun(pick)
    add_record_arguments(pick)

    bench = sub.add_parser("bench-pick", help="closed-loop success rate over seeded episodes")
    add_arguments(bench)
    from sim.soak import add_episode_arguments, add_track_arguments

    add_track_arguments(sub.add_parser("soak-track", help="memory and time over a 10,000-frame track"))
    add_episode_arguments(sub.add_parser("soak-episodes", help="memory and time over back-to-back episodes"))
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        if args.subcommand == "bench-pick":
            from sim.bench_pick import run_from_args

            return run_from_args(args)
        if args.subcommand in ("soak-track", "soak-episodes"):
            from sim.soak import run_from_args as run_soak_from_args

            return run_soak_from_args(args)
        return _view(args) if args.subcommand == "view" else _pick(args)
    except PromposeError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
