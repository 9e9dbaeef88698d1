"""`prompose-grasp bench --methods`: which rows run, and a clear error for a name that is not a row."""

from __future__ import annotations

from math import nan
from types import SimpleNamespace

import pytest

from prompose_grasp.cli import main
from prompose_grasp.errors import InvalidInputError, UnknownNameError
from prompose_grasp.eval.bench_estimator import (
    METHODS,
    _track_confidence,
    format_report,
    parse_methods,
    run_estimator_benchmark,
)
from prompose_grasp.eval.nocs import NOCS_METRIC_KEYS


def test_default_is_every_method():
    assert parse_methods(None) == METHODS
    assert parse_methods("") == METHODS


def test_subset_in_report_order_without_duplicates():
    # given in another order, with spaces and a repeat: the rows come out once each, in METHODS order
    got = parse_methods(" ours_tracked_oracle_mask, ours_tracked ,ours_tracked_oracle_mask")
    assert got == ("ours_tracked", "ours_tracked_oracle_mask")
    assert parse_methods(["obb", "ours"]) == ("ours", "obb")


def test_unknown_name_lists_the_valid_ones():
    with pytest.raises(UnknownNameError) as info:
        parse_methods("ours_tracked,ours_trackd")
    msg = str(info.value)
    assert "'ours_trackd'" in msg
    for m in METHODS:
        assert m in msg


def test_empty_list_is_an_error():
    with pytest.raises(InvalidInputError):
        parse_methods([])


def test_bad_name_fails_before_reading_the_data(tmp_path):
    # the folder has no split.json: the method names are checked first
    with pytest.raises(UnknownNameError):
        run_estimator_benchmark(tmp_path, methods="nope")


def test_cli_reports_a_bad_name(tmp_path, capsys):
    rc = main(["bench", "--data", str(tmp_path), "--methods", "ours,nope"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "unknown benchmark method 'nope'" in err
    assert "ours_tracked_oracle_mask" in err


def test_report_text_has_only_the_rows_run():
    table = {"per_class": {}, "mean": dict.fromkeys(NOCS_METRIC_KEYS, 50.0)}
    report = {
        "data": "d",
        "split": "test",
        "frames": 0,
        "categories": [],
        "tables": {"ours_tracked_oracle_mask": {mode: table for mode in ("nocs", "aligned", "exact")}},
        "timing": {"track_oracle_update": {"n": 2, "median_ms": 20.0, "p90_ms": 30.0, "mean_ms": 25.0}},
        "tracking_fps": float("nan"),
        "tracking_oracle_mask_fps": 40.0,
        "tracking_oracle_mask_fps_median": 50.0,
    }
    text = format_report(report)
    assert "ours_tracked_oracle_mask  [iou_mode=exact]" in text
    assert "ours_oracle_mask  [iou_mode" not in text
    assert "tracking from the oracle mask: 40.0 frames/s" in text
    assert "\ntracking:" not in text


def test_a_tracked_prediction_is_ranked_as_the_frame_that_started_its_track():
    # first frame grounded at 0.9 with 80 % of the fitted shape seen; two tracked updates (no grounding
    # score, no coverage); a loss, grounded again at 0.5 in full view
    frames = [(0.9, 0.8), (nan, nan), (nan, nan), (0.5, 1.0)]
    got, confidence = [], 1.0
    for score, coverage in frames:
        confidence = _track_confidence(SimpleNamespace(score=score, coverage=coverage), confidence)
        got.append(confidence)
    assert got == pytest.approx([0.72, 0.72, 0.72, 0.5])
