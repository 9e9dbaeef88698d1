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
import sys
from collections.abc import Sequence

import prompose_grasp
from prompose_grasp.cli.exit_codes import EXIT_BAD_INPUT, EXIT_DEVICE_FAULT, EXIT_FAILED, exit_status
from prompose_grasp.cli.perception import add_bench, add_estimate, add_eval_nocs, add_track
from prompose_grasp.cli.pick import add_bench_pick, add_demo, add_run
from prompose_grasp.cli.serve import add_serve
from prompose_grasp.errors import DeviceFault, PromposeError

__all__ = ["EXIT_BAD_INPUT", "EXIT_DEVICE_FAULT", "EXIT_FAILED", "build_parser", "exit_status", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="prompose-grasp",
        description="Language-commanded pick-and-place from RGB-D frames (ProM-Pose perception, "
        "python-fcl grasping, Pinocchio/mink IK, MuJoCo and UR execution).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {prompose_grasp.__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-v, -vv)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    add_demo(sub)
    add_estimate(sub)
    add_track(sub)
    add_eval_nocs(sub)
    add_bench(sub)
    add_run(sub)
    add_bench_pick(sub)
    add_serve(sub)
    # `train` parses its own arguments (prompose_grasp.perception.train) so that torch loads only when used.
    sub.add_parser("train", help="train the ProM-Pose network on a synthetic dataset (see: train --help)")
    return parser


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
