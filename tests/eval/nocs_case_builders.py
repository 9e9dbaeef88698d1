"""Builders for NOCS result dicts used by the eval tests (hand-built cases and seeded random ones)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

NOCS_NAMES = ("BG", "bottle", "bowl", "camera", "can", "laptop", "mug")


def sRT(s: float, t, R=None) -> np.ndarray:
    """(4, 4) [s R | t; 0 0 0 1]."""
    M = np.eye(4)
    M[:3, :3] = s * (np.eye(3) if R is None else np.asarray(R, dtype=float))
    M[:3, 3] = t
    return M


def Ry(deg: float) -> np.ndarray:
    return Rotation.from_euler("y", deg, degrees=True).as_matrix()


def result(gt=(), pred=()) -> dict:
    """A result dict from lists of instances.

    gt: [(class_id, sRT, scales, handle_visibility)], pred: [(class_id, sRT, scales, score)].
    """
    return {
        "gt_class_ids": np.array([g[0] for g in gt], dtype=np.int32),
        "gt_RTs": np.array([g[1] for g in gt], dtype=np.float64).reshape(-1, 4, 4),
        "gt_scales": np.array([g[2] for g in gt], dtype=np.float64).reshape(-1, 3),
        "gt_handle_visibility": np.array([g[3] for g in gt], dtype=np.int64),
        "pred_class_ids": np.array([p[0] for p in pred], dtype=np.int32),
        "pred_scores": np.array([p[3] for p in pred], dtype=np.float32),
        "pred_RTs": np.array([p[1] for p in pred], dtype=np.float64).reshape(-1, 4, 4),
        "pred_scales": np.array([p[2] for p in pred], dtype=np.float64).reshape(-1, 3),
    }


def random_results(rng: np.random.Generator, num_images: int, num_classes: int = 7) -> list[dict]:
    """Seeded scenes with near and far predictions, misses, false positives, hidden mug handles and tied
    scores, so that IoUs and pose errors fall on both sides of every reported threshold."""
    results = []
    for _ in range(num_images):
        gt, pred = [], []
        for _ in range(rng.integers(0, 5)):
            cls = int(rng.integers(1, num_classes))
            R = Rotation.random(random_state=rng).as_matrix()
            t = rng.uniform([-0.2, -0.15, 0.5], [0.2, 0.15, 1.2])
            s = rng.uniform(0.1, 0.3)
            scales = rng.uniform(0.3, 0.9, 3)
            gt.append((cls, sRT(s, t, R), scales, int(rng.random() < 0.5)))
            for _ in range(rng.integers(0, 3)):  # 0, 1 or 2 detections of this object
                dR = Rotation.from_rotvec(rng.normal(size=3) * np.radians(rng.uniform(0, 12))).as_matrix()
                spin = Ry(rng.uniform(0, 360)) if rng.random() < 0.3 else np.eye(3)
                dt = rng.normal(size=3) * rng.uniform(0, 0.03)
                ds = np.exp(rng.normal(scale=0.1))
                score = round(float(rng.uniform(0.3, 1.0)), 1)  # one decimal: many ties
                pred.append(
                    (cls, sRT(s * ds, t + dt, dR @ R @ spin), scales * rng.uniform(0.9, 1.1, 3), score)
                )
        for _ in range(rng.integers(0, 2)):  # false positives, some near an object of another class
            cls = int(rng.integers(1, num_classes))
            R = Rotation.random(random_state=rng).as_matrix()
            t = rng.uniform([-0.2, -0.15, 0.5], [0.2, 0.15, 1.2])
            pred.append((cls, sRT(rng.uniform(0.1, 0.3), t, R), rng.uniform(0.3, 0.9, 3), 0.5))
        results.append(result(gt, pred))
    return results
