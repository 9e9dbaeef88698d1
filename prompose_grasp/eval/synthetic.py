"""NOCS result dicts for synthetic frames (reading the dataset: `prompose_grasp.perception.dataset`)."""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np

from prompose_grasp.eval.nocs import IOU_MODES, compute_nocs_map
from prompose_grasp.geometry import Pose9D
from prompose_grasp.geometry.pointcloud import valid_depth_mask
from prompose_grasp.perception.dataset import GroundTruthObject, SyntheticFrame

__all__ = ["MIN_GT_DEPTH_PIXELS", "evaluated_objects", "nocs_image_result", "nocs_tables"]

#: The standard CAMERA25 / REAL275 test protocol (the SPD test labels behind the published numbers, the
#: paper's included): an object is ground truth in a frame when at least 64 of its mask pixels have a depth
#: reading. A hidden object is not in the frame's ground truth; one seen on a few dozen pixels neither.
MIN_GT_DEPTH_PIXELS = 64


def evaluated_objects(sf: SyntheticFrame, categories: Collection[str]) -> list[GroundTruthObject]:
    """The ground truth of a frame under the standard protocol (`MIN_GT_DEPTH_PIXELS`): the objects of
    `categories` with at least 64 valid depth pixels in the frame's instance mask."""
    seen = sf.ground_truth_instance_mask[valid_depth_mask(sf.frame.depth_m)]
    ids, counts = np.unique(seen, return_counts=True)
    valid_pixels = dict(zip(ids.tolist(), counts.tolist(), strict=True))
    return [
        o
        for o in sf.ground_truth_objects
        if o.category in categories and valid_pixels.get(o.instance_id, 0) >= MIN_GT_DEPTH_PIXELS
    ]


def nocs_image_result(
    ground_truth: Sequence[tuple[int, Pose9D, bool]], predictions: Sequence[tuple[int, Pose9D, float]]
) -> dict[str, np.ndarray]:
    """One image's result dict in the NOCS / SPD format (docs/metrics.md) for `compute_nocs_map`.

    Args:
        ground_truth: (class id, pose, handle visible) per ground-truth object.
        predictions: (class id, pose, score) per prediction.
    """
    g = [p.to_nocs_sRT() for _, p, _ in ground_truth]
    q = [p.to_nocs_sRT() for _, p, _ in predictions]
    return {
        "gt_class_ids": np.array([c for c, _, _ in ground_truth], dtype=np.int64),
        "gt_RTs": np.array([a for a, _ in g], dtype=np.float64).reshape(-1, 4, 4),
        "gt_scales": np.array([b for _, b in g], dtype=np.float64).reshape(-1, 3),
        "gt_handle_visibility": np.array([int(h) for _, _, h in ground_truth], dtype=np.int64),
        "pred_class_ids": np.array([c for c, _, _ in predictions], dtype=np.int64),
        "pred_scores": np.array([s for _, _, s in predictions], dtype=np.float64),
        "pred_RTs": np.array([a for a, _ in q], dtype=np.float64).reshape(-1, 4, 4),
        "pred_scales": np.array([b for _, b in q], dtype=np.float64).reshape(-1, 3),
    }


def nocs_tables(
    per_image: Mapping[str, Sequence[Mapping[str, Any]]],
    synset_names: Sequence[str],
    y_symmetric_classes: Collection[str],
) -> dict[str, dict[str, Any]]:
    """{method: {iou mode: `compute_nocs_map` table}} for the synthetic benchmarks: every IoU mode, mugs
    without a visible handle counted as y-symmetric (NOCS protocol), classes without ground truth skipped."""
    return {
        method: {
            mode: compute_nocs_map(
                results,
                synset_names=synset_names,
                iou_mode=mode,
                y_symmetric_classes=y_symmetric_classes,
                handle_classes=("mug",),
                classes_without_gt="skip",
            )
            for mode in IOU_MODES
        }
        for method, results in per_image.items()
    }
