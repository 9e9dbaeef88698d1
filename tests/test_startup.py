"""Start-up cost: what importing the package loads (checked in fresh interpreters), and the lazy exports.

The package roots re-export lazily (PEP 562, `prompose_grasp._lazy`): importing the geometry layer costs
what numpy and scipy cost, and the package root loads neither torch nor mujoco.
"""

from __future__ import annotations

import ast
import importlib
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import prompose_grasp

ROOT = Path(__file__).resolve().parents[1]
HEAVY = {"torch", "mujoco", "fcl", "cv2", "transformers", "sentence_transformers", "tokenizers"}


def _loaded_after(code: str) -> set[str]:
    """Top-level module names loaded by `code` in a fresh interpreter (run from the repository root)."""
    probe = f"{code}\nimport sys, json\nprint(json.dumps(sorted({{m.split('.')[0] for m in sys.modules}})))"
    out = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, check=True, timeout=120
    )
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


def test_geometry_loads_numpy_and_scipy_only():
    loaded = _loaded_after(
        "import prompose_grasp.geometry\n"
        "from prompose_grasp.geometry import Pose9D, oriented_box_iou, back_project\n"
        "import prompose_grasp.geometry.se3"
    )
    assert not loaded & (HEAVY | {"trimesh", "pinocchio", "mink"}), loaded & HEAVY


def test_package_root_loads_no_torch_or_mujoco():
    loaded = _loaded_after("import prompose_grasp\nprompose_grasp.PromposeError\nprompose_grasp.__version__")
    assert not loaded & {"torch", "mujoco", "fcl", "cv2", "trimesh"}


def test_cli_help_loads_no_torch_or_mujoco():
    loaded = _loaded_after("from prompose_grasp.cli import build_parser\nbuild_parser().format_help()")
    assert not loaded & {"torch", "mujoco"}


def _packages() -> list[str]:
    found = pkgutil.walk_packages(prompose_grasp.__path__, "prompose_grasp.")
    return ["prompose_grasp", *sorted(m.name for m in found if m.ispkg)]


@pytest.mark.parametrize("name", _packages())
def test_lazy_exports_match_the_type_checking_imports_and_resolve(name):
    """Each package's lazy table names the same (module, name) pairs as its `if TYPE_CHECKING:` imports (what
    type checkers and readers see), and every name of `__all__` resolves to the object its module defines."""
    package = importlib.import_module(name)
    tree = ast.parse(Path(package.__file__).read_text())
    checked: set[tuple[str, str]] = set()
    for node in tree.body:
        if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING":
            for imp in node.body:
                assert isinstance(imp, ast.ImportFrom)
                checked |= {(imp.module, a.name) for a in imp.names}
    lazy: set[tuple[str, str]] = set()
    for node in tree.body:
        call = getattr(node, "value", None)
        if isinstance(call, ast.Call) and getattr(call.func, "id", "") == "attach":
            table = ast.literal_eval(call.args[1])
            lazy = {(module, n) for module, names in table.items() for n in names}
    assert lazy == checked
    for module, n in lazy:
        assert getattr(package, n) is getattr(importlib.import_module(module), n)
    assert set(package.__all__) <= set(dir(package))
    assert all(hasattr(package, n) for n in package.__all__)


def test_subpackages_are_attributes_of_the_root():
    assert prompose_grasp.geometry.Pose9D is prompose_grasp.Pose9D
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        _ = prompose_grasp.not_a_name
