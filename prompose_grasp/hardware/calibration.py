"""Hand-eye calibration files: where the camera is, as one rigid transform.

A YAML or JSON file holds exactly one of

```yaml
T_base_cam: [[r11, r12, r13, x], [r21, r22, r23, y], [r31, r32, r33, z], [0, 0, 0, 1]]   # fixed camera
T_flange_cam: [[...], [...], [...], [0, 0, 0, 1]]                                       # wrist camera
```

in metres, with the camera frame OpenCV's (x right, y down, z forward) and `base` / `flange` the UR
controller's base and tool0 frames (docs/conventions.md). An optional `note:` string is kept for the log.
`load_calibration` refuses anything that is not a proper rigid transform and says what is wrong.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from numpy.typing import ArrayLike

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.hardware.errors import CalibrationError

__all__ = ["HandEyeCalibration", "load_calibration"]

Mount = Literal["eye_to_hand", "eye_in_hand"]

_KEYS: dict[str, Mount] = {"T_base_cam": "eye_to_hand", "T_flange_cam": "eye_in_hand"}

#: A calibrated rotation block must satisfy |R^T R - I| <= this. Calibration tools write 6-9 significant
#: digits, so an honest rotation is orthonormal to ~1e-6; 1e-4 (a 0.006 deg shear) still admits hand-copied
#: matrices rounded to 4-5 digits and refuses anything that is not a rotation (a scale, a shear, a typo).
CALIBRATION_ROTATION_ATOL = 1e-4

#: A camera more than this far from the base or flange [m] is almost surely in millimetres.
MAX_CALIBRATION_TRANSLATION_M = 5.0


@dataclass(frozen=True)
class HandEyeCalibration:
    """A camera's pose on the cell.

    Attributes:
        mount: "eye_to_hand" (T is T_base_cam, the camera is fixed) or "eye_in_hand" (T is T_flange_cam).
        T: (4, 4) float64 rigid transform [m].
        source: where it was read from (for messages).
    """

    mount: Mount
    T: np.ndarray
    source: str = "<memory>"

    def __post_init__(self) -> None:
        if self.mount not in ("eye_to_hand", "eye_in_hand"):
            raise CalibrationError(f"mount must be 'eye_to_hand' or 'eye_in_hand', got {self.mount!r}")
        name = "T_base_cam" if self.mount == "eye_to_hand" else "T_flange_cam"
        object.__setattr__(self, "T", check_rigid(self.T, name, self.source))

    @property
    def key(self) -> str:
        return "T_base_cam" if self.mount == "eye_to_hand" else "T_flange_cam"

    def T_base_cam(self, T_base_flange: Callable[[], np.ndarray] | None = None) -> np.ndarray:
        """(4, 4) T_base_cam now; a wrist camera needs the current flange pose (`T_base_flange()`)."""
        if self.mount == "eye_to_hand":
            return self.T.copy()
        if T_base_flange is None:
            raise CalibrationError(
                f"{self.source}: a wrist camera (T_flange_cam) needs the arm's flange pose"
            )
        return np.asarray(T_base_flange(), dtype=np.float64) @ self.T


def check_rigid(T: ArrayLike, name: str, source: str = "<memory>") -> np.ndarray:
    """Validate a calibrated rigid transform (4, 4); re-orthonormalises the rotation (a rounding fix only).

    Raises `CalibrationError` naming what is wrong: shape, NaN, last row, a non-rotation (with the
    orthonormality error and determinant), or a translation that looks like millimetres.
    """
    try:
        A = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(f"{source}: {name} must be a 4x4 matrix of numbers") from None
    if A.shape != (4, 4):
        raise CalibrationError(f"{source}: {name} must be a 4x4 matrix (4 rows of 4), got shape {A.shape}")
    if not np.all(np.isfinite(A)):
        raise CalibrationError(f"{source}: {name} holds NaN or inf")
    if not np.allclose(A[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise CalibrationError(f"{source}: {name} must end with the row [0, 0, 0, 1], got {A[3].tolist()}")
    R = A[:3, :3]
    ortho = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if ortho > CALIBRATION_ROTATION_ATOL or det < 0:
        raise CalibrationError(
            f"{source}: {name}[:3, :3] is not a rotation (max |R^T R - I| = {ortho:.3g}, det = {det:.6g}; "
            f"needs <= {CALIBRATION_ROTATION_ATOL:g} and det = +1): a rigid transform has no scale, shear or "
            "mirror"
        )
    t = A[:3, 3]
    if float(np.linalg.norm(t)) > MAX_CALIBRATION_TRANSLATION_M:
        raise CalibrationError(
            f"{source}: {name} translation {t.tolist()} is {np.linalg.norm(t):.1f} m long; "
            f"calibrations are in metres (over {MAX_CALIBRATION_TRANSLATION_M:g} m usually means millimetres)"
        )
    U, _, Vt = np.linalg.svd(R)
    out = A.copy()
    out[:3, :3] = U @ Vt
    return out


def read_cell_file(path: str | Path, what: str, error: type[InvalidInputError] = InvalidInputError) -> Any:
    """The parsed content of a cell file (YAML, or JSON by its suffix); a missing or unparsable file raises
    `error` naming the file ("<path>: no such <what>")."""
    p = Path(path)
    if not p.is_file():
        raise error(f"{p}: no such {what}")
    text = p.read_text()
    try:
        return json.loads(text) if p.suffix.lower() == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        raise error(f"{p}: not valid {'JSON' if p.suffix.lower() == '.json' else 'YAML'}: {exc}") from None


def load_calibration(path: str | Path) -> HandEyeCalibration:
    """Read a hand-eye calibration file (YAML or JSON; see the module docstring)."""
    p = Path(path)
    what = "calibration file (a YAML/JSON file with T_base_cam or T_flange_cam)"
    doc = read_cell_file(p, what, CalibrationError)
    if not isinstance(doc, dict):
        raise CalibrationError(
            f"{p}: expected a mapping with T_base_cam or T_flange_cam, got {type(doc).__name__}"
        )
    present = [k for k in _KEYS if k in doc]
    if len(present) != 1:
        raise CalibrationError(
            f"{p}: needs exactly one of T_base_cam (fixed camera) or T_flange_cam (wrist camera); "
            f"found {present or 'neither'} among keys {sorted(doc)}"
        )
    key = present[0]
    try:
        return HandEyeCalibration(_KEYS[key], doc[key], source=str(p))
    except InvalidInputError:
        raise
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{p}: {key}: {exc}") from None
