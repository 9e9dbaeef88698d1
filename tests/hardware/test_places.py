"""Place-target files (`hardware.places`): values as written, the two pose forms agree, and every kind of
mistake is refused with a message that names it."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.hardware.places import load_place_targets


def _write(tmp_path, doc, name="places.yaml"):
    path = tmp_path / name
    path.write_text(json.dumps(doc) if name.endswith(".json") else yaml.safe_dump(doc))
    return path


BIN = {"kind": "bin", "pos_m": [0.45, -0.30, 0.02], "rpy_deg": [0, 0, 90],
       "half_extents_m": [0.15, 0.10], "wall_height_m": 0.12}  # fmt: skip


def test_values_come_back_as_written(tmp_path):
    pallet_T = [[1, 0, 0, 0.0], [0, 1, 0, 0.65], [0, 0, 1, -0.55], [0, 0, 0, 1]]
    doc = {"place_targets": {
        "bin": BIN,
        "pallet": {"kind": "pallet", "T_base_surface": pallet_T, "half_extents_m": [0.6, 0.4],
                   "pattern": {"rows": 2, "cols": 3, "layers": 2, "gap_m": 0.02, "interlock": True}},
    }}  # fmt: skip
    targets = load_place_targets(_write(tmp_path, doc))
    assert sorted(targets) == ["bin", "pallet"]
    b = targets["bin"]
    assert b.kind == "bin" and b.wall_height_m == 0.12
    np.testing.assert_array_equal(b.half_extents_xy_m, [0.15, 0.10])
    # yaw 90 deg about z, written out by hand: x -> y, y -> -x (float rounding of cos 90 deg: 1e-12).
    expected = np.array([[0, -1, 0, 0.45], [1, 0, 0, -0.30], [0, 0, 1, 0.02], [0, 0, 0, 1]], dtype=float)
    np.testing.assert_allclose(b.T_base_surface, expected, atol=1e-12)
    p = targets["pallet"]
    np.testing.assert_array_equal(p.T_base_surface, pallet_T)
    assert (p.pattern.rows, p.pattern.cols, p.pattern.layers, p.pattern.gap_m, p.pattern.interlock) == (
        2, 3, 2, 0.02, True,
    )  # fmt: skip


def test_rpy_and_matrix_forms_give_the_same_frame(tmp_path):
    roll, pitch, yaw = 4.0, -3.0, 30.0  # a slightly tilted conveyor, turned 30 deg
    r, p, y = (math.radians(a) for a in (roll, pitch, yaw))
    Rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    Ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    Rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx  # extrinsic x-y-z (URDF rpy)
    T[:3, 3] = [0.1, -0.55, 0.05]
    common = {"kind": "surface", "half_extents_m": [1.0, 0.25]}
    a = load_place_targets(_write(tmp_path, {"place_targets": {"conveyor": {
        **common, "pos_m": [0.1, -0.55, 0.05], "rpy_deg": [roll, pitch, yaw]}}}, "a.yaml"))  # fmt: skip
    b = load_place_targets(_write(tmp_path, {"place_targets": {"conveyor": {
        **common, "T_base_surface": T.tolist()}}}, "b.json"))  # fmt: skip
    # Both are the same rotation computed two ways in float64: agreement to rounding.
    np.testing.assert_allclose(a["conveyor"].T_base_surface, b["conveyor"].T_base_surface, atol=1e-12)


@pytest.mark.parametrize(
    ("places", "message"),
    [
        ({"shelf": BIN}, "not a fixture a command can name"),
        ({"bin": {**BIN, "colour": "blue"}}, "unknown keys \\['colour'\\]"),
        ({"bin": {**BIN, "pos_m": [450.0, -300.0, 20.0]}}, "millimetres"),
        ({"bin": {**BIN, "half_extents_m": [150.0, 100.0]}}, "millimetres"),
        ({"bin": {**BIN, "rpy_deg": [180, 0, 0]}}, "upward normal"),
        ({"bin": {**BIN, "rpy_deg": [0, 20, 0]}}, "20.0 deg"),
        ({"bin": {**BIN, "pattern": {"rows": 2}}}, "kind: pallet"),
        ({"bin": {**BIN, "T_base_surface": np.eye(4).tolist()}}, "either as pos_m"),
        ({"bin": {**BIN, "pos_m": [0.4, float("nan"), 0.0]}}, "finite number"),
        ({"bin": {**BIN, "pos_m": [0.4, 0.0]}}, "list of 3"),
        ({"bin": {**BIN, "kind": "shelf"}}, "kind must be one of"),
        ({"bin": {k: v for k, v in BIN.items() if k != "kind"}}, "kind must be one of"),
        ({"bin": {**BIN, "kind": 3}}, "kind must be one of"),
        (
            {
                "pallet": {
                    "kind": "pallet",
                    "pos_m": [0, 0.6, 0],
                    "half_extents_m": [0.6, 0.4],
                    "pattern": {"rows": 2.5},
                }
            },
            "integer",
        ),
        (
            {
                "pallet": {
                    "kind": "pallet",
                    "T_base_surface": np.diag([1.0, 1.0, 1.1, 1.0]).tolist(),
                    "half_extents_m": [0.6, 0.4],
                }
            },
            "not a rotation",
        ),
    ],
)
def test_mistakes_are_refused_with_a_reason(tmp_path, places, message):
    with pytest.raises(InvalidInputError, match=message):
        load_place_targets(_write(tmp_path, {"place_targets": places}))


def test_bad_files_are_refused(tmp_path):
    with pytest.raises(InvalidInputError, match="no such place-target file"):
        load_place_targets(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("place_targets: [unclosed")
    with pytest.raises(InvalidInputError, match="not valid YAML"):
        load_place_targets(bad)
    with pytest.raises(InvalidInputError, match="non-empty 'place_targets:'"):
        load_place_targets(_write(tmp_path, {"bin": BIN}))
