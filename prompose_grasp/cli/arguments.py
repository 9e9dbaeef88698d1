"""Argument checks and the `--rerun` option shared by the commands.

Every command checks its arguments first, before a model loads or a frame is read: a bad one ends the
command with exit status 2 and one line on stderr (`prompose_grasp.cli.main`), never after the work.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from prompose_grasp.errors import InvalidInputError

if TYPE_CHECKING:  # rerun loads only when a command is given --rerun
    from prompose_grasp.viz.rerun_recorder import RerunRecorder
    from prompose_grasp.viz.target import RerunTarget


#: Extensions `--overlay` may have: the image formats OpenCV writes (`cv2.imwrite` picks it by extension).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")


def check_output_file(path: str | None, flag: str, suffixes: Sequence[str] = ()) -> None:
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


def check_output_folder(path: str, flag: str) -> None:
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


def check_input_file(path: str | None, flag: str) -> None:
    if path is not None and not Path(path).is_file():
        raise InvalidInputError(f"{flag} {path}: no such file")


def check_at_least(value: int | None, flag: str, minimum: int) -> None:
    if value is not None and value < minimum:
        raise InvalidInputError(f"{flag} must be >= {minimum}, got {value}")


def check_scene_file(path: str) -> None:
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


def write_text(path: str | None, text: str) -> None:
    if path is None:
        print(text)
    else:
        with open(path, "w") as f:
            f.write(text + "\n")


def add_rerun(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--rerun",
        nargs="+",
        default=None,
        metavar="TARGET",
        help="record the run for the rerun viewer: FILE.rrd | spawn | connect [URL] (extra viz; "
        "docs/recording.md)",
    )


def rerun_target(args: argparse.Namespace) -> RerunTarget | None:
    """The `--rerun` target, checked before any work (None without the flag)."""
    if getattr(args, "rerun", None) is None:
        return None
    from prompose_grasp.viz.target import RerunTarget

    return RerunTarget.parse(args.rerun)


def open_recorder(target: RerunTarget | None) -> RerunRecorder | None:
    """A `RerunRecorder` for `target` (imports rerun), or None."""
    if target is None:
        return None
    from prompose_grasp.viz.rerun_recorder import RerunRecorder

    return RerunRecorder.open(target)


def close_recorder(recorder: RerunRecorder | None, target: RerunTarget | None) -> None:
    if recorder is not None:
        recorder.close()
        print(f"rerun recording: {target}", file=sys.stderr)
