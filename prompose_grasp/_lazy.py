"""Lazy package attributes (PEP 562): a package re-exports names without importing their modules up front.

The packages' `__init__`s used to import every module they re-export, so `import prompose_grasp.geometry`
(numpy + scipy by design) also paid for mujoco, python-fcl, OpenCV and trimesh through the package root:
~0.9 s before the first line of geometry ran. Each `__init__` now names where its exports live and
`attach` resolves one on first access, importing only that module (and what it imports).

>>> __getattr__, __dir__ = attach(__name__, {"prompose_grasp.geometry.pose9d": ("Pose9D",)})  # doctest: +SKIP
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterable, Mapping
from typing import Any

__all__ = ["attach"]


def attach(
    package: str, exports: Mapping[str, Iterable[str]], submodules: Iterable[str] = ()
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The `__getattr__` and `__dir__` of a package whose exports load on first access.

    Args:
        package: the package's `__name__`.
        exports: module path -> the names the package re-exports from it.
        submodules: child modules reachable as attributes (`prompose_grasp.perception` after a bare
            `import prompose_grasp`), imported on first access.

    Returns:
        (`__getattr__`, `__dir__`) to bind at the package's top level. A resolved name is stored on the
        package, so later accesses are plain attribute reads.
    """
    where = {name: module for module, names in exports.items() for name in names}
    children = frozenset(submodules)

    def __getattr__(name: str) -> Any:
        module = where.get(name)
        if module is not None:
            value = getattr(importlib.import_module(module), name)
            setattr(sys.modules[package], name, value)
            return value
        if name in children:
            return importlib.import_module(f"{package}.{name}")
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    def __dir__() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where) | children)

    return __getattr__, __dir__
