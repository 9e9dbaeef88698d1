"""Reading NOCS result pickles, the plain-text table, and the `prompose-grasp eval-nocs` command."""

from __future__ import annotations

import json
import logging
import math
import pickle

import numpy as np
import pytest
from nocs_case_builders import random_results, result, sRT

from prompose_grasp.cli import main
from prompose_grasp.errors import InvalidInputError
from prompose_grasp.eval import NOCS_METRIC_KEYS, compute_nocs_map, format_nocs_table, load_nocs_results

SCALES = np.array([0.5, 0.8, 0.5])


def _write(path, obj):
    with open(path, "wb") as f:
        pickle.dump(obj, f)
    return path


def _tagged(k: int) -> dict:
    r = result(
        gt=[(3, sRT(0.2, [0.0, 0.0, 0.8]), SCALES, 1)], pred=[(3, sRT(0.2, [0.0, 0.0, 0.8]), SCALES, 0.5)]
    )
    r["image_path"] = f"scene_{k}"  # extra keys are kept and ignored, as in the reference's pickles
    return r


def test_folder_is_read_in_sorted_name_order(tmp_path):
    for k in (2, 0, 1):
        _write(tmp_path / f"results_{k:04d}.pkl", _tagged(k))
    loaded = load_nocs_results([tmp_path])
    assert [r["image_path"] for r in loaded] == ["scene_0", "scene_1", "scene_2"]


def test_files_keep_the_given_order_and_lists_are_flattened(tmp_path):
    a = _write(tmp_path / "a.pkl", _tagged(0))
    b = _write(tmp_path / "b.pkl", [_tagged(1), _tagged(2)])
    loaded = load_nocs_results([str(b), a])
    assert [r["image_path"] for r in loaded] == ["scene_1", "scene_2", "scene_0"]
    assert [r["image_path"] for r in load_nocs_results(a)] == ["scene_0"]  # one path on its own


def test_loaded_results_evaluate_like_the_originals(tmp_path):
    results = random_results(np.random.default_rng(20), 12)
    for k, r in enumerate(results):
        _write(tmp_path / f"results_{k:03d}.pkl", r)
    loaded = load_nocs_results([tmp_path])
    assert compute_nocs_map(loaded, iou_mode="aligned") == compute_nocs_map(results, iou_mode="aligned")


def test_reference_summaries_in_a_folder_are_skipped(tmp_path, caplog):
    # The reference code writes mAP_Acc.pkl next to the per-image results.
    _write(tmp_path / "results_0.pkl", _tagged(0))
    _write(tmp_path / "mAP_Acc.pkl", {"iou_thres_list": [0.1], "iou_aps": np.zeros((8, 1))})
    with caplog.at_level(logging.WARNING, logger="prompose_grasp.eval"):
        loaded = load_nocs_results([tmp_path])
    assert len(loaded) == 1
    assert "mAP_Acc.pkl holds no NOCS per-image result dicts" in caplog.text
    # Named explicitly, the same file is an error.
    with pytest.raises(InvalidInputError, match="missing key"):
        load_nocs_results([tmp_path / "mAP_Acc.pkl"])


def test_loader_errors(tmp_path):
    with pytest.raises(InvalidInputError, match="holds no"):
        load_nocs_results([tmp_path])
    with pytest.raises(InvalidInputError, match="no such file or folder"):
        load_nocs_results([tmp_path / "absent.pkl"])
    with pytest.raises(InvalidInputError, match="no result paths"):
        load_nocs_results([])
    (tmp_path / "broken.pkl").write_bytes(b"not a pickle")
    with pytest.raises(InvalidInputError, match="not a readable pickle"):
        load_nocs_results([tmp_path / "broken.pkl"])
    with pytest.raises(InvalidInputError, match="expected a dict"):
        load_nocs_results([_write(tmp_path / "number.pkl", 42)])
    bad = _tagged(0)
    bad["pred_RTs"] = np.zeros((1, 3, 3))
    with pytest.raises(InvalidInputError, match=r"bad\.pkl.*'pred_RTs' must have shape"):
        load_nocs_results([_write(tmp_path / "bad.pkl", bad)])
    only_summary = tmp_path / "summaries"
    only_summary.mkdir()
    _write(only_summary / "mAP_Acc.pkl", {"iou_aps": 0})
    with pytest.raises(InvalidInputError, match="no NOCS result dicts found"):
        load_nocs_results([only_summary])


def test_format_table_lists_classes_mean_and_keys():
    table = compute_nocs_map([_tagged(0)], iou_mode="aligned")
    text = format_nocs_table(table, title="My run")
    lines = text.splitlines()
    assert lines[0] == "My run"
    assert lines[1].split() == ["class", *NOCS_METRIC_KEYS]
    rows = {line.split()[0]: line.split()[1:] for line in lines[3:] if not line.startswith("-")}
    assert rows["camera"] == ["100.0"] * 7
    assert rows["bottle"] == ["0.0"] * 7
    assert rows["mean"] == [f"{100 / 6:.1f}"] * 7
    skip = compute_nocs_map([_tagged(0)], iou_mode="aligned", classes_without_gt="skip")
    assert "n/a" in format_nocs_table(skip)
    with pytest.raises(InvalidInputError, match="per_class"):
        format_nocs_table({"mean": {}})
    with pytest.raises(InvalidInputError, match="lacks metric"):
        format_nocs_table({"mean": {}, "per_class": {}})


def test_cli_eval_nocs_prints_table_and_writes_json(tmp_path, capsys):
    results_dir = tmp_path / "results"
    results_dir.mkdir()
    results = random_results(np.random.default_rng(21), 8)
    for k, r in enumerate(results):
        _write(results_dir / f"results_{k:03d}.pkl", r)
    out = tmp_path / "out.json"
    assert main(["eval-nocs", str(results_dir), "--iou-mode", "aligned", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "iou_mode=aligned" in printed and "mean" in printed
    written = json.loads(out.read_text())
    expected = compute_nocs_map(results, iou_mode="aligned")
    assert set(written) == {"mean", "per_class"}
    for key in NOCS_METRIC_KEYS:
        a, b = written["mean"][key], expected["mean"][key]
        assert (math.isnan(a) and math.isnan(b)) or a == b  # JSON round-trips float64 exactly


def test_cli_unknown_iou_mode_exits_2(tmp_path, capsys):
    _write(tmp_path / "results_0.pkl", _tagged(0))
    assert main(["eval-nocs", str(tmp_path), "--iou-mode", "obb"]) == 2
    assert "known: nocs, aligned, exact" in capsys.readouterr().err


def _reduce_to(call, *args):
    """An object that pickles as `call(*args)`: what a crafted result file holds."""

    class Payload:
        def __reduce__(self):
            return (call, args)

    return Payload()


@pytest.mark.parametrize("protocol", [0, 2, 4, 5])
def test_a_crafted_pickle_is_refused_and_its_payload_never_runs(tmp_path, protocol):
    import os

    marker = tmp_path / "payload_ran"
    payloads = [
        _reduce_to(os.system, f"touch {marker}"),
        _reduce_to(open, str(marker), "w"),
        _reduce_to(eval, f"open({str(marker)!r}, 'w')"),
    ]
    for k, payload in enumerate(payloads):
        crafted = _tagged(0)
        crafted["gt_scales"] = payload  # hidden inside an otherwise valid result dict
        path = tmp_path / f"crafted_{k}.pkl"
        path.write_bytes(pickle.dumps(crafted, protocol=protocol))
        refused = r"refused to load: the pickle names \S+\.(system|open|eval),"
        with pytest.raises(InvalidInputError, match=refused):
            load_nocs_results([path])
        assert not marker.exists()


@pytest.mark.parametrize("protocol", [0, 1, 2, 3, 4, 5])
def test_result_pickles_of_numpy_arrays_still_load(tmp_path, protocol):
    r = _tagged(0)
    r["pred_scores"] = np.array([np.float32(0.5)])  # numpy scalars and arrays of several dtypes
    r["extra"] = {"scalar": np.float64(1.5), "ints": np.arange(3, dtype=np.int16), "set": {1, 2}, "c": 1j}
    r["fortran"] = np.asfortranarray(np.ones((2, 3)))
    path = _write_protocol(tmp_path / "r.pkl", r, protocol)
    (loaded,) = load_nocs_results([path])
    np.testing.assert_array_equal(loaded["gt_RTs"], r["gt_RTs"])
    assert loaded["extra"]["scalar"] == 1.5 and loaded["extra"]["ints"].dtype == np.int16
    np.testing.assert_array_equal(loaded["fortran"], r["fortran"])


def test_numpy_1_module_names_load_under_numpy_2_and_back(tmp_path):
    # numpy 1.x writes numpy.core.multiarray, numpy 2.x numpy._core.multiarray: either loads with either
    r = _tagged(0)
    data = pickle.dumps(r, protocol=2)
    for old, new in ((b"numpy._core", b"numpy.core"), (b"numpy.core", b"numpy._core")):
        path = tmp_path / "renamed.pkl"
        path.write_bytes(data.replace(old, new))
        (loaded,) = load_nocs_results([path])
        np.testing.assert_array_equal(loaded["gt_RTs"], r["gt_RTs"])


def _write_protocol(path, obj, protocol):
    path.write_bytes(pickle.dumps(obj, protocol=protocol))
    return path
