"""The NOCS evaluation example runs as a user would run it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "eval_nocs_pickles.py"


def test_eval_nocs_example_runs():
    out = subprocess.run([sys.executable, str(EXAMPLE)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for mode in ("nocs", "aligned", "exact"):
        assert f"iou_mode={mode}" in out.stdout
    assert "mean 3D50 by mode" in out.stdout
