"""Scenario files (YAML or JSON): parse and validate into a `SceneSpec`, then build a `SimWorld`.

The format is DESIGN.md's "Sim scene file"; docs/sim.md documents every key. In short::

    version: 1
    name: tabletop_household
    seed: 0                                   # random placements and appearances
    robot: {model: ur5e, base_pose: {pos: [0, -0.55, 0.75], rpy_deg: [0, 0, -90]}}   # UR base frame
    gripper: {type: parallel_jaw}                                # parallel_jaw | suction
    supports:
      - {name: table, type: table, size_m: [1.2, 0.8], height_m: 0.75}
      - {name: bin, type: bin, on_top_of: table, at_m: [0.3, 0.2], inner_size_m: [0.4, 0.3],
         wall_height_m: 0.12}
    cameras:
      - {name: front, pose: {pos: [0, -1, 1.5], look_at: [0, 0, 0.75]}, width: 640, height: 480,
         fovy_deg: 58, noise: realsense}
      - {name: wrist, mount: {body: flange, pose: {pos: [0, 0.08, 0.03]}},
         stand_in_pose: {pos: [0, -0.2, 1.2], look_at: [0, 0, 0.75]}, width: 320, height: 240, fovy_deg: 70}
    objects:
      - name: mug
        prompt: red mug
        mesh: {family: mug, params: {radius_m: 0.04}}  # or a path, or {path, up_axis, category, collision}
        scale: [1, 1, 1]
        rgba: [0.8, 0.1, 0.1, 1]                                  # or texture: checker | file.png | random
        place: {support: table, region: {centre_m: [0, 0], half_extents_m: [0.3, 0.2]}}  # or pose: {...}
    place_targets:
      - {name: bin, support: bin}

Relative paths (meshes, textures) are relative to the scene file. Unknown keys, families, support types, noise
models, robots and grippers raise `UnknownNameError` listing the accepted names.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.geometry.se3 import R_from_quat_wxyz, make_T, random_rotation
from sim.appearance import BUILTIN_TEXTURES, Appearance, random_appearance
from sim.camera import CameraSpec, look_at
from sim.noise import NOISE_PRESETS
from sim.objects import FAMILIES, SYMMETRIES, ObjectAsset, load_mesh_object, make_object
from sim.placement import sample_upright_placements
from sim.robot_scene import add_robot
from sim.scene_builder import SceneBuilder
from sim.world import SimWorld, Support

__all__ = [
    "GRIPPER_TYPES",
    "ROBOT_MODELS",
    "SceneSpec",
    "build_scene",
    "load_scene",
    "load_world",
    "parse_pose",
    "parse_scene",
]

log = logging.getLogger(__name__)

#: Robot models a scene may name (the UR family); built by `sim.robot_scene.add_robot`.
ROBOT_MODELS = ("ur3e", "ur5e", "ur10e", "ur16e", "ur5")
#: Gripper types a scene may name.
GRIPPER_TYPES = ("parallel_jaw", "suction")
SUPPORT_TYPES = ("table", "bin", "conveyor", "pallet")
SCENE_VERSION = 1

_TOP_KEYS = (
    "version", "name", "seed", "timestep_s", "robot", "gripper", "supports", "support", "cameras",
    "objects", "place_targets", "lights", "headlight", "floor", "settle", "pipeline",
)  # fmt: skip
_SUPPORT_KEYS = {
    "table": ("name", "type", "pose", "on_top_of", "at_m", "yaw_deg", "size_m", "height_m", "appearance"),
    "bin": (
        "name",
        "type",
        "pose",
        "on_top_of",
        "at_m",
        "yaw_deg",
        "inner_size_m",
        "wall_height_m",
        "wall_m",
        "appearance",
    ),
    "conveyor": (
        "name",
        "type",
        "pose",
        "on_top_of",
        "at_m",
        "yaw_deg",
        "length_m",
        "width_m",
        "height_m",
        "appearance",
    ),
    "pallet": ("name", "type", "pose", "on_top_of", "at_m", "yaw_deg", "appearance"),
}
_CAMERA_KEYS = ("name", "pose", "mount", "stand_in_pose", "width", "height", "fovy_deg", "noise")
_OBJECT_KEYS = (
    "name", "prompt", "mesh", "scale", "rgba", "texture", "appearance", "pose", "place", "stack", "count",
    "fixed", "density_kg_m3",
)  # fmt: skip
_PLACE_KEYS = ("support", "region", "orientation", "margin_m")
_STACK_KEYS = ("support", "rows", "cols", "layers", "gap_m", "at_m", "jitter_m", "yaw_jitter_deg")
_PATTERN_KEYS = ("rows", "cols", "layers", "gap_m")
_POSE_KEYS = ("pos", "rpy_deg", "quat_wxyz", "look_at")


@dataclass(frozen=True)
class SceneSpec:
    """A parsed, validated scene file. `raw` keeps the document; `base_dir` resolves relative paths."""

    name: str
    seed: int
    raw: Mapping[str, Any]
    base_dir: Path
    robot: Mapping[str, Any] | None = None
    gripper: Mapping[str, Any] | None = None
    supports: tuple[Mapping[str, Any], ...] = ()
    cameras: tuple[Mapping[str, Any], ...] = ()
    objects: tuple[Mapping[str, Any], ...] = ()
    place_targets: tuple[Mapping[str, Any], ...] = ()
    timestep_s: float = 0.002
    settle: bool = True
    extras: Mapping[str, Any] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------------------
# parsing


def _check_keys(d: Any, allowed: tuple[str, ...], where: str) -> Mapping[str, Any]:
    if not isinstance(d, Mapping):
        raise InvalidInputError(f"{where} must be a mapping, got {type(d).__name__}")
    for key in d:
        if key not in allowed:
            raise UnknownNameError(f"key in {where}", key, allowed)
    return d


def _vec(x: Any, n: int, where: str) -> np.ndarray:
    if isinstance(x, str | bytes | Mapping):
        raise InvalidInputError(f"{where} must be {n} finite numbers, got {x!r:.60}")
    try:
        a = np.asarray(x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{where} must be {n} finite numbers, got {x!r:.60}") from None
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{where} must be {n} finite numbers, got {x!r:.60}")
    return a


def _is_number(v: Any) -> bool:
    """A finite real number (Python or numpy), not a bool."""
    return isinstance(v, numbers.Real) and not isinstance(v, bool | np.bool_) and math.isfinite(float(v))


def _scalar(
    d: Mapping[str, Any],
    key: str,
    where: str,
    minimum: float | None = None,
    strict: bool = False,
    maximum: float | None = None,
    integer: bool = False,
) -> None:
    """Check `d[key]`, when present: a finite number (an integer with `integer`), >= `minimum` (> with
    `strict`) and < `maximum`."""
    if key not in d:
        return
    v = d[key]
    ok = _is_number(v) and (not integer or float(v).is_integer())
    if ok and minimum is not None:
        ok = v > minimum if strict else v >= minimum
    if ok and maximum is not None:
        ok = v < maximum
    if not ok:
        kind = "integer" if integer else "number"
        bound = "" if minimum is None else f" {'>' if strict else '>='} {minimum:g}"
        bound += "" if maximum is None else f" and < {maximum:g}"
        raise InvalidInputError(f"{where}.{key} must be a finite {kind}{bound}, got {v!r:.60}")


def _vector(d: Mapping[str, Any], key: str, n: int, where: str, minimum: float | None = None) -> None:
    """Check `d[key]`, when present: `n` finite numbers, each > `minimum` when given."""
    if key in d:
        a = _vec(d[key], n, f"{where}.{key}")
        if minimum is not None and np.any(a <= minimum):
            raise InvalidInputError(f"{where}.{key} must be {n} numbers > {minimum:g}, got {d[key]!r:.60}")


def _flag(d: Mapping[str, Any], key: str, where: str) -> None:
    if key in d and not isinstance(d[key], bool):
        raise InvalidInputError(f"{where}.{key} must be true or false, got {d[key]!r:.60}")


def _text(d: Mapping[str, Any], key: str, where: str) -> None:
    if key in d and not isinstance(d[key], str):
        raise InvalidInputError(f"{where}.{key} must be a string, got {d[key]!r:.60}")


def _items(doc: Mapping[str, Any], key: str) -> list[Any]:
    """The list under `key` (absent or null: empty)."""
    value = doc.get(key)
    if value is None:
        return []
    if not isinstance(value, list | tuple):
        raise InvalidInputError(f"{key} must be a list, got {type(value).__name__}")
    return list(value)


def _named(value: Any, known: Any, kind: str) -> None:
    """Raise `UnknownNameError` unless `value` is a str among `known` (a dict's keys or a sequence)."""
    if not isinstance(value, str) or value not in known:
        raise UnknownNameError(kind, value, sorted(known) if isinstance(known, set | dict) else known)


def _check_appearance(a: Any, where: str) -> None:
    """A support's `appearance`: "random" or the keys of `sim.appearance.Appearance`."""
    if a == "random":
        return
    keys = tuple(f.name for f in dataclasses.fields(Appearance))
    _check_keys(a, keys, where)
    try:
        Appearance(**a)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{where}: {exc}") from None


def _check_texture(texture: Any, base: Path, where: str) -> None:
    """An object's `texture`: null (none), a builtin name, or an image file (relative to the scene file)."""
    if texture is None:
        return
    if not isinstance(texture, str):
        raise InvalidInputError(f"{where} must be a builtin texture or an image file, got {texture!r:.60}")
    if texture not in BUILTIN_TEXTURES and not Path(_resolve(base, texture)).is_file():
        raise InvalidInputError(
            f"{where} {texture!r} is neither a builtin ({', '.join(BUILTIN_TEXTURES)}) nor an image file"
        )


def _rpy_R(rpy_deg: np.ndarray) -> np.ndarray:
    """Rotation of fixed-axis roll, pitch, yaw [deg]: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = np.radians(rpy_deg)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def parse_pose(d: Any, where: str, allow_look_at: bool = False) -> np.ndarray:
    """(4, 4) transform from {pos, rpy_deg | quat_wxyz | look_at (cameras: OpenCV frame)}; metres, degrees."""
    _check_keys(d, _POSE_KEYS if allow_look_at else _POSE_KEYS[:3], where)
    pos = _vec(d.get("pos", (0.0, 0.0, 0.0)), 3, f"{where}.pos")
    given = [k for k in ("rpy_deg", "quat_wxyz", "look_at") if k in d]
    if len(given) > 1:
        raise InvalidInputError(f"{where}: give one of rpy_deg, quat_wxyz, look_at, not {given}")
    if "look_at" in d:
        return look_at(pos, _vec(d["look_at"], 3, f"{where}.look_at"))
    if "quat_wxyz" in d:
        q = _vec(d["quat_wxyz"], 4, f"{where}.quat_wxyz")
        if np.linalg.norm(q) < 1e-9:
            raise InvalidInputError(f"{where}.quat_wxyz must not be zero")
        return make_T(R_from_quat_wxyz(q), pos)
    return make_T(_rpy_R(_vec(d.get("rpy_deg", (0.0, 0.0, 0.0)), 3, f"{where}.rpy_deg")), pos)


def _parse_mesh(d: Any, where: str, base: Path | None = None) -> Mapping[str, Any]:
    """Check an object's `mesh`; with `base` (the scene file's folder), a mesh path must name a file."""
    if isinstance(d, str):
        d = {"path": d}
    _check_keys(d, ("family", "params", "path", "up_axis", "category", "symmetry", "collision"), where)
    if ("family" in d) == ("path" in d):
        raise InvalidInputError(f"{where} needs exactly one of 'family' or 'path'")
    if "family" in d:
        _named(d["family"], FAMILIES, "object family")
        params = d.get("params", {}) or {}
        known = FAMILIES[d["family"]].ranges
        if not isinstance(params, Mapping):
            raise InvalidInputError(f"{where}.params must be a mapping, got {type(params).__name__}")
        for key, value in params.items():
            if key not in known:
                raise UnknownNameError(f"parameter of family {d['family']!r} in {where}", key, sorted(known))
            if isinstance(value, list | tuple):  # [lo, hi]: drawn per seed
                lo, hi = _vec(value, 2, f"{where}.params.{key}")
                if not lo <= hi:
                    raise InvalidInputError(f"{where}.params.{key}: a range [lo, hi] needs lo <= hi")
            else:
                _scalar(params, key, f"{where}.params")
    else:
        _text(d, "path", where)
        if base is not None and not Path(_resolve(base, d["path"])).is_file():
            raise InvalidInputError(f"{where}.path {d['path']!r}: no such mesh file (relative to {base})")
    for key in ("up_axis", "category", "collision"):
        _text(d, key, where)
    if "symmetry" in d:
        _named(d["symmetry"], SYMMETRIES, "symmetry")
    return d


def parse_scene(doc: Mapping[str, Any], base_dir: str | Path = ".") -> SceneSpec:
    """Validate a scene document (already loaded from YAML/JSON) into a `SceneSpec`.

    Every key is checked here, before anything is built: names against the known choices, numbers for
    type, finiteness and sign, vectors for length, mesh and texture files for existence (relative to
    `base_dir`), `pipeline` against `PickConfig`.

    Raises:
        InvalidInputError, UnknownNameError: the first thing wrong, named by its place in the document.
    """
    base = Path(base_dir)
    _check_keys(doc, _TOP_KEYS, "the scene")
    version = doc.get("version", SCENE_VERSION)
    if version != SCENE_VERSION or isinstance(version, bool):
        raise InvalidInputError(f"scene version {version!r} is not supported; this reader knows version 1")
    _scalar(doc, "seed", "the scene", minimum=0, integer=True)
    _scalar(doc, "timestep_s", "the scene", minimum=0.0, strict=True)
    for key in ("settle", "floor"):
        _flag(doc, key, "the scene")
    for i, light in enumerate(_items(doc, "lights")):
        where = f"lights[{i}]"
        _check_keys(light, ("pos", "dir", "diffuse", "castshadow"), where)
        if "pos" not in light:
            raise InvalidInputError(f"{where} needs a pos")
        _vector(light, "pos", 3, where)
        _vector(light, "dir", 3, where)
        if "diffuse" in light:  # one intensity, or (r, g, b)
            if _is_number(light["diffuse"]):
                _scalar(light, "diffuse", where, minimum=0.0)
            else:
                _vector(light, "diffuse", 3, where)
        _flag(light, "castshadow", where)
    if doc.get("headlight") is not None:
        h = _check_keys(doc["headlight"], ("ambient", "diffuse"), "headlight")
        for key in ("ambient", "diffuse"):
            _scalar(h, key, "headlight", minimum=0.0)
    if doc.get("pipeline") is not None:
        _check_pipeline(doc["pipeline"])
    robot = doc.get("robot")
    if robot is not None:
        _check_keys(robot, ("model", "base_pose", "home_q_rad"), "robot")
        if robot.get("model") not in ROBOT_MODELS:
            raise UnknownNameError("robot", robot.get("model"), ROBOT_MODELS)
        if "base_pose" in robot:
            parse_pose(robot["base_pose"], "robot.base_pose")
        if "home_q_rad" in robot:
            _vec(robot["home_q_rad"], 6, "robot.home_q_rad")
    gripper = doc.get("gripper")
    if gripper is not None:
        _check_keys(gripper, ("type",), "gripper")
        if gripper.get("type") not in GRIPPER_TYPES:
            raise UnknownNameError("gripper", gripper.get("type"), GRIPPER_TYPES)
        if robot is None:
            raise InvalidInputError("a gripper needs a robot: add `robot: {model: ...}` to the scene")

    supports = _items(doc, "supports")
    if "support" in doc:
        supports.insert(0, doc["support"])
    names: set[str] = set()
    for i, s in enumerate(supports):
        where = f"supports[{i}]"
        if not isinstance(s, Mapping) or s.get("type") not in SUPPORT_TYPES:
            raise UnknownNameError(
                f"support type in {where}", getattr(s, "get", dict().get)("type"), SUPPORT_TYPES
            )
        _check_keys(s, _SUPPORT_KEYS[s["type"]], where)
        _text(s, "name", where)
        if "pose" in s:
            parse_pose(s["pose"], f"{where}.pose")
        if "on_top_of" in s:
            _named(s["on_top_of"], names, f"support named in {where}.on_top_of (declare it first)")
        _vector(s, "at_m", 2, where)
        _scalar(s, "yaw_deg", where)
        for key in ("size_m", "inner_size_m"):
            _vector(s, key, 2, where, minimum=0.0)
        for key in ("height_m", "wall_height_m", "wall_m", "length_m", "width_m"):
            _scalar(s, key, where, minimum=0.0, strict=True)
        if "appearance" in s:
            _check_appearance(s["appearance"], f"{where}.appearance")
        names.add(s.get("name", s["type"]))

    cameras = _items(doc, "cameras")
    for i, c in enumerate(cameras):
        where = f"cameras[{i}]"
        _check_keys(c, _CAMERA_KEYS, where)
        if "name" not in c:
            raise InvalidInputError(f"{where} needs a name")
        _text(c, "name", where)
        if ("pose" in c) == ("mount" in c):
            raise InvalidInputError(f"{where} needs exactly one of 'pose' (fixed) or 'mount' (wrist)")
        if "pose" in c:
            parse_pose(c["pose"], f"{where}.pose", allow_look_at=True)
        else:
            _check_keys(c["mount"], ("body", "pose"), f"{where}.mount")
            _text(c["mount"], "body", f"{where}.mount")
            parse_pose(c["mount"].get("pose", {}), f"{where}.mount.pose", allow_look_at=True)
            if "stand_in_pose" in c:
                parse_pose(c["stand_in_pose"], f"{where}.stand_in_pose", allow_look_at=True)
        for key in ("width", "height"):
            _scalar(c, key, where, minimum=1, integer=True)
        _scalar(c, "fovy_deg", where, minimum=0.0, strict=True, maximum=180.0)
        if "noise" in c:
            _named(c["noise"], NOISE_PRESETS, "noise model")

    objects = _items(doc, "objects")
    for i, o in enumerate(objects):
        where = f"objects[{i}]"
        _check_keys(o, _OBJECT_KEYS, where)
        if "name" not in o or "mesh" not in o:
            raise InvalidInputError(f"{where} needs a name and a mesh")
        for key in ("name", "prompt"):
            _text(o, key, where)
        _parse_mesh(o["mesh"], f"{where}.mesh", base)
        placements = [k for k in ("pose", "place", "stack") if k in o]
        if len(placements) != 1:
            raise InvalidInputError(f"{where} needs exactly one of pose, place, stack; got {placements}")
        if "pose" in o:
            parse_pose(o["pose"], f"{where}.pose")
        if "place" in o:
            place = _check_keys(o["place"], _PLACE_KEYS, f"{where}.place")
            _named(place.get("support"), names, f"support in {where}.place")
            orientation = place.get("orientation", "upright")
            if not isinstance(orientation, str) or orientation not in ("upright", "random"):
                raise UnknownNameError("orientation", orientation, ("upright", "random"))
            _scalar(place, "margin_m", f"{where}.place", minimum=0.0)
            if place.get("region") is not None:
                region = _check_keys(place["region"], ("centre_m", "half_extents_m"), f"{where}.place.region")
                _vector(region, "centre_m", 2, f"{where}.place.region")
                _vector(region, "half_extents_m", 2, f"{where}.place.region", minimum=0.0)
        if "stack" in o:
            stack = _check_keys(o["stack"], _STACK_KEYS, f"{where}.stack")
            _named(stack.get("support"), names, f"support in {where}.stack")
            for key in ("rows", "cols", "layers"):
                _scalar(stack, key, f"{where}.stack", minimum=1, integer=True)
            for key in ("gap_m", "jitter_m", "yaw_jitter_deg"):
                _scalar(stack, key, f"{where}.stack", minimum=0.0)
            _vector(stack, "at_m", 2, f"{where}.stack")
        if "rgba" in o:
            Appearance(rgba=tuple(_vec(o["rgba"], 4, f"{where}.rgba")))
        if "texture" in o:
            _check_texture(o["texture"], base, f"{where}.texture")
        if o.get("appearance", "random") != "random":
            raise UnknownNameError(f"appearance in {where}", o["appearance"], ("random",))
        if "scale" in o:
            scale = o["scale"]
            if _is_number(scale):
                scale = [scale] * 3
            _vector({"scale": scale}, "scale", 3, where, minimum=0.0)
        _scalar(o, "count", where, minimum=1, integer=True)
        _scalar(o, "density_kg_m3", where, minimum=0.0, strict=True)
        _flag(o, "fixed", where)

    place_targets = _items(doc, "place_targets")
    for i, p in enumerate(place_targets):
        where = f"place_targets[{i}]"
        _check_keys(p, ("name", "support", "pattern"), where)
        if "name" not in p:
            raise InvalidInputError(f"{where} needs a name")
        _text(p, "name", where)
        if "pattern" in p:
            pattern = _check_keys(p["pattern"], _PATTERN_KEYS, f"{where}.pattern")
            for key in ("rows", "cols", "layers"):
                _scalar(pattern, key, f"{where}.pattern", minimum=1, integer=True)
            _scalar(pattern, "gap_m", f"{where}.pattern", minimum=0.0)
        _named(p.get("support"), names, f"support in {where}")

    return SceneSpec(
        name=str(doc.get("name", "scene")),
        seed=int(doc.get("seed", 0)),
        raw=doc,
        base_dir=base,
        robot=robot,
        gripper=gripper,
        supports=tuple(supports),
        cameras=tuple(cameras),
        objects=tuple(objects),
        place_targets=tuple(place_targets),
        timestep_s=float(doc.get("timestep_s", 0.002)),
        settle=bool(doc.get("settle", True)),
        extras={k: doc[k] for k in ("lights", "headlight", "floor", "pipeline") if k in doc},
    )


def _check_pipeline(settings: Any) -> None:
    """The scene's `pipeline` settings: `PickConfig` keyword arguments that make a valid `PickConfig`."""
    from prompose_grasp.pipeline.pick_and_place import PickConfig

    keys = tuple(f.name for f in dataclasses.fields(PickConfig) if f.name != "grasp")
    _check_keys(settings, keys, "pipeline")
    for key, value in settings.items():
        if isinstance(value, list | tuple | Mapping):
            raise InvalidInputError(f"pipeline.{key} must be a number, a string, true/false or null")
    try:
        PickConfig(**settings)
    except (TypeError, ValueError) as exc:  # PickConfig converts with int() / float()
        raise InvalidInputError(f"pipeline: {exc}") from None


def load_scene(path: str | Path) -> SceneSpec:
    """Read a YAML (.yaml/.yml) or JSON (.json) scene file and validate it (`parse_scene`).

    Raises:
        InvalidInputError: the file is missing, not UTF-8 text, not valid YAML / JSON (the message gives the
            line), or its document is not a valid scene. UnknownNameError: an unknown extension or name.
    """
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(f"scene file {str(p)!r} does not exist")
    suffix = p.suffix.lower()
    if suffix not in (".yaml", ".yml", ".json"):
        raise UnknownNameError("scene file extension", p.suffix, (".yaml", ".yml", ".json"))
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInputError(f"scene file {str(p)!r} cannot be read as UTF-8 text: {exc}") from None
    if suffix == ".json":
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InvalidInputError(f"scene file {str(p)!r} is not valid JSON: {exc}") from None
    else:
        import yaml

        try:
            doc = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            where = getattr(exc, "problem_mark", None)
            at = f" at line {where.line + 1}, column {where.column + 1}" if where is not None else ""
            problem = getattr(exc, "problem", None) or type(exc).__name__
            raise InvalidInputError(f"scene file {str(p)!r} is not valid YAML{at}: {problem}") from None
    return parse_scene(doc, base_dir=p.parent)


# ------------------------------------------------------------------------------------------------------------
# building


def _resolve(base: Path, path: str) -> str:
    p = Path(path).expanduser()
    return str(p if p.is_absolute() else (base / p))


def _asset(o: Mapping[str, Any], base: Path, rng: np.random.Generator) -> ObjectAsset:
    mesh = _parse_mesh(o["mesh"], "mesh")
    scale = np.broadcast_to(np.asarray(o.get("scale", 1.0), dtype=np.float64), (3,))
    if "family" in mesh:
        params = {
            k: (rng.uniform(float(v[0]), float(v[1])) if isinstance(v, list | tuple) else v)
            for k, v in (mesh.get("params") or {}).items()
        }
        asset = make_object(mesh["family"], params, rng=rng)
        if np.allclose(scale, 1.0):
            return asset
        parts = [m.copy() for m in asset.parts]
        cols = [m.copy() for m in asset.collision]
        for m in (*parts, *cols):
            m.vertices = m.vertices * scale
        return ObjectAsset(
            asset.category,
            tuple(parts),
            tuple(cols),
            asset.size * scale,
            asset.symmetry,
            asset.params,
            asset.source,
        )
    return load_mesh_object(
        _resolve(base, mesh["path"]),
        scale=scale,
        up_axis=mesh.get("up_axis", "y"),
        category=mesh.get("category"),
        symmetry=mesh.get("symmetry", "none"),
        collision=mesh.get("collision", "hull"),
    )


def _appearance(o: Mapping[str, Any], base: Path, rng: np.random.Generator) -> Appearance:
    if "rgba" in o or "texture" in o:
        texture = o.get("texture")
        if texture is not None and texture not in ("checker", "gradient", "flat", "noise"):
            texture = _resolve(base, texture)
        rgba = tuple(float(x) for x in o.get("rgba", (0.8, 0.8, 0.8, 1.0)))
        return Appearance(rgba=rgba, texture=texture)  # type: ignore[arg-type]
    return random_appearance(rng)


def _support_base(s: Mapping[str, Any], built: Mapping[str, Support]) -> np.ndarray:
    if "pose" in s:
        return parse_pose(s["pose"], "support.pose")
    yaw = math.radians(float(s.get("yaw_deg", 0.0)))
    at = _vec(s.get("at_m", (0.0, 0.0)), 2, "support.at_m")
    local = make_T(_rpy_R(np.array([0.0, 0.0, math.degrees(yaw)])), [at[0], at[1], 0.0])
    if "on_top_of" in s:
        return built[s["on_top_of"]].T_world_surface @ local
    return local


def build_scene(spec: SceneSpec, seed: int | None = None, settle: bool | None = None) -> SimWorld:
    """Build and compile the scene; random placements and appearances draw from `seed` (default: the file's).

    Objects placed with `place`/`stack` start just above their support; with `settle` (default: the file's,
    true) the physics runs until they rest, so ground truth is taken of a resting scene.
    """
    rng = np.random.default_rng(spec.seed if seed is None else seed)
    b = SceneBuilder(spec.name, timestep_s=spec.timestep_s)
    floor = spec.extras.get("floor", True)
    if floor:
        b.add_floor()
        b.add_skybox()
    for light in spec.extras.get("lights", None) or [
        {"pos": [0.6, -0.8, 2.6], "dir": [-0.2, 0.3, -1.0], "diffuse": 0.55},
        {"pos": [-0.8, 0.6, 2.4], "dir": [0.3, -0.2, -1.0], "diffuse": 0.3, "castshadow": False},
    ]:
        _check_keys(light, ("pos", "dir", "diffuse", "castshadow"), "lights[]")
        b.add_light(
            light["pos"],
            light.get("dir", (0, 0, -1)),
            light.get("diffuse", 0.6),
            castshadow=light.get("castshadow", True),
        )
    if "headlight" in spec.extras:
        h = _check_keys(spec.extras["headlight"], ("ambient", "diffuse"), "headlight")
        b.set_headlight(float(h.get("ambient", 0.25)), float(h.get("diffuse", 0.35)))

    supports: dict[str, Support] = {}
    for s in spec.supports:
        kind, name = s["type"], s.get("name", s["type"])
        T = _support_base(s, supports)
        app = None
        if "appearance" in s:
            a = s["appearance"]
            app = random_appearance(rng, kind="table") if a == "random" else Appearance(**a)
        if kind == "table":
            size = s.get("size_m", (1.2, 0.8))
            supports[name] = b.add_table(name, tuple(size), float(s.get("height_m", 0.75)), T, appearance=app)
        elif kind == "bin":
            supports[name] = b.add_bin(
                name, tuple(s.get("inner_size_m", (0.4, 0.3))), float(s.get("wall_height_m", 0.15)),
                float(s.get("wall_m", 0.01)), T, appearance=app,
            )  # fmt: skip
        elif kind == "conveyor":
            supports[name] = b.add_conveyor(
                name,
                float(s.get("length_m", 2.0)),
                float(s.get("width_m", 0.5)),
                float(s.get("height_m", 0.8)),
                T,
                appearance=app,
            )
        else:
            supports[name] = b.add_pallet(name, T, appearance=app)

    # Objects: explicit poses, stacks, then random placements grouped per support so they never overlap.
    groups: dict[tuple[str, str], list[tuple[str, ObjectAsset, Mapping[str, Any]]]] = {}
    drops: list[tuple[str, ObjectAsset, Mapping[str, Any]]] = []

    def place(name: str, asset: ObjectAsset, o: Mapping[str, Any], T_world_obj: np.ndarray) -> None:
        b.add_object(
            asset,
            name,
            T_world_obj,
            o.get("prompt"),
            _appearance(o, spec.base_dir, rng),
            bool(o.get("fixed", False)),
        )

    for o in spec.objects:
        count = int(o.get("count", 1))
        stack = o.get("stack")
        n = (
            count
            if stack is None
            else int(stack.get("rows", 1)) * int(stack.get("cols", 1)) * int(stack.get("layers", 1))
        )
        shared = _asset(o, spec.base_dir, rng) if stack is not None else None
        for k in range(n):
            name = o["name"] if n == 1 else f"{o['name']}_{k}"
            asset = shared if shared is not None else _asset(o, spec.base_dir, rng)
            if "pose" in o:
                place(name, asset, o, parse_pose(o["pose"], "object.pose"))
            elif stack is not None:
                place(name, asset, o, _stack_pose(asset, supports[stack["support"]], stack, k, rng))
            elif o["place"].get("orientation", "upright") == "random":
                drops.append((name, asset, o))
            else:
                key = (o["place"]["support"], json.dumps(o["place"].get("region"), sort_keys=True))
                groups.setdefault(key, []).append((name, asset, o))
    for (support_name, _), items in groups.items():
        region = items[0][2]["place"].get("region") or {}
        margin = float(items[0][2]["place"].get("margin_m", 0.01))
        poses = sample_upright_placements(
            [a for _, a, _ in items],
            supports[support_name],
            rng,
            margin_m=margin,
            region_half_extents_m=region.get("half_extents_m"),
            region_centre_m=region.get("centre_m", (0.0, 0.0)),
            clearance_m=0.001,
        )
        for (name, asset, o), T in zip(items, poses):
            place(name, asset, o, T)
    # Random orientations (bin clutter): bounding spheres packed low into the container, layer by layer, so
    # objects start close to their resting place and nothing is thrown out of the bin.
    spheres: dict[str, list[tuple[np.ndarray, float]]] = {}
    for name, asset, o in drops:
        sup = supports[o["place"]["support"]]
        region = o["place"].get("region") or {}
        half = np.asarray(region.get("half_extents_m", sup.half_extents_xy_m), dtype=np.float64)
        centre = np.asarray(region.get("centre_m", (0.0, 0.0)), dtype=np.float64)
        radius = 0.5 * float(np.linalg.norm(asset.size))
        lim = np.maximum(half - radius, 0.0)
        taken = spheres.setdefault(sup.name, [])
        z = radius + 0.002
        while True:
            candidates = [np.array([*(centre + rng.uniform(-lim, lim)), z]) for _ in range(30)]
            free = [
                c for c in candidates if all(np.linalg.norm(c - p) >= radius + rp + 0.002 for p, rp in taken)
            ]
            if free:
                break
            z += 0.5 * radius
        taken.append((free[0], radius))
        T_local = make_T(random_rotation(rng), free[0])
        b.add_object(
            asset, name, sup.T_world_surface @ T_local, o.get("prompt"), _appearance(o, spec.base_dir, rng)
        )

    if spec.robot is not None:  # before the cameras: a wrist camera mounts on the arm's flange
        add_robot(
            b,
            spec.robot["model"],
            parse_pose(spec.robot.get("base_pose", {}), "robot.base_pose"),
            gripper=(spec.gripper or {}).get("type"),
            home_q=spec.robot.get("home_q_rad"),
        )
    for c in spec.cameras:
        noise = NOISE_PRESETS[c.get("noise", "clean")]
        size = dict(
            width=int(c.get("width", 640)),
            height=int(c.get("height", 480)),
            fovy_deg=float(c.get("fovy_deg", 58.0)),
        )
        if "pose" in c:
            b.add_camera(
                CameraSpec(
                    c["name"], T_parent_cam=parse_pose(c["pose"], "camera.pose", True), noise=noise, **size
                )
            )
        else:
            body = c["mount"].get("body", "flange")
            if b.spec.body(body) is None:
                stand_in = parse_pose(c.get("stand_in_pose", {"pos": [0.0, 0.0, 1.2]}), "stand_in_pose", True)
                log.info(
                    "camera %r: body %r is not in the scene yet; a mocap stand-in carries it", c["name"], body
                )
                b.add_mount_body(body, stand_in)
            T_body_cam = parse_pose(c["mount"].get("pose", {}), "mount.pose", True)
            b.add_camera(
                CameraSpec(c["name"], T_parent_cam=T_body_cam, parent_body=body, noise=noise, **size)
            )
    for p in spec.place_targets:
        b.add_place_target(p["name"], supports[p["support"]])
    world = b.build()
    if spec.settle if settle is None else settle:
        world.settle()
    return world


def _stack_pose(
    asset: ObjectAsset,
    support: Support,
    stack: Mapping[str, Any],
    k: int,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Pose of the k-th box of a rows x cols x layers stack centred on `at_m` of the support (row-major,
    bottom up). With `jitter_m` / `yaw_jitter_deg` each box is shifted by up to that much along x and y and
    turned by up to that much about the vertical, drawn from `rng` (a stack stacked by hand, different per
    seed); the jitter is kept below half the gap plus 2 mm per side so neighbours barely touch at most."""
    rows, cols = int(stack.get("rows", 1)), int(stack.get("cols", 1))
    gap = float(stack.get("gap_m", 0.005))
    at = np.asarray(stack.get("at_m", (0.0, 0.0)), dtype=np.float64)
    layer, rem = divmod(k, rows * cols)
    r, c = divmod(rem, cols)
    sx, sy, sz = asset.size[0] + gap, asset.size[2] + gap, asset.size[1]
    x = at[0] + (c - (cols - 1) / 2.0) * sx
    y = at[1] + (r - (rows - 1) / 2.0) * sy
    R_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # obj +y -> surface +z
    t = np.array([x, y, layer * (sz + 0.001) + sz / 2.0 + 0.001])
    jitter = min(float(stack.get("jitter_m", 0.0)), gap / 2.0 + 0.002)
    yaw_jitter = math.radians(float(stack.get("yaw_jitter_deg", 0.0)))
    if rng is not None and (jitter > 0 or yaw_jitter > 0):
        t[:2] += rng.uniform(-jitter, jitter, 2)
        yaw = rng.uniform(-yaw_jitter, yaw_jitter)
        c, s = math.cos(yaw), math.sin(yaw)
        R_up = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R_up
    if abs(x) + asset.size[0] / 2 > support.half_extents_xy_m[0] + 0.05 or abs(y) + asset.size[2] / 2 > (
        support.half_extents_xy_m[1] + 0.05
    ):
        log.warning("stack on %r overhangs the support by more than 5 cm", support.name)
    return support.T_world_surface @ make_T(R_up, t)


def load_world(path: str | Path, seed: int | None = None, settle: bool | None = None) -> SimWorld:
    """`build_scene(load_scene(path), seed, settle)`."""
    return build_scene(load_scene(path), seed=seed, settle=settle)
