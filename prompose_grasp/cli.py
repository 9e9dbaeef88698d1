"""The `prompose-grasp` command. Argument parsing lives here and nowhere else in the library."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence

import prompose_grasp
from prompose_grasp.errors import PromposeError


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="prompose-grasp",
        description="Language-commanded pick-and-place from RGB-D frames (ProM-Pose perception, "
        "python-fcl grasping, Pinocchio/mink IK, MuJoCo and UR execution).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {prompose_grasp.__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-v, -vv)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _add_eval_nocs(sub)
    return parser


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

    results = load_nocs_results(args.results)
    kwargs = {} if args.synsets is None else {"synset_names": args.synsets}
    table = compute_nocs_map(results, iou_mode=args.iou_mode, **kwargs)
    print(format_nocs_table(table, title=f"NOCS mAP ({len(results)} images, iou_mode={args.iou_mode})"))
    if args.json_out:
        with open(args.json_out, "w") as f:
            json.dump(table, f, indent=2)
        print(f"wrote {args.json_out}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
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
    except PromposeError as exc:
        print(f"prompose-grasp {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
