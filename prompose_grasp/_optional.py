"""Optional dependencies fail at the point of use with the install hint, never as a silent `None`."""

from __future__ import annotations

import importlib
from types import ModuleType

from prompose_grasp.errors import MissingDependencyError


def require(module: str, extra: str) -> ModuleType:
    """Import `module` or raise `MissingDependencyError` naming the extra that installs it.

    >>> rtde_control = require("rtde_control", extra="ur")  # doctest: +SKIP
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingDependencyError(
            f"{module!r} is needed here but is not installed; install it with: "
            f"pip install 'prompose-grasp[{extra}]'"
        ) from exc
