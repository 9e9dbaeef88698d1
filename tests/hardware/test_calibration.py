"""Hand-eye calibration files: YAML and JSON, one rigid transform, clear errors otherwise."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from prompose_grasp.geometry.se3 import make_T, so3_exp
from prompose_grasp.hardware import CalibrationError, load_calibration

T = make_T(so3_exp([0.4, -1.1, 0.3]), [0.6, -0.2, 0.9])


def test_yaml_and_json_round_trip(tmp_path):
    (tmp_path / "a.yaml").write_text(yaml.safe_dump({"T_base_cam": T.tolist(), "note": "cell 3"}))
    (tmp_path / "b.json").write_text(json.dumps({"T_flange_cam": T.tolist()}))
    a, b = load_calibration(tmp_path / "a.yaml"), load_calibration(tmp_path / "b.json")
    assert (a.mount, a.key, b.mount, b.key) == ("eye_to_hand", "T_base_cam", "eye_in_hand", "T_flange_cam")
    # Text round trip keeps ~17 digits; the SVD re-orthonormalisation moves entries by ~1e-16.
    np.testing.assert_allclose(a.T, T, atol=1e-12)
    np.testing.assert_allclose(b.T, T, atol=1e-12)


def test_rounded_matrix_is_accepted_and_made_orthonormal(tmp_path):
    (tmp_path / "c.yaml").write_text(yaml.safe_dump({"T_base_cam": np.round(T, 5).tolist()}))
    R = load_calibration(tmp_path / "c.yaml").T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)  # orthonormal to float64 rounding
    np.testing.assert_allclose(R, T[:3, :3], atol=1e-4)  # within the 5-digit rounding it was given


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"T_base_cam": np.diag([2.0, 2.0, 2.0, 1.0]).tolist()}, "not a rotation"),
        ({"T_base_cam": np.diag([1.0, 1.0, -1.0, 1.0]).tolist()}, "not a rotation"),  # a mirror
        ({"T_base_cam": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "4x4"),
        ({"T_base_cam": (np.eye(4) + np.eye(4, k=-3)).tolist()}, r"\[0, 0, 0, 1\]"),
        ({"T_base_cam": make_T(np.eye(3), [600.0, 0, 900.0]).tolist()}, "millimetres"),
        ({"T_base_cam": [[float("nan")] * 4] * 4}, "NaN"),
        ({"T_base_cam": T.tolist(), "T_flange_cam": T.tolist()}, "exactly one"),
        ({"camera": T.tolist()}, "exactly one"),
        ({"T_base_cam": "identity"}, "4x4"),
    ],
)
def test_bad_calibrations_are_refused_with_a_reason(tmp_path, doc, message):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CalibrationError, match=message):
        load_calibration(path)


def test_missing_and_unparsable_files(tmp_path):
    with pytest.raises(CalibrationError, match="no such calibration file"):
        load_calibration(tmp_path / "nope.yaml")
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(CalibrationError, match="not valid JSON"):
        load_calibration(tmp_path / "x.json")
