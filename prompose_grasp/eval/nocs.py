"""NOCS-compatible 9-DoF pose metrics: 3D IoU AP and n-degree m-cm AP, as published tables report them.

This re-implements the evaluation protocol of the public NOCS code (hughw19/NOCS_CVPR2019, `utils.py`:
`compute_degree_cm_mAP` and the functions it calls) and of SPD (mentian/object-deformnet, `lib/utils.py`:
`compute_mAP`), which later papers (ProM-Pose included) reuse:

1. Per image and per class (background excluded), predictions are sorted by score (high first).
2. 3D IoU between every prediction and every ground-truth (GT) box of the class. For classes symmetric about
   their y axis (bottle, bowl, can; a mug whose handle is hidden) the IoU is the best over the prediction
   rotated about its own y axis by 2 pi k / 20, k = 0..19.
3. Greedy matching at each IoU threshold in linspace(0, 1, 101): each prediction in score order takes the
   unmatched GT of highest IoU if that IoU is strictly above the threshold.
4. Pose metrics use only the predictions and GTs matched at IoU > 0.1. Their rotation error [deg] is the
   angle of R_pred R_gt^T, or for the symmetric cases the angle between the two y axes; their translation
   error [cm] is |t_pred - t_gt|. At each (degree, cm) threshold pair of the grids 0..60 deg (+ 360) and
   0..15 cm in 0.5 cm steps (+ 100) each prediction in score order takes, among the unmatched GTs within both
   thresholds, the one of least degree + cm.
5. Average precision per class over all images: VOC all-point AP (precision made monotone, summed over
   recall steps). The mean is over the classes 1..C-1; a class with no GT anywhere gets AP 0 when it has no
   predictions and NaN when it has some, and enters the mean as such (`classes_without_gt="reference"`);
   `classes_without_gt="skip"` reports it as NaN and leaves it out of the mean instead.

Three IoU modes (see docs/metrics.md):

- ``nocs``: the reference code's IoU. It reduces the (3, 8) corner array over axis 0, i.e. takes for each
  corner the max and min of its three coordinates instead of each coordinate's max and min over the corners.
  The result depends on where the boxes sit relative to the camera. Published tables were made with it.
- ``aligned``: the same axis-aligned IoU with the reduction fixed: IoU of the camera-frame axis-aligned
  bounding boxes of the two oriented boxes.
- ``exact``: IoU of the oriented boxes themselves (`prompose_grasp.geometry.boxes.oriented_box_iou`).

The results agree with the reference code up to floating-point rounding (numbers land on the same side of
every threshold unless a value sits on a threshold to within ~1e-7). One documented difference: the rotation
error clips its cosine to [-1, 1] as SPD does; the original NOCS code does not, so a cosine rounded just past
-1 (a 180 degree error) becomes NaN there and is counted as a hit.

One module over 600 lines on purpose: it is one protocol, steps 1-5 above, whose thresholds, matching and AP
are checked against the reference code together; split, a reader would lose the order of the steps.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.eval.nocs_results import NocsImageResult, split_sRT
from prompose_grasp.geometry.boxes import BOX_CORNER_SIGNS, oriented_box_iou
from prompose_grasp.geometry.se3 import project_to_so3

__all__ = [
    "DEGREE_THRESHOLDS",
    "IOU_MODES",
    "IOU_THRESHOLDS",
    "NOCS_METRIC_KEYS",
    "NOCS_SYNSET_NAMES",
    "POSE_IOU_GATE",
    "SHIFT_THRESHOLDS_CM",
    "NocsAPCurves",
    "compute_nocs_map",
    "nocs_ap_curves",
    "nocs_box_iou",
    "nocs_pose_error",
    "voc_average_precision",
]

logger = logging.getLogger(__name__)

#: The IoU modes, see the module docstring.
IOU_MODES = ("nocs", "aligned", "exact")

#: The synset list of the NOCS datasets (CAMERA25, REAL275); index 0 is background.
NOCS_SYNSET_NAMES = ("BG", "bottle", "bowl", "camera", "can", "laptop", "mug")

#: Keys of the reported metrics, in table order: 3D IoU AP at 0.25 / 0.5 / 0.75, then n-degree m-cm AP.
NOCS_METRIC_KEYS = ("3D25", "3D50", "3D75", "5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm")

#: Classes whose pose is defined up to a rotation about the object's y axis (the reference's list).
Y_SYMMETRIC_CLASSES = ("bottle", "bowl", "can")

#: Classes that count as y-symmetric when their handle is hidden (`gt_handle_visibility` == 0).
HANDLE_CLASSES = ("mug",)

#: The reference's threshold grids. The reported values sit on grid points exactly (0.25, 0.5, 0.75; 5 and 10
#: degrees; 2 and 5 cm), and each threshold is evaluated independently, so the grids only matter for curves.
IOU_THRESHOLDS = np.linspace(0.0, 1.0, 101)
DEGREE_THRESHOLDS = np.array([*range(61), 360], dtype=np.float64)
SHIFT_THRESHOLDS_CM = np.append(np.linspace(0.0, 1.0, 31) * 15.0, 100.0)
for _a in (IOU_THRESHOLDS, DEGREE_THRESHOLDS, SHIFT_THRESHOLDS_CM):
    _a.setflags(write=False)

#: Pose AP is computed on the predictions and GTs matched at 3D IoU > this (`use_matches_for_pose=True`).
POSE_IOU_GATE = 0.1

#: The reference tries this many rotations about y (2 pi k / 20) for symmetric classes.
NUM_SYMMETRY_ROTATIONS = 20

_CLASS_POLICIES = ("reference", "skip")


def _grid_index(grid: np.ndarray, value: float) -> int:
    i = int(np.argmin(np.abs(grid - value)))
    assert grid[i] == value, (grid[i], value)  # the reported values are exact grid points (module constants)
    return i


_IOU_GATE_INDEX = _grid_index(IOU_THRESHOLDS, POSE_IOU_GATE)
#: metric key -> ("iou", index) or ("pose", degree index, shift index) into the grids.
_METRIC_INDEX: dict[str, tuple[int, ...]] = {
    "3D25": (_grid_index(IOU_THRESHOLDS, 0.25),),
    "3D50": (_grid_index(IOU_THRESHOLDS, 0.5),),
    "3D75": (_grid_index(IOU_THRESHOLDS, 0.75),),
    "5deg2cm": (_grid_index(DEGREE_THRESHOLDS, 5), _grid_index(SHIFT_THRESHOLDS_CM, 2)),
    "5deg5cm": (_grid_index(DEGREE_THRESHOLDS, 5), _grid_index(SHIFT_THRESHOLDS_CM, 5)),
    "10deg2cm": (_grid_index(DEGREE_THRESHOLDS, 10), _grid_index(SHIFT_THRESHOLDS_CM, 2)),
    "10deg5cm": (_grid_index(DEGREE_THRESHOLDS, 10), _grid_index(SHIFT_THRESHOLDS_CM, 5)),
}


def _check_iou_mode(iou_mode: str) -> str:
    if iou_mode not in IOU_MODES:
        raise UnknownNameError("IoU mode", iou_mode, IOU_MODES)
    return iou_mode


def _y_rotations_h(num: int) -> np.ndarray:
    """(num, 4, 4) homogeneous rotations about y by 2 pi k / num, k = 0..num-1 (k = 0 is the identity)."""
    theta = 2.0 * np.pi * np.arange(num) / num
    c, s = np.cos(theta), np.sin(theta)
    Ry = np.zeros((num, 4, 4))
    Ry[:, 0, 0], Ry[:, 0, 2], Ry[:, 2, 0], Ry[:, 2, 2] = c, s, -s, c
    Ry[:, 1, 1] = Ry[:, 3, 3] = 1.0
    return Ry


_Y_ROTATIONS_H = _y_rotations_h(NUM_SYMMETRY_ROTATIONS)


# ----------------------------------------------------------------------------------------------------- IoU


def _corners_cam(sRT: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """(..., 8, 3) camera-frame corners [m] of NOCS boxes: sRT (..., 4, 4) applied to (+-scales / 2), corners
    in the reference's order (which the `nocs` mode depends on: it compares corner k with corner k)."""
    local = BOX_CORNER_SIGNS * (0.5 * scales[..., None, :])  # (..., 8, 3)
    return np.einsum("...ij,...kj->...ki", sRT[..., :3, :3], local) + sRT[..., None, :3, 3]


def _axis_aligned_iou(corners_a: np.ndarray, corners_b: np.ndarray, iou_mode: str) -> np.ndarray:
    """IoU of every a against every b, `nocs` or `aligned` mode.

    Args:
        corners_a: (A, 8, 3), corners_b: (B, 8, 3) camera-frame corners [m].
    Returns:
        (A, B) float64 IoU; NaN (a degenerate `nocs` extent, 0 / 0) is returned as 0, as the reference's
        running max(0, ...) ignores it.
    """
    # The reference reduces its (3, 8) array over axis 0: per corner, over the coordinates. Fixed: per
    # coordinate, over the corners.
    axis = -1 if iou_mode == "nocs" else -2
    hi_a, lo_a = corners_a.max(axis=axis), corners_a.min(axis=axis)  # (A, F), F = 8 (nocs) or 3 (aligned)
    hi_b, lo_b = corners_b.max(axis=axis), corners_b.min(axis=axis)
    ext = np.minimum(hi_a[:, None], hi_b[None]) - np.maximum(lo_a[:, None], lo_b[None])  # (A, B, F)
    inter = np.where(ext.min(axis=-1) < 0.0, 0.0, np.prod(ext, axis=-1))
    union = np.prod(hi_a - lo_a, axis=-1)[:, None] + np.prod(hi_b - lo_b, axis=-1)[None] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        iou = inter / union
    return np.nan_to_num(iou, nan=0.0)


def _exact_iou_matrix(
    pred_sRT: np.ndarray,
    pred_scales: np.ndarray,
    gt_sRT: np.ndarray,
    gt_scales: np.ndarray,
    y_sym: np.ndarray,
) -> np.ndarray:
    s_p, R_p, t_p = split_sRT(pred_sRT)
    s_g, R_g, t_g = split_sRT(gt_sRT)
    # float32 storage leaves R = M / s a few 1e-8 off orthonormal, and a method may store a slightly
    # non-similarity M: the oriented box takes the nearest rotation.
    R_p = np.array([project_to_so3(R) for R in R_p])
    R_g = np.array([project_to_so3(R) for R in R_g])
    size_p, size_g = s_p[:, None] * pred_scales, s_g[:, None] * gt_scales
    # A box is its own image under a half turn about its y axis, so rotations k and k + 10 (of 20) give the
    # same box and the same IoU: try only the first half.
    half_turns = _Y_ROTATIONS_H[: NUM_SYMMETRY_ROTATIONS // 2, :3, :3]
    out = np.zeros((len(pred_sRT), len(gt_sRT)))
    for i in range(len(pred_sRT)):
        for j in range(len(gt_sRT)):
            rotations = half_turns if y_sym[j] else half_turns[:1]
            out[i, j] = max(
                oriented_box_iou(R_p[i] @ Ry, t_p[i], size_p[i], R_g[j], t_g[j], size_g[j])
                for Ry in rotations
            )
    return out


def _iou_matrix(
    pred_sRT: np.ndarray,
    pred_scales: np.ndarray,
    gt_sRT: np.ndarray,
    gt_scales: np.ndarray,
    y_sym: np.ndarray,
    iou_mode: str,
) -> np.ndarray:
    """(P, G) IoU of predictions against GTs; for GT j with `y_sym[j]` the best over the prediction's 20
    rotations about its own y axis (sRT_pred @ Ry), else the prediction as it is."""
    P, G = len(pred_sRT), len(gt_sRT)
    if P == 0 or G == 0:
        return np.zeros((P, G))
    if iou_mode == "exact":
        return _exact_iou_matrix(pred_sRT, pred_scales, gt_sRT, gt_scales, y_sym)
    gt_corners = _corners_cam(gt_sRT, gt_scales)  # (G, 8, 3)
    K = NUM_SYMMETRY_ROTATIONS if np.any(y_sym) else 1
    rotated = pred_sRT[:, None] @ _Y_ROTATIONS_H[None, :K]  # (P, K, 4, 4)
    pred_corners = _corners_cam(rotated, np.broadcast_to(pred_scales[:, None], (P, K, 3)))
    iou = _axis_aligned_iou(pred_corners.reshape(P * K, 8, 3), gt_corners, iou_mode).reshape(P, K, G)
    return np.where(y_sym[None, :], iou.max(axis=1), iou[:, 0])


def nocs_box_iou(
    sRT_pred: np.ndarray,
    scales_pred: np.ndarray,
    sRT_gt: np.ndarray,
    scales_gt: np.ndarray,
    iou_mode: str = "nocs",
    y_symmetric: bool = False,
) -> float:
    """3D IoU of two NOCS boxes, as the metric computes it.

    Args:
        sRT_pred, sRT_gt: (4, 4) similarity transforms [s R | t; 0 0 0 1], NOCS box frame -> camera [m].
        scales_pred, scales_gt: (3,) NOCS box extents (> 0); the metric box is s * scales.
        iou_mode: "nocs" (the reference's, depends on the distance from the camera), "aligned" (camera-frame
            axis-aligned boxes) or "exact" (oriented boxes).
        y_symmetric: take the best IoU over the prediction rotated about its y axis by 2 pi k / 20.
    Returns:
        IoU in [0, 1].
    """
    _check_iou_mode(iou_mode)
    image = NocsImageResult.from_dict(
        {
            "gt_class_ids": [1],
            "gt_RTs": [sRT_gt],
            "gt_scales": [scales_gt],
            "pred_class_ids": [1],
            "pred_scores": [1.0],
            "pred_RTs": [sRT_pred],
            "pred_scales": [scales_pred],
        },
        where="nocs_box_iou (pred_RTs / pred_scales = sRT_pred / scales_pred, gt_* = sRT_gt / scales_gt)",
    )
    y_sym = np.array([bool(y_symmetric)])
    iou = _iou_matrix(image.pred_sRT, image.pred_scales, image.gt_sRT, image.gt_scales, y_sym, iou_mode)
    return float(iou[0, 0])


# --------------------------------------------------------------------------------------------- pose errors


def _pose_errors(
    pred_sRT: np.ndarray, gt_sRT: np.ndarray, y_sym: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(P, G) rotation errors [deg] and (P, G) translation errors [cm] of predictions against GTs."""
    _, R_p, t_p = split_sRT(pred_sRT)
    _, R_g, t_g = split_sRT(gt_sRT)
    # Full rotation: cos = (trace(R_p R_g^T) - 1) / 2, and trace(A B^T) = sum(A * B).
    cos_full = (np.einsum("pij,gij->pg", R_p, R_g) - 1.0) / 2.0
    # About y: the angle between the two y axes (the second columns).
    y_p, y_g = R_p[:, :, 1], R_g[:, :, 1]
    norms = np.linalg.norm(y_p, axis=1)[:, None] * np.linalg.norm(y_g, axis=1)[None]
    cos_y = (y_p @ y_g.T) / norms
    cos = np.where(y_sym[None, :], cos_y, cos_full)
    deg = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    cm = np.linalg.norm(t_p[:, None] - t_g[None], axis=-1) * 100.0
    return deg, cm


def nocs_pose_error(
    sRT_pred: np.ndarray, sRT_gt: np.ndarray, y_symmetric: bool = False
) -> tuple[float, float]:
    """Rotation error [deg] and translation error [cm] between two sRTs, as the metric computes them.

    Args:
        sRT_pred, sRT_gt: (4, 4) [s R | t; 0 0 0 1] with det > 0.
        y_symmetric: compare only the y axes (bottle, bowl, can; a mug whose handle is hidden).
    Returns:
        (degrees in [0, 180], centimetres).
    """
    image = NocsImageResult.from_dict(
        {
            "gt_class_ids": [1],
            "gt_RTs": [sRT_gt],
            "gt_scales": [[1.0, 1.0, 1.0]],
            "pred_class_ids": [1],
            "pred_scores": [1.0],
            "pred_RTs": [sRT_pred],
            "pred_scales": [[1.0, 1.0, 1.0]],
        },
        where="nocs_pose_error (pred_RTs = sRT_pred, gt_RTs = sRT_gt)",
    )
    deg, cm = _pose_errors(image.pred_sRT, image.gt_sRT, np.array([bool(y_symmetric)]))
    return float(deg[0, 0]), float(cm[0, 0])


# -------------------------------------------------------------------------------------- matching and AP


def _match_iou(overlaps: np.ndarray, thresholds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Greedy IoU matching at every threshold at once.

    Args:
        overlaps: (P, G) IoU, predictions already in score order (high first).
        thresholds: (T,).
    Returns:
        pred_matched (T, P) bool, gt_matched (T, G) bool.
    """
    P, G = overlaps.shape
    T = len(thresholds)
    pred_matched = np.zeros((T, P), dtype=bool)
    gt_matched = np.zeros((T, G), dtype=bool)
    if P == 0 or G == 0:
        return pred_matched, gt_matched
    rows = np.arange(T)
    for i in range(P):
        # The reference walks GTs by falling IoU, skips matched ones and stops at the first unmatched one:
        # a match iff that one's IoU is > threshold. Same sort call, so ties resolve the same way.
        order = np.argsort(overlaps[i])[::-1]
        free = ~gt_matched[:, order]  # (T, G)
        has_free = free.any(axis=1)
        j = order[free.argmax(axis=1)]  # (T,) the first unmatched GT in that order
        hit = has_free & (overlaps[i, j] > thresholds)
        pred_matched[hit, i] = True
        gt_matched[rows[hit], j[hit]] = True
    return pred_matched, gt_matched


def _match_pose(
    deg: np.ndarray, cm: np.ndarray, degree_thresholds: np.ndarray, shift_thresholds_cm: np.ndarray
) -> np.ndarray:
    """Greedy pose matching at every (degree, cm) threshold pair at once.

    Args:
        deg, cm: (P, G) errors, predictions in score order (high first).
        degree_thresholds: (D,), shift_thresholds_cm: (S,).
    Returns:
        pred_matched (D, S, P) bool.
    """
    P, G = deg.shape
    D, S = len(degree_thresholds), len(shift_thresholds_cm)
    pred_matched = np.zeros((D, S, P), dtype=bool)
    if P == 0 or G == 0:
        return pred_matched
    gt_matched = np.zeros((D, S, G), dtype=bool)
    d_idx, s_idx = np.meshgrid(np.arange(D), np.arange(S), indexing="ij")
    for i in range(P):
        # GTs by rising degree + cm; the first unmatched one within both thresholds is taken.
        order = np.argsort(deg[i] + cm[i])
        within = (deg[i, order] <= degree_thresholds[:, None, None]) & (
            cm[i, order] <= shift_thresholds_cm[None, :, None]
        )
        ok = within & ~gt_matched[:, :, order]  # (D, S, G)
        hit = ok.any(axis=-1)
        j = order[ok.argmax(axis=-1)]  # (D, S)
        pred_matched[hit, i] = True
        gt_matched[d_idx[hit], s_idx[hit], j[hit]] = True
    return pred_matched


def voc_average_precision(matched: np.ndarray, scores: np.ndarray, num_gt: int) -> np.ndarray:
    """VOC all-point average precision, as the reference computes it.

    Predictions are ranked by score (high first); precision is made non-increasing from the right and summed
    over the recall steps. The recall is padded with 1 at the end, so missed GTs cost precision 0.

    Args:
        matched: (..., N) bool, whether prediction n is a true positive (one array per threshold).
        scores: (N,) float, confidences.
        num_gt: number of GT instances (the recall denominator).
    Returns:
        (...) float64 AP in [0, 1]; 0 with no predictions; NaN with predictions but num_gt == 0 (0 / 0 in the
        reference's recall).
    """
    matched = np.asarray(matched, dtype=bool)
    scores = np.asarray(scores, dtype=np.float64)
    if matched.shape[-1:] != scores.shape or scores.ndim != 1:
        raise InvalidInputError(
            f"matched must have shape (..., N) with N = len(scores) = {scores.shape}, got {matched.shape}"
        )
    if num_gt < 0:
        raise InvalidInputError(f"num_gt must be >= 0, got {num_gt}")
    n = len(scores)
    lead = matched.shape[:-1]
    if n == 0:
        return np.zeros(lead)
    order = np.argsort(scores)[::-1]  # the reference's call, so equal scores rank the same way
    tp = np.cumsum(matched[..., order], axis=-1)
    precision = tp / np.arange(1, n + 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        # The reference divides a float32 count; keep its rounding of the recall.
        recall = (tp.astype(np.float32) / np.float32(num_gt)).astype(np.float64)
    zeros, ones = np.zeros((*lead, 1)), np.ones((*lead, 1))
    precision = np.concatenate([zeros, precision, zeros], axis=-1)
    recall = np.concatenate([zeros, recall, ones], axis=-1)
    envelope = np.flip(np.maximum.accumulate(np.flip(precision, axis=-1), axis=-1), axis=-1)
    return np.sum(np.diff(recall, axis=-1) * envelope[..., 1:], axis=-1)


# ----------------------------------------------------------------------------------------------- curves


@dataclass(frozen=True)
class NocsAPCurves:
    """AP over the reference's full threshold grids, per class (background excluded). Fractions in [0, 1].

    Attributes:
        class_names: (C-1,) the synset names without background, row order of the arrays below.
        iou_mode: the IoU mode used.
        iou_thresholds: (T,) = linspace(0, 1, 101).
        degree_thresholds: (D,) = 0..60 and 360 [deg].
        shift_thresholds_cm: (S,) = 0..15 in 0.5 steps and 100 [cm].
        iou_ap: (C-1, T) 3D IoU AP per class and threshold.
        pose_ap: (C-1, D, S) pose AP per class and threshold pair, on the detections matched at IoU > 0.1.
        num_gt: (C-1,) GT instances per class over all images.
        num_pred: (C-1,) predictions per class over all images.
        num_pose_gt: (C-1,) GTs matched at IoU > 0.1 (the recall denominator of the pose AP).
        num_images: number of result dicts read.
    """

    class_names: tuple[str, ...]
    iou_mode: str
    iou_thresholds: np.ndarray
    degree_thresholds: np.ndarray
    shift_thresholds_cm: np.ndarray
    iou_ap: np.ndarray
    pose_ap: np.ndarray
    num_gt: np.ndarray
    num_pred: np.ndarray
    num_pose_gt: np.ndarray
    num_images: int

    def __post_init__(self) -> None:
        for name in ("iou_ap", "pose_ap", "num_gt", "num_pred", "num_pose_gt"):
            getattr(self, name).setflags(write=False)

    def table(self, classes_without_gt: str = "reference") -> dict[str, dict[str, Any]]:
        """The reported metrics in percent: {"mean": {key: AP}, "per_class": {name: {key: AP}}}.

        Args:
            classes_without_gt: "reference" keeps the reference's values for classes with no GT (0 without
                predictions, NaN with some) and averages over all classes; "skip" reports them as NaN and
                averages over the others.
        """
        if classes_without_gt not in _CLASS_POLICIES:
            raise UnknownNameError("classes_without_gt policy", classes_without_gt, _CLASS_POLICIES)
        per_class_ap = np.empty((len(self.class_names), len(NOCS_METRIC_KEYS)))
        for k, key in enumerate(NOCS_METRIC_KEYS):
            index = _METRIC_INDEX[key]
            per_class_ap[:, k] = (
                self.iou_ap[:, index[0]] if len(index) == 1 else self.pose_ap[:, index[0], index[1]]
            )
        if classes_without_gt == "skip":
            per_class_ap[self.num_gt == 0] = np.nan
            counted = self.num_gt > 0
            mean = (
                per_class_ap[counted].mean(axis=0)
                if np.any(counted)
                else np.full(len(NOCS_METRIC_KEYS), np.nan)
            )
        else:
            missing = [n for n, g in zip(self.class_names, self.num_gt) if g == 0]
            if missing:
                logger.warning(
                    "no ground truth for class(es) %s: their AP is 0 (NaN with predictions) and enters the "
                    "mean as in the reference code; classes_without_gt='skip' leaves them out",
                    ", ".join(missing),
                )
            mean = per_class_ap.mean(axis=0)
        return {
            "mean": {key: float(100.0 * mean[k]) for k, key in enumerate(NOCS_METRIC_KEYS)},
            "per_class": {
                name: {key: float(100.0 * per_class_ap[c, k]) for k, key in enumerate(NOCS_METRIC_KEYS)}
                for c, name in enumerate(self.class_names)
            },
        }


def _check_synsets(synset_names: Sequence[str]) -> tuple[str, ...]:
    if isinstance(synset_names, str) or not all(isinstance(n, str) for n in synset_names):
        raise InvalidInputError(f"synset_names must be a sequence of class names, got {synset_names!r}")
    names = tuple(synset_names)
    if len(names) < 2:
        raise InvalidInputError(
            f"synset_names needs background (index 0) and at least one class, got {names}"
        )
    if len(set(names)) != len(names):
        raise InvalidInputError(f"synset_names must be unique, got {names}")
    return names


def nocs_ap_curves(
    results: Sequence[Mapping[str, Any]],
    synset_names: Sequence[str] = NOCS_SYNSET_NAMES,
    iou_mode: str = "nocs",
    *,
    y_symmetric_classes: Collection[str] = Y_SYMMETRIC_CLASSES,
    handle_classes: Collection[str] = HANDLE_CLASSES,
) -> NocsAPCurves:
    """AP curves over the reference's threshold grids (see the module docstring for the protocol).

    Args:
        results: per-image NOCS / SPD result dicts (see `prompose_grasp.eval.nocs_results`).
        synset_names: class names by class id; index 0 is background and is not evaluated.
        iou_mode: "nocs", "aligned" or "exact".
        y_symmetric_classes: class names whose pose is defined up to a rotation about y.
        handle_classes: class names that count as y-symmetric where `gt_handle_visibility` is 0.
    Raises:
        UnknownNameError: unknown `iou_mode`.
        InvalidInputError: a result dict is malformed (the message names it and what is wrong).
    """
    iou_mode = _check_iou_mode(iou_mode)
    names = _check_synsets(synset_names)
    if isinstance(results, Mapping):
        raise InvalidInputError("results must be a sequence of per-image result dicts, got a single dict")
    images = [
        NocsImageResult.from_dict(r, where=f"result {k}", num_classes=len(names))
        for k, r in enumerate(results)
    ]
    if not images:
        raise InvalidInputError("results is empty; pass at least one per-image result dict")

    C = len(names) - 1
    T, D, S = len(IOU_THRESHOLDS), len(DEGREE_THRESHOLDS), len(SHIFT_THRESHOLDS_CM)
    iou_hits: list[list[np.ndarray]] = [[] for _ in range(C)]
    iou_scores: list[list[np.ndarray]] = [[] for _ in range(C)]
    pose_hits: list[list[np.ndarray]] = [[] for _ in range(C)]
    pose_scores: list[list[np.ndarray]] = [[] for _ in range(C)]
    num_gt = np.zeros(C, dtype=np.int64)
    num_pose_gt = np.zeros(C, dtype=np.int64)

    for image in images:
        for c in range(C):
            class_id = c + 1
            g = image.gt_class_ids == class_id
            p = image.pred_class_ids == class_id
            if not np.any(g) and not np.any(p):
                continue
            order = np.argsort(image.pred_scores[p])[::-1]  # the reference's call: ties rank the same way
            pred_sRT, pred_scales = image.pred_sRT[p][order], image.pred_scales[p][order]
            scores = image.pred_scores[p][order]
            gt_sRT, gt_scales = image.gt_sRT[g], image.gt_scales[g]
            name = names[class_id]
            y_sym = np.full(int(g.sum()), name in y_symmetric_classes)
            if name in handle_classes:
                y_sym |= ~image.gt_handle_visible[g]

            # The reference stores the IoU matrix as float32; thresholds compare against those values.
            overlaps = _iou_matrix(pred_sRT, pred_scales, gt_sRT, gt_scales, y_sym, iou_mode).astype(
                np.float32
            )
            pred_hit, gt_hit = _match_iou(overlaps, IOU_THRESHOLDS)
            iou_hits[c].append(pred_hit)
            iou_scores[c].append(scores)
            num_gt[c] += len(gt_sRT)

            keep_p, keep_g = pred_hit[_IOU_GATE_INDEX], gt_hit[_IOU_GATE_INDEX]
            deg, cm = _pose_errors(pred_sRT[keep_p], gt_sRT[keep_g], y_sym[keep_g])
            pose_hits[c].append(_match_pose(deg, cm, DEGREE_THRESHOLDS, SHIFT_THRESHOLDS_CM))
            pose_scores[c].append(scores[keep_p])
            num_pose_gt[c] += int(keep_g.sum())

    iou_ap = np.zeros((C, T))
    pose_ap = np.zeros((C, D, S))
    num_pred = np.zeros(C, dtype=np.int64)
    for c in range(C):
        if iou_scores[c]:
            s_iou = np.concatenate(iou_scores[c])
            num_pred[c] = len(s_iou)
            iou_ap[c] = voc_average_precision(np.concatenate(iou_hits[c], axis=-1), s_iou, int(num_gt[c]))
            s_pose = np.concatenate(pose_scores[c])
            pose_ap[c] = voc_average_precision(
                np.concatenate(pose_hits[c], axis=-1), s_pose, int(num_pose_gt[c])
            )
    return NocsAPCurves(
        class_names=names[1:],
        iou_mode=iou_mode,
        iou_thresholds=IOU_THRESHOLDS,
        degree_thresholds=DEGREE_THRESHOLDS,
        shift_thresholds_cm=SHIFT_THRESHOLDS_CM,
        iou_ap=iou_ap,
        pose_ap=pose_ap,
        num_gt=num_gt,
        num_pred=num_pred,
        num_pose_gt=num_pose_gt,
        num_images=len(images),
    )


def compute_nocs_map(
    results: Sequence[Mapping[str, Any]],
    synset_names: Sequence[str] = NOCS_SYNSET_NAMES,
    iou_mode: str = "nocs",
    *,
    classes_without_gt: str = "reference",
    y_symmetric_classes: Collection[str] = Y_SYMMETRIC_CLASSES,
    handle_classes: Collection[str] = HANDLE_CLASSES,
) -> dict[str, dict[str, Any]]:
    """The NOCS mAP table from per-image result dicts, in percent.

    Args:
        results: per-image NOCS / SPD result dicts (keys gt_class_ids, gt_RTs, gt_scales,
            gt_handle_visibility, pred_class_ids, pred_scores, pred_RTs, pred_scales), e.g. from
            `load_nocs_results`.
        synset_names: class names by class id; index 0 is background and is not evaluated.
        iou_mode: "nocs" (the reference's IoU; compare with published tables), "aligned" (fixed axis-aligned
            IoU) or "exact" (oriented-box IoU).
        classes_without_gt: "reference" (default; as the reference code) or "skip" (NaN, left out of the
            mean).
        y_symmetric_classes, handle_classes: see `nocs_ap_curves`.
    Returns:
        {"mean": {key: AP}, "per_class": {name: {key: AP}}} with keys 3D25, 3D50, 3D75, 5deg2cm, 5deg5cm,
        10deg2cm, 10deg5cm, AP in percent (Python floats; NaN where undefined).
    Raises:
        UnknownNameError: unknown `iou_mode` or `classes_without_gt`.
        InvalidInputError: a result dict is malformed.
    """
    if classes_without_gt not in _CLASS_POLICIES:
        raise UnknownNameError("classes_without_gt policy", classes_without_gt, _CLASS_POLICIES)
    curves = nocs_ap_curves(
        results,
        synset_names,
        iou_mode,
        y_symmetric_classes=y_symmetric_classes,
        handle_classes=handle_classes,
    )
    return curves.table(classes_without_gt)
