"""Dataset generator: layout, split, ground truth in the files, determinism, resuming."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from conftest import back_project

from prompose_grasp.errors import InvalidInputError
from prompose_grasp.geometry.camera import CameraIntrinsics
from sim.dataset import DatasetConfig, generate, make_split

pytestmark = [pytest.mark.sim, pytest.mark.slow]


def _config(out, **kw):
    base = dict(out=str(out), scenes=3, frames=2, seed=3, width=128, height=96, workers=1, noise="realsense")
    base.update(kw)
    return DatasetConfig(**base)


def test_split_is_disjoint_and_deterministic(tmp_path):
    cfg = _config(tmp_path, scenes=20)
    split = make_split(cfg)
    assert not set(split["train"]["categories"]) & set(split["test"]["categories"])
    scenes = split["train"]["scenes"] + split["val"]["scenes"] + split["test"]["scenes"]
    assert sorted(scenes) == [f"scene_{i:05d}" for i in range(20)]
    assert (len(split["train"]["scenes"]), len(split["val"]["scenes"]), len(split["test"]["scenes"])) == (
        14,
        2,
        4,
    )
    assert split == make_split(cfg)
    with pytest.raises(InvalidInputError, match="disjoint"):
        _config(tmp_path, train_categories=("can", "mug"), test_categories=("mug",))


def test_generate_layout_ground_truth_and_resume(tmp_path):
    cfg = _config(tmp_path)
    stats = generate(cfg, progress=False)
    assert stats["frames_written"] == 6
    split = json.loads((tmp_path / "split.json").read_text())
    test_scenes = set(split["test"]["scenes"])
    for scene in sorted(p.name for p in tmp_path.iterdir() if p.is_dir()):
        for k in range(2):
            stem = tmp_path / scene / f"{k:06d}"
            color = cv2.imread(f"{stem}-color.png", cv2.IMREAD_UNCHANGED)
            depth = cv2.imread(f"{stem}-depth.png", cv2.IMREAD_UNCHANGED)
            mask = cv2.imread(f"{stem}-mask.png", cv2.IMREAD_UNCHANGED)
            meta = json.loads((stem.parent / f"{k:06d}-meta.json").read_text())
            assert color.shape == (96, 128, 3) and depth.dtype == np.uint16 and mask.shape == (96, 128)
            K = CameraIntrinsics.from_K(np.array(meta["K"]), meta["width"], meta["height"])
            cats = {o["category"] for o in meta["objects"]}
            if scene in test_scenes:
                assert cats & set(split["test"]["categories"])
            else:
                assert not cats & set(split["test"]["categories"])
            depth_m = depth.astype(np.float64) * meta["depth_scale_m"]
            for o in meta["objects"]:
                assert set(o) >= {"id", "category", "prompt", "mesh", "R", "t", "size", "symmetry"}
                m = mask == o["id"]
                assert int(m.sum()) == o["visible_px"]
                if m.sum() < 10:
                    continue
                pts = back_project(depth_m, K.fx, K.fy, K.cx, K.cy, m)
                R, t, size = np.array(o["R"]), np.array(o["t"]), np.array(o["size"])
                p_obj = (pts - t) @ R
                # realsense error bound: 5 sigma (1 mm + 3.7 mm/m^2 z^2) + half a mm unit, on any axis
                tol = 5 * (0.001 + 0.0037 * pts[:, 2:3] ** 2) + 0.0005 + 1e-4
                assert np.all(np.abs(p_obj) <= size / 2 + tol), (scene, o["name"])
    # resuming: nothing is regenerated; a deleted scene comes back bit-identical
    before = (tmp_path / "scene_00001" / "000001-color.png").read_bytes()
    assert generate(cfg, progress=False)["scenes_skipped"] == 3
    for f in (tmp_path / "scene_00001").iterdir():
        f.unlink()
    assert generate(cfg, progress=False)["frames_written"] == 2
    assert (tmp_path / "scene_00001" / "000001-color.png").read_bytes() == before
