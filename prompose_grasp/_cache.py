"""The user cache directory: what is costly to compute and the same between processes is kept here."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir"]


def cache_dir() -> Path:
    """Where results are kept between processes: `$PROMPOSE_GRASP_CACHE`, else
    `$XDG_CACHE_HOME/prompose_grasp`, else `~/.cache/prompose_grasp`. Nothing is created here."""
    env = os.environ.get("PROMPOSE_GRASP_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "prompose_grasp"
