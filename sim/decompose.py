"""Convex collision parts of a loaded mesh: its approximate convex decomposition (CoACD), cached on disk.

MuJoCo collides a mesh geom as its convex hull. The hull of a whole scanned object is wrong for most of them:
a cup's or a bowl's is solid (a finger cannot enter it, a rim cannot be gripped), a hammer's is a slab
between its head and the end of its handle, a banana's fills its inner curve. CoACD (Wei et al., SIGGRAPH
2022) cuts the mesh into convex parts that follow its concavities; each part is a hull MuJoCo can collide.

The parts are cached in `cache_dir()` (`$PROMPOSE_GRASP_CACHE/collision`, else the user cache), keyed by the
mesh's vertices and faces, the settings and the CoACD version: a decomposition takes 10-50 s per scanned
object on one core, once. A cache that cannot be read or written is recomputed or skipped, with a log line.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import logging
from pathlib import Path

import numpy as np
import trimesh

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.perception.knowledge.table import cache_dir as _user_cache_dir

__all__ = ["MAX_PARTS", "THRESHOLD", "cache_dir", "convex_parts"]

log = logging.getLogger(__name__)

#: At most this many convex parts per object: enough for a cup's wall in sectors and a mug's handle, few
#: enough for MuJoCo's collision pairs (24 parts x the gripper's ~10 boxes).
MAX_PARTS = 24
#: CoACD's concavity threshold (its default, 0.05: the largest distance between a part and its hull,
#: relative to the object's size; a 10 cm cup's 4 mm wall stays hollow).
THRESHOLD = 0.05
#: CoACD's search settings: a coarser sampling and a shallower tree search than its defaults (2000, 150, 3),
#: 8-50 s per scanned object on one core instead of minutes; the parts still follow walls and handles.
_SEARCH = {"resolution": 1000, "mcts_iterations": 60, "mcts_max_depth": 2}


def cache_dir() -> Path:
    """Where the decompositions are kept: `collision/` under the library's user cache."""
    return _user_cache_dir() / "collision"


def _key(mesh: trimesh.Trimesh, version: str) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    h.update(f"coacd {version} threshold {THRESHOLD} parts {MAX_PARTS} {sorted(_SEARCH.items())}".encode())
    return h.hexdigest()[:24]


def _load(path: Path) -> list[trimesh.Trimesh] | None:
    try:
        with np.load(path) as data:
            n = int(data["n"])
            parts = [trimesh.Trimesh(data[f"v{k}"], data[f"f{k}"], process=False) for k in range(n)]
    except FileNotFoundError:
        return None
    except Exception as exc:  # a truncated or foreign file: recompute
        log.warning("collision cache %s unreadable (%s): decomposing again", path, exc)
        return None
    return parts if parts and all(len(p.faces) for p in parts) else None


def _save(path: Path, parts: list[trimesh.Trimesh]) -> None:
    arrays: dict[str, np.ndarray] = {"n": np.array(len(parts))}
    for k, p in enumerate(parts):
        arrays[f"v{k}"] = np.asarray(p.vertices, dtype=np.float64)
        arrays[f"f{k}"] = np.asarray(p.faces, dtype=np.int64)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, **arrays)
        tmp.replace(path)
    except OSError as exc:
        log.warning("collision cache %s not written (%s)", path, exc)


def convex_parts(mesh: trimesh.Trimesh) -> list[trimesh.Trimesh]:
    """The convex parts (at most `MAX_PARTS`) of `mesh`'s approximate convex decomposition, in its frame.

    Raises:
        InvalidInputError: CoACD is not installed (`pip install coacd`, the sim's `sim` extra).
    """
    try:
        import coacd
    except ImportError as exc:
        raise InvalidInputError(
            "collision 'decompose' needs CoACD: pip install coacd (or the project's 'sim' extra)"
        ) from exc
    try:
        version = importlib.metadata.version("coacd")
    except importlib.metadata.PackageNotFoundError:
        version = "?"
    path = cache_dir() / f"coacd-{_key(mesh, version)}.npz"
    parts = _load(path)
    if parts is not None:
        return parts
    log.info("decomposing a %d-face mesh into convex parts (once, cached in %s)", len(mesh.faces),
             path.parent)  # fmt: skip
    coacd.set_log_level("error")
    raw = coacd.run_coacd(
        coacd.Mesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)),
        threshold=THRESHOLD,
        max_convex_hull=MAX_PARTS,
        preprocess_mode="auto",
        seed=0,
        **_SEARCH,
    )
    parts = [trimesh.Trimesh(np.asarray(v), np.asarray(f), process=False).convex_hull for v, f in raw]
    parts = [p for p in parts if len(p.faces) >= 4 and p.volume > 0]
    if not parts:  # degenerate: the whole hull, as without decomposition
        parts = [mesh.convex_hull]
    _save(path, parts)
    return parts
