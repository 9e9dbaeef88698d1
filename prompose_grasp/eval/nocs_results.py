"""NOCS / SPD per-image result dicts: reading them from pickles and checking them.

The public NOCS (hughw19/NOCS_CVPR2019) and SPD (mentian/object-deformnet) evaluation code writes one pickle
per image holding a dict with these keys (other keys, such as `gt_bboxes` or `pred_bboxes`, are ignored here):

=======================  ==============  ============================================================
key                      shape           meaning
=======================  ==============  ============================================================
`gt_class_ids`           (M,) int        class index into the synset list (0 is background)
`gt_RTs`                 (M, 4, 4)       sRT: [s R | t; 0 0 0 1], NOCS box frame -> camera frame [m]
`gt_scales`              (M, 3)          box extents in the NOCS frame; metric size = s * scales
`gt_handle_visibility`   (M,)            0 where a mug's handle is hidden (then the mug counts as
                                         symmetric about y); optional, ones when absent (as SPD does)
`pred_class_ids`         (N,) int        as `gt_class_ids`
`pred_scores`            (N,) float      detection confidence, higher is better
`pred_RTs`               (N, 4, 4)       as `gt_RTs`
`pred_scales`            (N, 3)          as `gt_scales`
=======================  ==============  ============================================================

A pickle can name any function for the loader to call, so result files are read with a restricted
unpickler (`_read_pickle`): it rebuilds numpy arrays, dtypes and scalars and plain Python containers, and
refuses every other global with an `InvalidInputError` naming it, before anything is called. A crafted
file's payload never runs.
"""

from __future__ import annotations

import builtins
import collections
import logging
import os
import pickle
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError

__all__ = ["NOCS_RESULT_KEYS", "NocsImageResult", "load_nocs_results", "split_sRT"]

logger = logging.getLogger(__name__)

#: The keys every per-image result dict must hold (`gt_handle_visibility` is optional: ones when absent).
NOCS_RESULT_KEYS = (
    "gt_class_ids",
    "gt_RTs",
    "gt_scales",
    "pred_class_ids",
    "pred_scores",
    "pred_RTs",
    "pred_scales",
)

#: The last row of an sRT must be (0, 0, 0, 1). The reference code demands exact equality; float32 storage
#: keeps 0 and 1 exact, and this margin only admits rounding from arithmetic done before saving.
_HOMOGENEOUS_ROW_ATOL = 1e-6


def split_sRT(sRT: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split similarity transforms as the reference code does: s = cbrt(det(M)), R = M / s, M = sRT[:3, :3].

    Args:
        sRT: (..., 4, 4) float, [s R | t; 0 0 0 1] with det > 0.
    Returns:
        s (...,) scale, R (..., 3, 3) rotation (exactly orthonormal only when the input is a scaled rotation),
        t (..., 3) translation [m].
    """
    sRT = np.asarray(sRT, dtype=np.float64)
    s = np.cbrt(np.linalg.det(sRT[..., :3, :3]))
    R = sRT[..., :3, :3] / s[..., None, None]
    return s, R, sRT[..., :3, 3]


def _integer_ids(value: Any, key: str, where: str) -> np.ndarray:
    a = np.asarray(value)
    if a.size == 0:
        return np.zeros(0, dtype=np.int64)
    if a.ndim != 1:
        raise InvalidInputError(f"{where}: {key!r} must have shape (N,), got {a.shape}")
    if a.dtype.kind not in "iuf" or not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
        raise InvalidInputError(f"{where}: {key!r} must hold integer class indices, got {a}")
    return a.astype(np.int64)


def _float_array(value: Any, key: str, shape: tuple[int, ...], where: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{where}: {key!r} must be a numeric array of shape {shape}") from exc
    if shape[0] == 0 and a.size == 0:  # an image without instances may store [] or an empty array
        return np.zeros(shape, dtype=np.float64)
    if a.shape != shape:
        raise InvalidInputError(
            f"{where}: {key!r} must have shape {shape} (its first axis matches the number of class ids), "
            f"got {a.shape}"
        )
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{where}: {key!r} must be finite, got NaN or inf")
    return a


def _check_sRT(sRT: np.ndarray, key: str, where: str) -> None:
    if len(sRT) == 0:
        return
    bad_row = np.any(np.abs(sRT[:, 3, :] - [0.0, 0.0, 0.0, 1.0]) > _HOMOGENEOUS_ROW_ATOL, axis=1)
    if np.any(bad_row):
        i = int(np.argmax(bad_row))
        raise InvalidInputError(f"{where}: {key}[{i}] must have last row (0, 0, 0, 1), got {sRT[i, 3]}")
    det = np.linalg.det(sRT[:, :3, :3])
    if np.any(det <= 0.0):
        i = int(np.argmax(det <= 0.0))
        raise InvalidInputError(
            f"{where}: {key}[{i}][:3, :3] must be s * R with s > 0 and R a rotation (det > 0), "
            f"got det = {det[i]:.6g}"
        )


@dataclass(frozen=True)
class NocsImageResult:
    """One image's checked result dict, float64 / int64 copies of the arrays (see the module docstring).

    Attributes:
        gt_class_ids: (M,) int64.
        gt_sRT: (M, 4, 4) float64.
        gt_scales: (M, 3) float64, > 0.
        gt_handle_visible: (M,) bool, False where `gt_handle_visibility` is 0.
        pred_class_ids: (N,) int64.
        pred_scores: (N,) float64.
        pred_sRT: (N, 4, 4) float64.
        pred_scales: (N, 3) float64, > 0.
    """

    gt_class_ids: np.ndarray
    gt_sRT: np.ndarray
    gt_scales: np.ndarray
    gt_handle_visible: np.ndarray
    pred_class_ids: np.ndarray
    pred_scores: np.ndarray
    pred_sRT: np.ndarray
    pred_scales: np.ndarray

    @classmethod
    def from_dict(cls, result: Mapping[str, Any], where: str = "result", num_classes: int | None = None):
        """Check a NOCS / SPD result dict and convert it.

        Args:
            result: the per-image dict (keys in `NOCS_RESULT_KEYS`, optionally `gt_handle_visibility`).
            where: names the dict in error messages (e.g. "result 3 (results_real_scene_1_0000.pkl)").
            num_classes: when given, class ids must lie in [0, num_classes).
        Raises:
            InvalidInputError: a key is missing, or an array has the wrong shape, is not finite, or an sRT is
                not a similarity transform.
        """
        if not isinstance(result, Mapping):
            raise InvalidInputError(
                f"{where}: expected a dict with keys {', '.join(NOCS_RESULT_KEYS)}, "
                f"got {type(result).__name__}"
            )
        missing = [k for k in NOCS_RESULT_KEYS if k not in result]
        if missing:
            raise InvalidInputError(
                f"{where}: missing key(s) {', '.join(missing)}; a NOCS result dict needs "
                f"{', '.join(NOCS_RESULT_KEYS)} (and optionally gt_handle_visibility)"
            )
        gt_ids = _integer_ids(result["gt_class_ids"], "gt_class_ids", where)
        pred_ids = _integer_ids(result["pred_class_ids"], "pred_class_ids", where)
        m, n = len(gt_ids), len(pred_ids)
        gt_sRT = _float_array(result["gt_RTs"], "gt_RTs", (m, 4, 4), where)
        gt_scales = _float_array(result["gt_scales"], "gt_scales", (m, 3), where)
        if result.get("gt_handle_visibility") is None:
            handle = np.ones(m)
        else:
            handle = _float_array(result["gt_handle_visibility"], "gt_handle_visibility", (m,), where)
        pred_scores = _float_array(result["pred_scores"], "pred_scores", (n,), where)
        pred_sRT = _float_array(result["pred_RTs"], "pred_RTs", (n, 4, 4), where)
        pred_scales = _float_array(result["pred_scales"], "pred_scales", (n, 3), where)
        _check_sRT(gt_sRT, "gt_RTs", where)
        _check_sRT(pred_sRT, "pred_RTs", where)
        for key, scales in (("gt_scales", gt_scales), ("pred_scales", pred_scales)):
            if np.any(scales <= 0.0):
                raise InvalidInputError(f"{where}: {key!r} must be > 0 (box extents), got {scales}")
        if num_classes is not None:
            for key, ids in (("gt_class_ids", gt_ids), ("pred_class_ids", pred_ids)):
                if np.any((ids < 0) | (ids >= num_classes)):
                    raise InvalidInputError(
                        f"{where}: {key!r} holds {sorted(set(ids.tolist()))} but the synset list has "
                        f"{num_classes} names (indices 0..{num_classes - 1}); pass the synset list the "
                        f"results were written with"
                    )
        return cls(gt_ids, gt_sRT, gt_scales, handle != 0, pred_ids, pred_scores, pred_sRT, pred_scales)


def _looks_like_result(obj: Any) -> bool:
    return isinstance(obj, Mapping) and any(k in obj for k in NOCS_RESULT_KEYS)


def _latin1_encode(text: str, encoding: str = "latin1") -> bytes:
    """`_codecs.encode` as protocol 0-2 pickles use it to store bytes (a numpy buffer): latin1 only."""
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise pickle.UnpicklingError(f"_codecs.encode is allowed with latin1 only, got {encoding!r}")
    return text.encode("latin1")


def _allowed_globals() -> dict[tuple[str, str], Any]:
    """The globals a NOCS / SPD result pickle may name: how numpy (1.x writes `numpy.core`, 2.x
    `numpy._core`) rebuilds arrays, dtypes and scalars, and plain containers. Each name maps to this numpy's
    own object, so a 1.x pickle loads under 2.x without touching the deprecated `numpy.core` alias."""
    try:
        from numpy._core import multiarray, numeric  # numpy >= 2
    except ImportError:  # numpy 1.x
        from numpy.core import multiarray, numeric  # type: ignore[no-redef]
    allowed: dict[tuple[str, str], Any] = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
        ("_codecs", "encode"): _latin1_encode,
        ("collections", "OrderedDict"): collections.OrderedDict,
    }
    for core in ("numpy.core", "numpy._core"):
        allowed[(f"{core}.multiarray", "_reconstruct")] = multiarray._reconstruct
        allowed[(f"{core}.multiarray", "scalar")] = multiarray.scalar
        # protocol 5 rebuilds contiguous arrays from a buffer
        allowed[(f"{core}.numeric", "_frombuffer")] = numeric._frombuffer  # type: ignore[attr-defined]
    for name in ("set", "frozenset", "complex", "slice"):
        for module in ("builtins", "__builtin__"):  # __builtin__: Python 2
            allowed[(module, name)] = getattr(builtins, name)
    return allowed


class _ResultUnpickler(pickle.Unpickler):
    """Unpickles numpy arrays and plain containers only (`_allowed_globals`); any other global is refused
    with an `InvalidInputError` naming it, before it is imported or called."""

    def __init__(self, file: Any, path: Path, **kwargs: Any):
        super().__init__(file, **kwargs)
        self._path = path
        self._allowed = _allowed_globals()

    def find_class(self, module: str, name: str) -> Any:
        try:
            return self._allowed[(module, name)]
        except KeyError:
            raise InvalidInputError(
                f"{self._path}: refused to load: the pickle names {module}.{name}, which a NOCS result "
                "file does not need (only numpy arrays, dtypes, scalars and plain containers are loaded)"
            ) from None


def _read_pickle(path: Path) -> Any:
    try:
        try:
            with open(path, "rb") as f:
                return _ResultUnpickler(f, path).load()
        except UnicodeDecodeError:
            # Pickles written by Python 2 store numpy buffers as str; latin1 maps their bytes one to one.
            with open(path, "rb") as f:
                return _ResultUnpickler(f, path, encoding="latin1").load()
    except (
        pickle.UnpicklingError,
        EOFError,
        AttributeError,
        ImportError,
        IndexError,
        KeyError,
        TypeError,
        ValueError,
        MemoryError,
        OverflowError,
        RecursionError,
    ) as exc:
        if isinstance(exc, InvalidInputError):
            raise
        raise InvalidInputError(f"{path}: not a readable pickle ({type(exc).__name__}: {exc})") from exc


def _results_in(path: Path, content: Any, explicit: bool) -> list[dict]:
    items = list(content) if isinstance(content, (list, tuple)) else [content]
    if not explicit and not all(_looks_like_result(x) for x in items):
        # Folders written by the reference code also hold its summaries (mAP_Acc.pkl, IoU_3D_AP_*.pkl).
        logger.warning("%s holds no NOCS per-image result dicts; skipped", path)
        return []
    out = []
    for k, item in enumerate(items):
        where = f"{path}" if len(items) == 1 else f"{path} [item {k}]"
        NocsImageResult.from_dict(item, where=where)
        out.append(item)
    return out


def load_nocs_results(paths: Sequence[str | os.PathLike[str]] | str | os.PathLike[str]) -> list[dict]:
    """Read NOCS / SPD per-image result dicts from pickles.

    Args:
        paths: result `.pkl` files, or folders whose `*.pkl` files (not recursive) are read in sorted name
            order. A pickle holds one result dict or a list of them. In a folder, pickles that hold no result
            dict (the reference code's own summaries such as `mAP_Acc.pkl`) are skipped with a warning; a file
            named explicitly must hold result dicts.
    Returns:
        the result dicts in order (files in the order given, folder contents sorted by name), each checked
        with `NocsImageResult.from_dict`.
    Raises:
        InvalidInputError: a path does not exist, no result pickle was found, or a pickle holds something else
            than result dicts (the message names the file and what is wrong).
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    if len(paths) == 0:
        raise InvalidInputError("no result paths given; pass .pkl files or folders holding them")
    results: list[dict] = []
    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            files = sorted(path.glob("*.pkl"))
            if not files:
                raise InvalidInputError(f"{path}: folder holds no *.pkl result files")
            for f in files:
                results.extend(_results_in(f, _read_pickle(f), explicit=False))
        elif path.is_file():
            results.extend(_results_in(path, _read_pickle(path), explicit=True))
        else:
            raise InvalidInputError(f"{path}: no such file or folder")
    if not results:
        raise InvalidInputError(
            f"no NOCS result dicts found in {', '.join(str(p) for p in paths)}; expected pickles holding "
            f"dicts with keys {', '.join(NOCS_RESULT_KEYS)}"
        )
    logger.info("read %d NOCS result dicts", len(results))
    return results
