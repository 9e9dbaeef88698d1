"""Place-target files: the fixtures of a real cell that place commands name ("in the bin", "on the pallet").

A YAML or JSON file maps each fixture kind the command parser knows (`pipeline.command.PLACE_TARGETS`: bin,
table, pallet, conveyor) to where its standing surface is in the robot's `base` frame, in metres:

```yaml
place_targets:
  bin:      {kind: bin, pos_m: [0.45, -0.30, 0.02], rpy_deg: [0, 0, 0],
             half_extents_m: [0.15, 0.10], wall_height_m: 0.12}      # the bin's floor, z up
  conveyor: {kind: surface, pos_m: [0.0, -0.55, 0.05], rpy_deg: [0, 0, 90], half_extents_m: [1.0, 0.25]}
  pallet:   {kind: pallet, T_base_surface: [[1, 0, 0, 0.0], [0, 1, 0, 0.65], [0, 0, 1, -0.55], [0, 0, 0, 1]],
             half_extents_m: [0.6, 0.4],
             pattern: {rows: 2, cols: 2, layers: 1, gap_m: 0.02, interlock: false}}
```

Each entry gives its pose either as `pos_m` + `rpy_deg` (extrinsic x-y-z roll, pitch, yaw in degrees, as
URDF) or as a 4x4 `T_base_surface`; the frame sits at the centre of the standing surface with z along its
upward normal. `load_place_targets` refuses unknown fixture names and keys, non-rigid poses, surfaces whose z
axis points down, and lengths that look like millimetres, and says what is wrong: a wrong place target is
where the arm will put an object down.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.grasp.place import PLACE_KINDS, PalletPattern, PlaceTarget
from prompose_grasp.hardware.calibration import check_rigid, read_cell_file
from prompose_grasp.pipeline.command import PLACE_TARGETS

__all__ = ["load_place_targets"]

_ENTRY_KEYS = ("kind", "pos_m", "rpy_deg", "T_base_surface", "half_extents_m", "wall_height_m", "pattern")
_PATTERN_KEYS = ("rows", "cols", "layers", "gap_m", "interlock")

#: A fixture's surface may tilt at most this far from level [deg]: an object put down on a steeper surface
#: slides off, and a larger tilt usually means a mistyped rpy.
MAX_SURFACE_TILT_DEG = 15.0

#: No fixture of a UR cell is larger than this across or further than this from the base [m]; more means
#: the file is in millimetres.
MAX_CELL_LENGTH_M = 5.0


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InvalidInputError(f"{where} must be a finite number, got {value!r}")
    return float(value)


def _vector(value: Any, n: int, where: str) -> np.ndarray:
    if not isinstance(value, list | tuple) or len(value) != n:
        raise InvalidInputError(f"{where} must be a list of {n} numbers, got {value!r}")
    return np.array([_number(v, f"{where}[{i}]") for i, v in enumerate(value)])


def _pose(entry: Mapping[str, Any], where: str, source: str) -> np.ndarray:
    has_T = "T_base_surface" in entry
    has_pos = "pos_m" in entry or "rpy_deg" in entry
    if has_T == has_pos:
        raise InvalidInputError(
            f"{where}: give the pose either as pos_m + rpy_deg or as T_base_surface (found "
            f"{[k for k in ('pos_m', 'rpy_deg', 'T_base_surface') if k in entry] or 'neither'})"
        )
    if has_T:
        try:
            T = np.asarray(entry["T_base_surface"], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"{where}.T_base_surface: {exc}") from None
        # Same rigid-transform checks (and millimetre guard) as a hand-eye calibration.
        T = check_rigid(T, f"{where}.T_base_surface", source)
    else:
        if "pos_m" not in entry:
            raise InvalidInputError(f"{where}: rpy_deg without pos_m")
        T = np.eye(4)
        T[:3, 3] = _vector(entry["pos_m"], 3, f"{where}.pos_m")
        rpy = _vector(entry.get("rpy_deg", [0.0, 0.0, 0.0]), 3, f"{where}.rpy_deg")
        T[:3, :3] = Rotation.from_euler("xyz", rpy, degrees=True).as_matrix()
        if float(np.linalg.norm(T[:3, 3])) > MAX_CELL_LENGTH_M:
            raise InvalidInputError(
                f"{where}.pos_m {T[:3, 3].tolist()} is {np.linalg.norm(T[:3, 3]):.1f} m from the base; "
                f"place targets are in metres (over {MAX_CELL_LENGTH_M:g} m usually means millimetres)"
            )
    tilt = math.degrees(math.acos(float(np.clip(T[2, 2], -1.0, 1.0))))
    if tilt > MAX_SURFACE_TILT_DEG:
        raise InvalidInputError(
            f"{where}: the surface's z axis (its upward normal) is {tilt:.1f} deg from the base's z; at most "
            f"{MAX_SURFACE_TILT_DEG:g} deg is accepted (z must point up, out of the surface)"
        )
    return T


def _entry(name: str, entry: Any, source: str) -> PlaceTarget:
    where = f"{source}: place_targets.{name}"
    if not isinstance(entry, Mapping):
        raise InvalidInputError(f"{where} must be a mapping, got {type(entry).__name__}")
    unknown = sorted(set(entry) - set(_ENTRY_KEYS))
    if unknown:
        raise InvalidInputError(f"{where}: unknown keys {unknown}; known: {', '.join(_ENTRY_KEYS)}")
    half = _vector(entry.get("half_extents_m"), 2, f"{where}.half_extents_m")
    if np.any(half > MAX_CELL_LENGTH_M):
        raise InvalidInputError(
            f"{where}.half_extents_m {half.tolist()} exceeds {MAX_CELL_LENGTH_M:g} m: is it in millimetres?"
        )
    pattern = None
    if "pattern" in entry:
        p = entry["pattern"]
        if not isinstance(p, Mapping) or set(p) - set(_PATTERN_KEYS):
            raise InvalidInputError(
                f"{where}.pattern must be a mapping with keys among {_PATTERN_KEYS}, got {p!r}"
            )
        counts: dict[str, int] = {}
        for key in ("rows", "cols", "layers"):
            if key in p and (isinstance(p[key], bool) or not isinstance(p[key], int)):
                raise InvalidInputError(f"{where}.pattern.{key} must be an integer, got {p[key]!r}")
            if key in p:
                counts[key] = p[key]
        default = PalletPattern()
        pattern = PalletPattern(
            rows=counts.get("rows", default.rows),
            cols=counts.get("cols", default.cols),
            layers=counts.get("layers", default.layers),
            gap_m=_number(p["gap_m"], f"{where}.pattern.gap_m") if "gap_m" in p else default.gap_m,
            interlock=bool(p["interlock"]) if "interlock" in p else default.interlock,
        )
    kind = entry.get("kind")
    if pattern is not None and kind != "pallet":
        raise InvalidInputError(f"{where}: a pattern is for kind: pallet, not {kind!r}")
    if not isinstance(kind, str):
        raise InvalidInputError(f"{where}.kind must be one of {', '.join(PLACE_KINDS)}, got {kind!r}")
    return PlaceTarget(
        kind,
        _pose(entry, where, source),
        half,
        wall_height_m=_number(entry.get("wall_height_m", 0.0), f"{where}.wall_height_m"),
        pattern=pattern,
    )


def load_place_targets(path: str | Path) -> dict[str, PlaceTarget]:
    """Read a place-target file (YAML or JSON; see the module docstring) -> {fixture name: PlaceTarget}."""
    p = Path(path)
    doc = read_cell_file(p, "place-target file (a YAML/JSON file with place_targets: ...)")
    if (
        not isinstance(doc, Mapping)
        or not isinstance(doc.get("place_targets"), Mapping)
        or not doc["place_targets"]
    ):
        raise InvalidInputError(f"{p}: expected a mapping with a non-empty 'place_targets:' mapping")
    targets = {}
    for name, entry in doc["place_targets"].items():
        if name not in PLACE_TARGETS:
            raise InvalidInputError(
                f"{p}: place target {name!r} is not a fixture a command can name; use one of "
                f"{', '.join(PLACE_TARGETS)} (e.g. 'put the red mug in the bin' -> bin)"
            )
        targets[name] = _entry(name, entry, str(p))
    return targets
