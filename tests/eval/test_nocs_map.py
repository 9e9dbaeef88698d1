"""NOCS mAP: hand-built cases whose AP is known by construction, an independent loop-based statement of the
protocol on seeded random scenes, the handling of classes without ground truth, and input errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from nocs_case_builders import NOCS_NAMES, Ry, random_results, result, sRT

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.eval import (
    IOU_MODES,
    NOCS_METRIC_KEYS,
    compute_nocs_map,
    nocs_ap_curves,
    voc_average_precision,
)
from prompose_grasp.geometry.boxes import oriented_box_iou

# AP of hand-built cases is a ratio of small integers; the float32 recall of the reference (kept on purpose)
# rounds it by ~1e-7 relative, i.e. 1e-5 percentage points.
AP_TOL = 1e-4
IOU_KEYS = ("3D25", "3D50", "3D75")
POSE_KEYS = ("5deg2cm", "5deg5cm", "10deg2cm", "10deg5cm")

CAMERA, BOTTLE, MUG = 3, 1, 6
SCALES = np.array([0.5, 0.8, 0.5])  # x = z: a spin about y leaves the box (as a set) unchanged


def _row(table, name=None):
    return table["mean"] if name is None else table["per_class"][name]


def _assert_row(row, expected: dict):
    for key, value in expected.items():
        assert row[key] == pytest.approx(value, abs=AP_TOL), key


# ------------------------------------------------------------------------------------------ VOC AP


def test_voc_ap_by_hand():
    # Ranked hits T F T with 3 GTs: precision 1, 1/2, 2/3 at recall 1/3, 1/3, 2/3; the monotone envelope
    # is 1, 2/3, 2/3; AP = 1/3 * 1 + 1/3 * 2/3 = 5/9 (the third GT is never found: recall step to 1 at 0).
    ap = voc_average_precision([True, False, True], [0.9, 0.8, 0.7], num_gt=3)
    assert ap == pytest.approx(5 / 9, abs=1e-7)  # float32 recall, as the reference
    # The ranking is by score, not by position.
    assert voc_average_precision([True, True, False], [0.9, 0.7, 0.8], 3) == pytest.approx(5 / 9, abs=1e-7)


def test_voc_ap_edge_cases():
    assert voc_average_precision(np.zeros((2, 0), bool), np.zeros(0), 4).tolist() == [0.0, 0.0]
    assert voc_average_precision([False, False], [0.5, 0.4], 2) == 0.0
    assert math.isnan(float(voc_average_precision([False], [0.5], 0)))  # the reference's 0 / 0 recall
    assert voc_average_precision([[True, True], [True, False]], [0.2, 0.9], 2).tolist() == pytest.approx(
        [1.0, 0.25],
        abs=1e-7,  # float32 recall; second row: 1 of 2 GTs found at rank 2, precision 1/2 at recall 1/2
    )
    with pytest.raises(InvalidInputError, match="shape"):
        voc_average_precision([True, False], [0.5], 2)


# ------------------------------------------------------------------------------------- hand-built AP


def _perfect_scene(rng: np.random.Generator) -> dict:
    gt, pred = [], []
    for cls in range(1, 7):
        M = sRT(
            rng.uniform(0.1, 0.3),
            [rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(0.5, 1.5)],
            Ry(rng.uniform(0, 360)),
        )
        scales = rng.uniform(0.3, 0.9, 3)
        gt.append((cls, M, scales, int(rng.integers(0, 2))))
        pred.append((cls, M, scales, float(rng.uniform(0.2, 1.0))))
    return result(gt, pred)


@pytest.mark.parametrize("mode", IOU_MODES)
def test_perfect_predictions_score_100_everywhere(mode):
    rng = np.random.default_rng(10)
    table = compute_nocs_map([_perfect_scene(rng) for _ in range(3)], iou_mode=mode)
    for name in NOCS_NAMES[1:]:
        _assert_row(_row(table, name), dict.fromkeys(NOCS_METRIC_KEYS, 100.0))
    _assert_row(_row(table), dict.fromkeys(NOCS_METRIC_KEYS, 100.0))


def test_half_the_objects_detected():
    # 4 cameras over 2 images, 2 found exactly: precision 1 up to recall 1/2, so 3D AP = 50. Pose AP only
    # counts the detections matched at IoU > 0.1, which are all exact: 100.
    objects = [sRT(0.2, [x, 0.0, 0.8]) for x in (-0.3, 0.3)]
    images = [
        result(
            gt=[(1, M, SCALES, 1) for M in objects],
            pred=[(1, objects[0], SCALES, 0.9)],
        )
        for _ in range(2)
    ]
    table = compute_nocs_map(images, synset_names=("BG", "camera"), iou_mode="aligned")
    expected = {**dict.fromkeys(IOU_KEYS, 50.0), **dict.fromkeys(POSE_KEYS, 100.0)}
    _assert_row(_row(table, "camera"), expected)
    _assert_row(_row(table), expected)


def test_false_positive_scored_above_the_true_positive():
    # A far-away false positive outranks the exact detection: precision 1/2 at recall 1, AP = 50 on every
    # IoU threshold. It never matches at IoU > 0.1, so the pose AP sees only the exact one: 100. (It sits
    # 2.2 m behind: the reference IoU of a box 50 cm to the side would pass 3D25.)
    gt = sRT(0.2, [0.0, 0.0, 0.8])
    image = result(
        gt=[(1, gt, SCALES, 1)],
        pred=[(1, sRT(0.2, [0.0, 0.0, 3.0]), SCALES, 0.9), (1, gt, SCALES, 0.8)],
    )
    for mode in IOU_MODES:
        table = compute_nocs_map([image], synset_names=("BG", "camera"), iou_mode=mode)
        _assert_row(_row(table), {**dict.fromkeys(IOU_KEYS, 50.0), **dict.fromkeys(POSE_KEYS, 100.0)})


def test_loose_detection_scored_above_the_exact_one():
    # Box 6 cm wide, the higher-scored detection shifted 3 cm sideways: corrected IoU exactly 1/3. At 0.25
    # it takes the GT first (hit, then a false positive: AP 100); at 0.5 and 0.75 it misses and the exact
    # detection matches second (AP 50). It also takes the GT at the 0.1 gate, so the pose AP is that of
    # a 0 deg, 3 cm error: 0 at 2 cm, 100 at 5 cm.
    scales = np.array([0.3, 0.8, 0.5])
    gt = sRT(0.2, [0.0, 0.0, 0.8])
    image = result(
        gt=[(1, gt, scales, 1)],
        pred=[(1, sRT(0.2, [0.03, 0.0, 0.8]), scales, 0.9), (1, gt, scales, 0.8)],
    )
    expected = {"3D25": 100.0, "3D50": 50.0, "3D75": 50.0}
    expected.update({"5deg2cm": 0.0, "5deg5cm": 100.0, "10deg2cm": 0.0, "10deg5cm": 100.0})
    for mode in ("aligned", "exact"):
        _assert_row(_row(compute_nocs_map([image], ("BG", "camera"), mode)), expected)


def test_reference_iou_inflates_a_loose_detection():
    # The fact: a 5 cm sideways copy of the (0.5, 0.8, 0.5) x 0.2 box at 0.8 m has nocs IoU 0.8157
    # (corrected: 1/3). Scored above the exact copy, it takes the GT at every IoU threshold in nocs mode.
    gt = sRT(0.2, [0.0, 0.0, 0.8])
    image = result(
        gt=[(1, gt, SCALES, 1)],
        pred=[(1, sRT(0.2, [0.05, 0.0, 0.8]), SCALES, 0.9), (1, gt, SCALES, 0.8)],
    )
    nocs = _row(compute_nocs_map([image], ("BG", "camera"), "nocs"))
    aligned = _row(compute_nocs_map([image], ("BG", "camera"), "aligned"))
    _assert_row(nocs, {"3D25": 100.0, "3D50": 100.0, "3D75": 100.0})
    _assert_row(aligned, {"3D25": 100.0, "3D50": 50.0, "3D75": 50.0})


def _spun_scene(class_id: int, handle_visibility: int, scales=SCALES) -> dict:
    gt = sRT(0.2, [0.05, -0.02, 0.9], Ry(30))
    spun = gt.copy()
    spun[:3, :3] = spun[:3, :3] @ Ry(90)
    return result(gt=[(class_id, gt, scales, handle_visibility)], pred=[(class_id, spun, scales, 0.9)])


def test_symmetric_class_spun_about_y_still_counts():
    # A bottle detected with the right box but spun 90 deg about its axis: the y axes agree (0 deg), and
    # the best IoU over spins about y is 1, even for x != z extents.
    for scales in (SCALES, np.array([0.3, 0.8, 0.5])):
        for mode in IOU_MODES:
            table = compute_nocs_map(
                [_spun_scene(BOTTLE, 1, scales)], iou_mode=mode, classes_without_gt="skip"
            )
            _assert_row(_row(table, "bottle"), dict.fromkeys(NOCS_METRIC_KEYS, 100.0))


def test_asymmetric_class_spun_90_degrees_fails_the_degree_metrics():
    # Same spin for a camera: the box is unchanged as a set (x = z), so every 3D IoU metric holds, but the
    # rotation error is 90 deg.
    for mode in ("aligned", "exact"):
        table = compute_nocs_map([_spun_scene(CAMERA, 1)], iou_mode=mode, classes_without_gt="skip")
        _assert_row(
            _row(table, "camera"), {**dict.fromkeys(IOU_KEYS, 100.0), **dict.fromkeys(POSE_KEYS, 0.0)}
        )


def test_mug_is_symmetric_only_when_its_handle_is_hidden():
    hidden = compute_nocs_map([_spun_scene(MUG, 0)], iou_mode="aligned", classes_without_gt="skip")
    visible = compute_nocs_map([_spun_scene(MUG, 1)], iou_mode="aligned", classes_without_gt="skip")
    _assert_row(_row(hidden, "mug"), dict.fromkeys(NOCS_METRIC_KEYS, 100.0))
    _assert_row(_row(visible, "mug"), {**dict.fromkeys(IOU_KEYS, 100.0), **dict.fromkeys(POSE_KEYS, 0.0)})


def test_predictions_of_another_class_do_not_match():
    gt = sRT(0.2, [0.0, 0.0, 0.8])
    image = result(gt=[(CAMERA, gt, SCALES, 1)], pred=[(BOTTLE, gt, SCALES, 0.9)])
    table = compute_nocs_map([image], iou_mode="aligned")
    _assert_row(_row(table, "camera"), dict.fromkeys(NOCS_METRIC_KEYS, 0.0))
    # Predictions but no GT: the reference's 0 / 0 recall gives NaN for 3D IoU AP; no bottle passes the
    # IoU gate, so the pose AP has neither predictions nor GTs: 0.
    assert all(math.isnan(_row(table, "bottle")[k]) for k in IOU_KEYS)
    assert all(_row(table, "bottle")[k] == 0.0 for k in POSE_KEYS)


# ------------------------------------------------------------------------------ classes without GT


def test_classes_without_gt_reference_and_skip():
    gt = sRT(0.2, [0.0, 0.0, 0.8])
    only_cameras = [result(gt=[(CAMERA, gt, SCALES, 1)], pred=[(CAMERA, gt, SCALES, 0.9)])]
    reference = compute_nocs_map(only_cameras, iou_mode="aligned")
    # The reference averages all six classes, the five empty ones at AP 0.
    _assert_row(_row(reference), dict.fromkeys(NOCS_METRIC_KEYS, 100.0 / 6))
    assert _row(reference, "bowl") == dict.fromkeys(NOCS_METRIC_KEYS, 0.0)
    skip = compute_nocs_map(only_cameras, iou_mode="aligned", classes_without_gt="skip")
    _assert_row(_row(skip), dict.fromkeys(NOCS_METRIC_KEYS, 100.0))
    assert all(math.isnan(v) for v in _row(skip, "bowl").values())
    # A prediction of a class without GT: the reference's 0 / 0 recall makes that class's 3D AP, and so
    # the mean, NaN; its pose AP (nothing passes the IoU gate) is 0.
    with_fp = [result(gt=[(CAMERA, gt, SCALES, 1)], pred=[(CAMERA, gt, SCALES, 0.9), (2, gt, SCALES, 0.5)])]
    reference = compute_nocs_map(with_fp, iou_mode="aligned")
    assert all(math.isnan(_row(reference)[k]) for k in IOU_KEYS)
    _assert_row(_row(reference), dict.fromkeys(POSE_KEYS, 100.0 / 6))
    skip = compute_nocs_map(with_fp, iou_mode="aligned", classes_without_gt="skip")
    _assert_row(_row(skip), dict.fromkeys(NOCS_METRIC_KEYS, 100.0))


def test_curves_count_instances():
    rng = np.random.default_rng(11)
    curves = nocs_ap_curves([_perfect_scene(rng) for _ in range(2)], iou_mode="aligned")
    assert curves.class_names == NOCS_NAMES[1:]
    assert curves.num_gt.tolist() == [2] * 6 and curves.num_pred.tolist() == [2] * 6
    assert curves.num_pose_gt.tolist() == [2] * 6
    assert curves.iou_ap.shape == (6, 101) and curves.pose_ap.shape == (6, 62, 32)
    # Exact boxes match above every IoU threshold below 1 (and not at 1: strictly greater is required).
    np.testing.assert_allclose(curves.iou_ap[:, :100], 1.0, atol=1e-7)  # float32 recall
    np.testing.assert_array_equal(curves.iou_ap[:, 100], 0.0)


# --------------------------------------------------------------------- independent protocol statement


def _h(R):
    M = np.eye(4)
    M[:3, :3] = R
    return M


def _oracle_iou(mode, sRT_p, sc_p, sRT_g, sc_g, symmetric):
    signs = np.array(
        [[1, 1, 1], [1, 1, -1], [-1, 1, 1], [-1, 1, -1], [1, -1, 1], [1, -1, -1], [-1, -1, 1], [-1, -1, -1]],
        float,
    )

    def one(M):
        if mode == "exact":
            s_p, s_g = np.cbrt(np.linalg.det(M[:3, :3])), np.cbrt(np.linalg.det(sRT_g[:3, :3]))
            R_p, R_g = M[:3, :3] / s_p, sRT_g[:3, :3] / s_g
            return oriented_box_iou(R_p, M[:3, 3], s_p * sc_p, R_g, sRT_g[:3, 3], s_g * sc_g)
        a = (M @ np.vstack([(signs * sc_p / 2).T, np.ones((1, 8))]))[:3]
        b = (sRT_g @ np.vstack([(signs * sc_g / 2).T, np.ones((1, 8))]))[:3]
        axis = 0 if mode == "nocs" else 1
        a_max, a_min, b_max, b_min = a.max(axis), a.min(axis), b.max(axis), b.min(axis)
        lo, hi = np.maximum(a_min, b_min), np.minimum(a_max, b_max)
        inter = 0.0 if np.min(hi - lo) < 0 else np.prod(hi - lo)
        return inter / (np.prod(a_max - a_min) + np.prod(b_max - b_min) - inter)

    spins = [Ry(360.0 * k / 20) for k in range(20)] if symmetric else [np.eye(3)]
    best = 0.0
    for R in spins:
        best = max(best, one(sRT_p @ _h(R)))
    return best


def _oracle_errors(sRT_p, sRT_g, symmetric):
    R_p = sRT_p[:3, :3] / np.cbrt(np.linalg.det(sRT_p[:3, :3]))
    R_g = sRT_g[:3, :3] / np.cbrt(np.linalg.det(sRT_g[:3, :3]))
    if symmetric:
        y_p, y_g = R_p[:, 1], R_g[:, 1]
        cos = y_p @ y_g / (np.linalg.norm(y_p) * np.linalg.norm(y_g))
    else:
        cos = (np.trace(R_p @ R_g.T) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1, 1))), 100 * np.linalg.norm(sRT_p[:3, 3] - sRT_g[:3, 3])


def _oracle_ap(hits, scores, num_gt):
    order = np.argsort(np.asarray(scores, dtype=float))[::-1]
    precision, recall, tp = [0.0], [0.0], 0
    for rank, k in enumerate(order, start=1):
        tp += bool(hits[k])
        precision.append(tp / rank)
        recall.append(tp / num_gt if num_gt else math.nan)
    precision.append(0.0)
    recall.append(1.0)
    for k in range(len(precision) - 2, -1, -1):
        precision[k] = max(precision[k], precision[k + 1])
    return sum(
        (recall[k] - recall[k - 1]) * precision[k]
        for k in range(1, len(recall))
        if recall[k] != recall[k - 1]
    )


def _oracle_map(results, names, mode):
    """The protocol of the reference code, one loop at a time, at the reported thresholds only."""
    iou_thresholds = {"gate": 0.1, "3D25": 0.25, "3D50": 0.5, "3D75": 0.75}
    pose_thresholds = {"5deg2cm": (5, 2), "5deg5cm": (5, 5), "10deg2cm": (10, 2), "10deg5cm": (10, 5)}
    per_class = {}
    for c in range(1, len(names)):
        hits = {k: [] for k in [*iou_thresholds, *pose_thresholds]}
        scores = {"iou": [], "pose": []}
        num_gt = num_pose_gt = 0
        for r in results:
            g_idx = [j for j, cid in enumerate(r["gt_class_ids"]) if cid == c]
            p_idx = [i for i, cid in enumerate(r["pred_class_ids"]) if cid == c]
            p_idx = [p_idx[k] for k in np.argsort(np.asarray(r["pred_scores"])[p_idx])[::-1]]
            sym = [
                names[c] in ("bottle", "bowl", "can")
                or (names[c] == "mug" and r["gt_handle_visibility"][j] == 0)
                for j in g_idx
            ]
            iou = np.array(
                [
                    [
                        _oracle_iou(
                            mode,
                            r["pred_RTs"][i],
                            r["pred_scales"][i],
                            r["gt_RTs"][j],
                            r["gt_scales"][j],
                            sym[b],
                        )
                        for b, j in enumerate(g_idx)
                    ]
                    for i in p_idx
                ]
            ).reshape(len(p_idx), len(g_idx))
            num_gt += len(g_idx)
            scores["iou"] += [float(r["pred_scores"][i]) for i in p_idx]
            gate_pred, gate_gt = [], []
            for key, thr in iou_thresholds.items():
                taken = set()
                for a in range(len(p_idx)):
                    hit = False
                    for b in sorted(range(len(g_idx)), key=lambda b: -iou[a, b]):
                        if b in taken:
                            continue
                        if iou[a, b] > thr:
                            taken.add(b)
                            hit = True
                        break  # only the best unmatched GT is tried
                    hits[key].append(hit)
                    if key == "gate" and hit:
                        gate_pred.append(a)
                if key == "gate":
                    gate_gt = sorted(taken)
            num_pose_gt += len(gate_gt)
            scores["pose"] += [float(r["pred_scores"][p_idx[a]]) for a in gate_pred]
            err = {
                (a, b): _oracle_errors(r["pred_RTs"][p_idx[a]], r["gt_RTs"][g_idx[b]], sym[b])
                for a in gate_pred
                for b in gate_gt
            }
            for key, (deg_thr, cm_thr) in pose_thresholds.items():
                taken = set()
                for a in gate_pred:
                    hit = False
                    for b in sorted(gate_gt, key=lambda b: sum(err[a, b])):
                        if b not in taken and err[a, b][0] <= deg_thr and err[a, b][1] <= cm_thr:
                            taken.add(b)
                            hit = True
                            break
                    hits[key].append(hit)
        per_class[names[c]] = {
            **{k: 100 * _oracle_ap(hits[k], scores["iou"], num_gt) for k in IOU_KEYS},
            **{k: 100 * _oracle_ap(hits[k], scores["pose"], num_pose_gt) for k in POSE_KEYS},
        }
    mean = {k: float(np.mean([per_class[n][k] for n in names[1:]])) for k in NOCS_METRIC_KEYS}
    return {"mean": mean, "per_class": per_class}


@pytest.mark.parametrize(("mode", "num_images"), [("nocs", 60), ("aligned", 60), ("exact", 15)])
def test_matches_loop_statement_of_the_protocol_on_random_scenes(mode, num_images):
    results = random_results(np.random.default_rng(12), num_images)
    expected = _oracle_map(results, NOCS_NAMES, mode)
    table = compute_nocs_map(results, iou_mode=mode)
    assert set(table["per_class"]) == set(NOCS_NAMES[1:])
    for name in NOCS_NAMES[1:]:
        _assert_row(_row(table, name), expected["per_class"][name])
    _assert_row(_row(table), expected["mean"])
    # The scenes are not trivial: metrics differ from each other and from 0 and 100.
    values = [v for row in table["per_class"].values() for v in row.values()]
    assert len({round(v, 3) for v in values}) > 10


# ----------------------------------------------------------------------------------------- errors


def _valid():
    gt = sRT(0.2, [0.0, 0.0, 0.8])
    return result(gt=[(CAMERA, gt, SCALES, 1)], pred=[(CAMERA, gt, SCALES, 0.9)])


def test_unknown_iou_mode_lists_the_modes():
    with pytest.raises(UnknownNameError, match=r"unknown IoU mode 'obb'; known: nocs, aligned, exact"):
        compute_nocs_map([_valid()], iou_mode="obb")
    with pytest.raises(UnknownNameError, match="reference, skip"):
        compute_nocs_map([_valid()], classes_without_gt="drop")


def test_missing_key_is_named():
    bad = _valid()
    del bad["pred_RTs"]
    with pytest.raises(InvalidInputError, match=r"result 1: missing key\(s\) pred_RTs"):
        compute_nocs_map([_valid(), bad])


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("pred_RTs", np.zeros((1, 3, 4)), r"'pred_RTs' must have shape \(1, 4, 4\)"),
        ("gt_scales", np.ones((2, 3)), r"'gt_scales' must have shape \(1, 3\)"),
        ("pred_scores", np.array([np.nan]), "finite"),
        ("gt_class_ids", np.array([1.5]), "integer class indices"),
        ("pred_class_ids", np.array([9]), "synset list has 7 names"),
        ("gt_handle_visibility", np.ones(3), r"'gt_handle_visibility' must have shape \(1,\)"),
        ("pred_scales", -np.ones((1, 3)), "> 0"),
    ],
)
def test_malformed_results_are_rejected(key, value, message):
    bad = _valid()
    bad[key] = value
    with pytest.raises(InvalidInputError, match=message):
        compute_nocs_map([bad])


def test_empty_and_single_dict_inputs_are_rejected():
    with pytest.raises(InvalidInputError, match="empty"):
        compute_nocs_map([])
    with pytest.raises(InvalidInputError, match="single dict"):
        compute_nocs_map(_valid())
    with pytest.raises(InvalidInputError, match="synset_names"):
        compute_nocs_map([_valid()], synset_names="BG")


def test_handle_visibility_is_optional_and_images_may_be_empty():
    no_handle = _valid()
    del no_handle["gt_handle_visibility"]
    empty = result()
    table = compute_nocs_map([no_handle, empty], iou_mode="aligned", classes_without_gt="skip")
    _assert_row(_row(table), dict.fromkeys(NOCS_METRIC_KEYS, 100.0))
