"""Evaluation: NOCS-compatible 9-DoF pose metrics (3D IoU and n-degree m-cm mAP) and report tables.

Typical use on the per-image result pickles written by the public NOCS / SPD evaluation code::

    from prompose_grasp.eval import compute_nocs_map, format_nocs_table, load_nocs_results

    results = load_nocs_results(["results/eval_real"])
    table = compute_nocs_map(results, iou_mode="nocs")  # "aligned" / "exact": corrected IoUs
    print(format_nocs_table(table, title="REAL275"))

See docs/metrics.md for the protocol and the three IoU modes.
"""

from typing import TYPE_CHECKING

from prompose_grasp._lazy import attach

if TYPE_CHECKING:  # what the lazy attributes below resolve to, for type checkers and readers
    from prompose_grasp.eval.nocs import (
        DEGREE_THRESHOLDS,
        IOU_MODES,
        IOU_THRESHOLDS,
        NOCS_METRIC_KEYS,
        NOCS_SYNSET_NAMES,
        SHIFT_THRESHOLDS_CM,
        NocsAPCurves,
        compute_nocs_map,
        nocs_ap_curves,
        nocs_box_iou,
        nocs_pose_error,
        voc_average_precision,
    )
    from prompose_grasp.eval.nocs_results import (
        NOCS_RESULT_KEYS,
        NocsImageResult,
        load_nocs_results,
        split_sRT,
    )
    from prompose_grasp.eval.report import format_nocs_table

__getattr__, __dir__ = attach(
    __name__,
    {
        "prompose_grasp.eval.nocs": (
            "DEGREE_THRESHOLDS",
            "IOU_MODES",
            "IOU_THRESHOLDS",
            "NOCS_METRIC_KEYS",
            "NOCS_SYNSET_NAMES",
            "SHIFT_THRESHOLDS_CM",
            "NocsAPCurves",
            "compute_nocs_map",
            "nocs_ap_curves",
            "nocs_box_iou",
            "nocs_pose_error",
            "voc_average_precision",
        ),
        "prompose_grasp.eval.nocs_results": (
            "NOCS_RESULT_KEYS",
            "NocsImageResult",
            "load_nocs_results",
            "split_sRT",
        ),
        "prompose_grasp.eval.report": ("format_nocs_table",),
    },
    submodules=(
        "baselines",
        "bench_estimator",
        "bench_fit",
        "bench_network",
        "nocs",
        "nocs_results",
        "report",
        "synthetic",
    ),
)

__all__ = [
    "DEGREE_THRESHOLDS",
    "IOU_MODES",
    "IOU_THRESHOLDS",
    "NOCS_METRIC_KEYS",
    "NOCS_RESULT_KEYS",
    "NOCS_SYNSET_NAMES",
    "SHIFT_THRESHOLDS_CM",
    "NocsAPCurves",
    "NocsImageResult",
    "compute_nocs_map",
    "format_nocs_table",
    "load_nocs_results",
    "nocs_ap_curves",
    "nocs_box_iou",
    "nocs_pose_error",
    "split_sRT",
    "voc_average_precision",
]
