"""Seeded malformed scene files: every case ends in a `PromposeError` from `load_scene` / `parse_scene`, with
a one-line message, before anything is built.

The cases mutate the shipped `tabletop_household.yaml` in one place each, chosen to be malformed by
construction: broken YAML (checked to fail `yaml.safe_load`), a document that is no mapping, a number
replaced by text, NaN, a list or a mapping, a name replaced by an unknown one, a section replaced by the
wrong type, an unknown key added, a required key removed. Mutations that can be valid are left out (null for
an optional section, a number for a [lo, hi] range, a free-text name or prompt changed).
"""

from __future__ import annotations

import copy
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from prompose_grasp.errors import PromposeError
from sim.scene_file import load_scene, parse_scene

SCENES = Path(__file__).resolve().parents[2] / "sim" / "scenes"
BASE_TEXT = (SCENES / "tabletop_household.yaml").read_text()
BASE_DOC = yaml.safe_load(BASE_TEXT)
N_DOC_CASES = 260
N_FILE_CASES = 60

#: Keys whose string value names one of a fixed set of choices (or a file): any other string is wrong.
_NAME_KEYS = {"type", "model", "family", "noise", "support", "on_top_of", "texture", "candidate_order"}
#: Keys whose value is free text: any string is valid there.
_FREE_TEXT_KEYS = {"name", "prompt"}
#: Keys that may be removed: required ones (their absence is an error).
_REQUIRED = {
    ("objects", "name"),
    ("objects", "mesh"),
    ("objects", "place"),
    ("supports", "type"),
    ("cameras", "name"),
    ("cameras", "pose"),
    ("cameras", "mount"),
    ("robot", "model"),
    ("gripper", "type"),
    ("place", "support"),
    ("mesh", "family"),
    ("place_targets", "support"),
    ("place_targets", "name"),
}


def _leaves(node: Any, path: tuple = ()) -> list[tuple[tuple, Any]]:
    """(path, value) of every node of the document, depth first (the root excluded)."""
    out = []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for key, value in items:
        out.append(((*path, key), value))
        out.extend(_leaves(value, (*path, key)))
    return out


def _set(doc: dict, path: tuple, value: Any) -> None:
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value


def _section(path: tuple) -> str:
    """The name of the mapping a path's last key belongs to ("objects" for ("objects", 2, "name"))."""
    named = [k for k in path[:-1] if isinstance(k, str)]
    return named[-1] if named else ""


LEAVES = _leaves(BASE_DOC)
NUMBERS = [(p, v) for p, v in LEAVES if isinstance(v, int | float) and not isinstance(v, bool)]
NUMBERS = [(p, v) for p, v in NUMBERS if "pipeline" not in p]
PIPELINE_NUMBERS = [(p, v) for p, v in LEAVES if isinstance(v, int | float) and "pipeline" in p]
NAMES = [(p, v) for p, v in LEAVES if isinstance(v, str) and isinstance(p[-1], str) and p[-1] in _NAME_KEYS]
MAPPINGS = [(p, v) for p, v in LEAVES if isinstance(v, dict) and p[-1] != "params"]
LISTS = [(p, v) for p, v in LEAVES if isinstance(v, list) and p[-1] not in ("radius_m", "height_m")]
REMOVABLE = [(p, v) for p, v in LEAVES if isinstance(p[-1], str) and (_section(p), p[-1]) in _REQUIRED]


def _bad_doc(rng: np.random.Generator) -> tuple[str, Any]:
    """(label, document) with one malformed change to the tabletop scene."""
    doc = copy.deepcopy(BASE_DOC)
    kind = int(rng.integers(8))
    if kind == 0:  # a number replaced by text, NaN, inf, a list or a mapping
        path, _ = NUMBERS[rng.integers(len(NUMBERS))]
        bad = ["abc", "", math.nan, math.inf, -math.inf, [1.0, 2.0, 3.0, 4.0, 5.0], {"x": 1}, [[1], [2, 3]]]
        value = bad[rng.integers(len(bad))]
    elif kind == 1:  # a pipeline setting (PickConfig) replaced by text, NaN or a list
        path, _ = PIPELINE_NUMBERS[rng.integers(len(PIPELINE_NUMBERS))]
        value = ["abc", math.nan, math.inf, [1, 2], {"x": 1}][rng.integers(5)]
    elif kind == 2:  # a name replaced by an unknown one or by another type
        path, _ = NAMES[rng.integers(len(NAMES))]
        value = ["no_such_name_xyz", 5, [1], {"a": 1}, True][rng.integers(5)]
    elif kind == 3:  # a section (mapping) replaced by the wrong type
        path, _ = MAPPINGS[rng.integers(len(MAPPINGS))]
        value = ["abc", 5, [1, 2], True][rng.integers(4)]
    elif kind == 4:  # a list replaced by the wrong type
        path, _ = LISTS[rng.integers(len(LISTS))]
        value = ["abc", {"a": 1}, 7, [[1, 2], [3]]][rng.integers(4)]
    elif kind == 5:  # an unknown key in a mapping (the document itself included)
        mappings = [((), doc)] + [(p, v) for p, v in MAPPINGS]
        path, _ = mappings[rng.integers(len(mappings))]
        node = doc
        for key in path:
            node = node[key]
        node[f"zz_unknown_{rng.integers(100)}"] = 1
        return f"unknown key in {path}", doc
    elif kind == 6:  # a required key removed
        path, _ = REMOVABLE[rng.integers(len(REMOVABLE))]
        node = doc
        for key in path[:-1]:
            node = node[key]
        del node[path[-1]]
        return f"removed {path}", doc
    else:  # no mapping at all
        return "not a mapping", [None, [], [BASE_DOC], "scene", 5, 1.5][rng.integers(6)]
    _set(doc, path, value)
    return f"{path} = {value!r}", doc


_BROKEN_YAML = (
    "objects: [unclosed",
    "\tkey: 1",
    "key: 'unterminated",
    "key: value: other",
    "- *no_such_anchor",
    "}{",
    "key: [1, 2",
    "? [",
)


def _bad_file(rng: np.random.Generator, folder: Path, k: int) -> tuple[str, Path]:
    """(label, path) of a scene file that cannot be read as a scene."""
    kind = int(rng.integers(5))
    if kind == 0:  # broken YAML, inserted at a random line (or appended where that still parses)
        lines = BASE_TEXT.splitlines()
        snippet = _BROKEN_YAML[rng.integers(len(_BROKEN_YAML))]
        at = int(rng.integers(len(lines) + 1))
        text = "\n".join([*lines[:at], snippet, *lines[at:]])
        try:
            yaml.safe_load(text)
        except yaml.YAMLError:
            pass
        else:
            text = BASE_TEXT + "\n" + snippet
        with pytest.raises(yaml.YAMLError):  # the case is malformed by construction
            yaml.safe_load(text)
        path = folder / f"broken_{k}.yaml"
        path.write_text(text)
        return f"broken YAML {snippet!r} at line {at}", path
    if kind == 1:  # broken JSON
        path = folder / f"broken_{k}.json"
        path.write_text('{"version": 1, "objects": [' if rng.random() < 0.5 else "{'version': 1}")
        return "broken JSON", path
    if kind == 2:  # bytes that are no UTF-8 text
        path = folder / f"binary_{k}.yaml"
        path.write_bytes(bytes(rng.integers(128, 256, 64, dtype=np.uint8)))
        return "binary", path
    if kind == 3:  # a file name the reader does not know, or a folder, or nothing
        choice = int(rng.integers(3))
        path = [folder / f"scene_{k}.txt", folder, folder / "missing.yaml"][choice]
        if choice == 0:
            path.write_text(BASE_TEXT)
        return f"path kind {choice}", path
    path = folder / f"empty_{k}.yaml"  # an empty file (no document) or a comment only
    path.write_text("" if rng.random() < 0.5 else "# nothing here\n")
    return "empty", path


def _check(label: str, call, failures: list[str]) -> None:
    try:
        call()
    except PromposeError as exc:
        if not str(exc).strip() or "\n" in str(exc):
            failures.append(f"{label}: message is not one line: {exc!s}")
    except Exception as exc:  # the point of the test: no foreign exception escapes
        failures.append(f"{label}: {type(exc).__name__}: {exc}")
    else:
        failures.append(f"{label}: accepted")


def test_the_shipped_scene_parses():
    parse_scene(copy.deepcopy(BASE_DOC), base_dir=SCENES)  # the cases start from a valid document


def test_malformed_scene_documents_are_refused():
    rng = np.random.default_rng(20273)
    failures: list[str] = []
    t0 = time.perf_counter()
    for k in range(N_DOC_CASES):
        label, doc = _bad_doc(rng)
        _check(f"case {k} ({label})", lambda doc=doc: parse_scene(doc, base_dir=SCENES), failures)
    assert not failures, "\n".join(failures[:20])
    assert time.perf_counter() - t0 < 30.0  # parsing only: nothing is built


def test_malformed_scene_files_are_refused(tmp_path):
    rng = np.random.default_rng(20274)
    failures: list[str] = []
    for k in range(N_FILE_CASES):
        label, path = _bad_file(rng, tmp_path, k)
        _check(f"case {k} ({label})", lambda path=path: load_scene(path), failures)
    assert not failures, "\n".join(failures[:20])


def test_bad_yaml_names_the_line(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(BASE_TEXT.replace("\nseed: 0", "\nseed: [0"))
    with pytest.raises(PromposeError, match=r"is not valid YAML at line \d+, column \d+"):
        load_scene(path)


def test_an_episode_refuses_bad_arguments_before_the_estimator_loads(tmp_path, monkeypatch):
    from prompose_grasp.perception import estimator as estimator_module
    from sim.pick import run_episode

    def refuse(*args, **kwargs):
        raise AssertionError("the estimator loaded for bad arguments")

    monkeypatch.setattr(estimator_module.ProMPose, "default", classmethod(refuse))
    scene = SCENES / "tabletop_household.yaml"
    existing = tmp_path / "summary.txt"
    existing.write_text("a file")
    with pytest.raises(PromposeError, match="exists and is not a folder"):
        run_episode(scene, "pick up the red mug", out_dir=existing)
    for seed in (-1, 1.5, "0", True):
        with pytest.raises(PromposeError, match="seed must be an integer >= 0"):
            run_episode(scene, "pick up the red mug", seed=seed)
    broken = tmp_path / "broken.yaml"
    broken.write_text("version: 1\nobjects: 5\n")
    with pytest.raises(PromposeError, match="objects must be a list"):
        run_episode(broken, "pick up the red mug")


def test_sim_pick_on_a_broken_scene_exits_2_with_one_line(tmp_path):
    import subprocess
    import sys

    broken = tmp_path / "broken.yaml"
    broken.write_text("version: 1\nobjects: [unclosed\n")
    root = Path(__file__).resolve().parents[2]
    argv = ["pick", "--scene", str(broken), "--command", "pick up the mug", "--out", str(tmp_path / "out")]
    run = subprocess.run(
        [sys.executable, "-m", "sim", *argv], capture_output=True, text=True, cwd=root, timeout=120
    )
    assert run.returncode == 2
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "is not valid YAML at line" in lines[0], run.stderr
    assert not (tmp_path / "out").exists()
