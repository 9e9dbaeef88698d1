"""Evaluate NOCS-format result pickles with prompose_grasp.eval.

Builds a few per-image result dicts in the format the public NOCS / SPD evaluation code writes (one pickle
per image), saves them to a temporary folder, reads them back and prints the NOCS mAP table in the three IoU
modes.
Run:  python examples/eval_nocs_pickles.py

The same folder can be evaluated from the shell:
    prompose-grasp eval-nocs RESULTS_DIR --iou-mode nocs --json out.json
"""

from __future__ import annotations

import pickle
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from prompose_grasp.eval import (
    IOU_MODES,
    NOCS_SYNSET_NAMES,
    compute_nocs_map,
    format_nocs_table,
    load_nocs_results,
)

rng = np.random.default_rng(0)


def make_sRT(scale: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[s R | t; 0 0 0 1]: NOCS box frame -> camera frame, as the result dicts store poses."""
    sRT = np.eye(4)
    sRT[:3, :3] = scale * R
    sRT[:3, 3] = t
    return sRT


def make_image(num_objects: int) -> dict:
    """One image: each object detected with noise (2-10 deg, 0.5-3 cm, 10 % scale), and a false positive."""
    gt_ids, gt_RTs, gt_scales, handle = [], [], [], []
    pred_ids, pred_RTs, pred_scales, scores = [], [], [], []
    for _ in range(num_objects):
        class_id = int(rng.integers(1, len(NOCS_SYNSET_NAMES)))
        # Objects stand upright on a table in front of the camera (OpenCV camera: y down, so "up" is -y).
        R = Rotation.from_euler(
            "xy", [180 + rng.uniform(-20, 20), rng.uniform(0, 360)], degrees=True
        ).as_matrix()
        t = np.array([rng.uniform(-0.2, 0.2), rng.uniform(0.0, 0.1), rng.uniform(0.6, 1.0)])
        scales = rng.uniform(0.3, 0.9, 3)
        scales /= np.linalg.norm(scales)  # NOCS box extents: the box diagonal is 1
        scale = rng.uniform(0.12, 0.3)  # s: the metric box diagonal [m]; the metric size is s * scales
        gt_ids.append(class_id)
        gt_RTs.append(make_sRT(scale, R, t))
        gt_scales.append(scales)
        handle.append(
            int(rng.random() < 0.7)
        )  # 0: the mug's handle is hidden, so the mug counts as symmetric

        axis = rng.normal(size=3)
        dR = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(rng.uniform(2, 10))).as_matrix()
        dt = rng.normal(size=3)
        dt *= rng.uniform(0.005, 0.03) / np.linalg.norm(dt)
        pred_ids.append(class_id)
        pred_RTs.append(make_sRT(scale * rng.uniform(0.9, 1.1), dR @ R, t + dt))
        pred_scales.append(scales)
        scores.append(rng.uniform(0.5, 1.0))
    # A false positive: a confident detection where there is no object.
    pred_ids.append(int(rng.integers(1, len(NOCS_SYNSET_NAMES))))
    pred_RTs.append(make_sRT(0.15, np.eye(3), np.array([0.3, -0.2, 1.4])))
    pred_scales.append(np.array([0.5, 0.8, 0.5]))
    scores.append(0.6)
    return {
        "gt_class_ids": np.array(gt_ids, dtype=np.int32),
        "gt_RTs": np.array(gt_RTs),
        "gt_scales": np.array(gt_scales),
        "gt_handle_visibility": np.array(handle),
        "pred_class_ids": np.array(pred_ids, dtype=np.int32),
        "pred_scores": np.array(scores, dtype=np.float32),
        "pred_RTs": np.array(pred_RTs),
        "pred_scales": np.array(pred_scales),
    }


with tempfile.TemporaryDirectory() as tmp:
    results_dir = Path(tmp)
    for k in range(20):
        with open(results_dir / f"results_{k:04d}.pkl", "wb") as f:
            pickle.dump(make_image(num_objects=int(rng.integers(2, 6))), f)

    results = load_nocs_results([results_dir])
    print(f"read {len(results)} result pickles from {results_dir}\n")
    for mode in IOU_MODES:
        table = compute_nocs_map(results, iou_mode=mode)
        print(format_nocs_table(table, title=f"iou_mode={mode}"))
        print()
    print(
        "mean 3D50 by mode:",
        {m: round(compute_nocs_map(results, iou_mode=m)["mean"]["3D50"], 1) for m in IOU_MODES},
    )
