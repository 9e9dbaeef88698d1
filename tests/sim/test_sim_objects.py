"""Procedural object library and mesh-file objects: canonical frames, exact sizes, errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from prompose_grasp.errors import InvalidInputError, UnknownNameError
from sim.objects import FAMILIES, NOCS_CATEGORIES, SYMMETRIES, load_mesh_object, make_object, sample_params

REQUIRED = (
    "box",
    "carton",
    "can",
    "bottle",
    "bowl",
    "mug",
    "cup",
    "laptop",
    "camera",
    "ball",
    "tube",
    "sack",
    "parcel",
)


def test_library_covers_the_issue_families():
    assert set(REQUIRED) <= set(FAMILIES)
    assert set(NOCS_CATEGORIES) <= set(FAMILIES)


@pytest.mark.parametrize("family", sorted(FAMILIES))
def test_canonical_frame_and_exact_size(family, rng):
    for _ in range(3):
        asset = make_object(family, rng=rng)
        v = np.vstack([p.vertices for p in asset.parts])
        # origin at the amodal box centre, size = extents: exact up to float64 rounding of the vertices
        np.testing.assert_allclose((v.min(0) + v.max(0)) / 2.0, 0.0, atol=1e-12)
        np.testing.assert_allclose(v.max(0) - v.min(0), asset.size, atol=1e-12)
        assert asset.symmetry in SYMMETRIES
        assert all(p.is_watertight for p in asset.parts)
        assert all(c.is_convex for c in asset.collision)
        # metric, household/logistics sized: 1 cm .. 1 m along every axis
        assert np.all(asset.size > 0.01) and np.all(asset.size < 1.0)


def test_sampled_params_respect_ranges(rng):
    for family, fam in FAMILIES.items():
        params = sample_params(family, rng)
        for key, (lo, hi) in fam.ranges.items():
            assert lo <= params[key] <= hi, (family, key)


def test_mug_handle_points_along_plus_x():
    mug = make_object("mug")
    body, handle = mug.parts
    # the handle lies beyond the body on +x only, centred in z
    assert handle.vertices[:, 0].max() > body.vertices[:, 0].max() + 0.01
    assert handle.vertices[:, 0].min() > body.bounds.mean(axis=0)[0]
    assert abs(handle.vertices[:, 2].mean()) < 1e-3  # a millimetre: tessellation symmetry about z = 0


def test_symmetric_families_are_symmetric_about_y():
    for family in ("can", "bottle", "bowl", "cup"):
        v = make_object(family).mesh.vertices
        r = np.hypot(v[:, 0], v[:, 2])
        # radius of revolution about y: the x and z extents agree (48 sections: exactly for sections % 4 == 0)
        np.testing.assert_allclose(np.ptp(v[:, 0]), np.ptp(v[:, 2]), rtol=1e-9)
        assert r.max() <= np.ptp(v[:, 0]) / 2.0 + 1e-9


def test_laptop_and_camera_fronts():
    laptop = make_object("laptop", {"opening_deg": 110.0})
    base, screen = laptop.parts
    assert screen.vertices[:, 1].max() > base.vertices[:, 1].max() + 0.1  # the screen stands up (+y)
    assert base.vertices[:, 2].mean() > screen.vertices[:, 2].mean()  # keyboard towards +z, screen behind
    cam = make_object("camera")
    lens = cam.parts[1]
    assert lens.vertices[:, 2].max() == pytest.approx(cam.size[2] / 2.0)  # lens reaches the +z face


def test_params_override_and_errors():
    can = make_object("can", {"radius_m": 0.03, "height_m": 0.1})
    np.testing.assert_allclose(can.size, [0.06, 0.1, 0.06], atol=1e-12)
    with pytest.raises(UnknownNameError, match=r"known: .*mug"):
        make_object("teapot")
    with pytest.raises(InvalidInputError, match="accepted"):
        make_object("can", {"diameter_m": 0.05})
    with pytest.raises(InvalidInputError):
        make_object("can", {"radius_m": -0.05})


def test_mesh_file_with_scale_and_up_axis(tmp_path):
    # a 4 x 2 x 6 cm box written as OBJ, z-up
    box = trimesh.creation.box(extents=[0.04, 0.02, 0.06])
    box.apply_translation([1.0, 2.0, 3.0])  # off-centre on purpose: the loader recentres
    path = tmp_path / "widget.obj"
    box.export(path)
    asset = load_mesh_object(path, scale=[2.0, 1.0, 1.0], up_axis="z")
    # z-up -> y-up: file z (6 cm) becomes canonical y; x scaled by 2; file y becomes canonical z
    np.testing.assert_allclose(asset.size, [0.08, 0.06, 0.02], atol=1e-9)
    np.testing.assert_allclose(asset.mesh.bounds.mean(axis=0), 0.0, atol=1e-9)
    assert asset.category == "widget" and asset.source == str(path)
    with pytest.raises(InvalidInputError):
        load_mesh_object(tmp_path / "missing.obj")
    with pytest.raises(UnknownNameError):
        load_mesh_object(path, up_axis="w")


SHARED_OBJECTS = Path(__file__).resolve().parents[3] / "shared" / "data" / "objects"


@pytest.mark.shared_data
@pytest.mark.skipif(
    not (SHARED_OBJECTS / "objects.json").is_file(), reason="../shared/data/objects is absent"
)
def test_real_meshes_load_with_their_listed_extents():
    entries = json.loads((SHARED_OBJECTS / "objects.json").read_text())[:5]
    for e in entries:
        asset = load_mesh_object(SHARED_OBJECTS / e["dir"] / "model.obj", up_axis="y")
        # objects.json rounds extents to 0.1 mm
        np.testing.assert_allclose(asset.size, e["extents_m"], atol=1.5e-4)
        assert asset.category == e["dir"]


def _open_cup(radius_m: float = 0.04, height_m: float = 0.1, wall_m: float = 0.004) -> trimesh.Trimesh:
    """A watertight open cup about z: a 4 mm wall and a 5 mm base around a cavity open at the top."""
    r_in = radius_m - wall_m
    profile = [[0.0, 0.0], [radius_m, 0.0], [radius_m, height_m], [r_in, height_m], [r_in, 0.005]]
    profile.append([0.0, 0.005])
    return trimesh.creation.revolve(np.array(profile), sections=32)  # about z


def _in_convex(part: trimesh.Trimesh, point: np.ndarray) -> bool:
    """Whether `point` (3,) lies inside the convex `part` (every face plane has it on its inner side)."""
    eq = ConvexHull(part.vertices).equations
    return bool(np.all(eq[:, :3] @ point + eq[:, 3] <= 1e-9))


def test_a_decomposed_cup_is_hollow_where_its_hull_is_solid(tmp_path, monkeypatch):
    pytest.importorskip("coacd", reason="collision 'decompose' needs the sim extra (coacd)")
    monkeypatch.setenv("PROMPOSE_GRASP_CACHE", str(tmp_path))
    path = tmp_path / "cup.stl"
    _open_cup().export(path)
    hull = load_mesh_object(path, up_axis="z")
    parts = load_mesh_object(path, up_axis="z", collision="decompose")
    assert len(hull.collision) == 1 and len(parts.collision) > 1
    np.testing.assert_allclose(parts.size, hull.size)  # the visual mesh and its box are the same
    # a point in the cavity, 3 cm below the rim on the axis: inside the hull, inside no part (a finger fits)
    inside = np.array([0.0, 0.02, 0.0])  # canonical frame: +y up, origin at the box centre
    assert _in_convex(hull.collision[0], inside)
    assert not any(_in_convex(p, inside) for p in parts.collision)
    # the wall is covered: a point in it, 2 mm inside the outer face, lies in a part
    assert any(_in_convex(p, np.array([0.038, 0.0, 0.0])) for p in parts.collision)
    # cached: the second load reads the parts back (same vertices) from the cache folder
    cached = list((tmp_path / "collision").glob("coacd-*.npz"))
    assert len(cached) == 1
    again = load_mesh_object(path, up_axis="z", collision="decompose")
    assert [len(p.vertices) for p in again.collision] == [len(p.vertices) for p in parts.collision]


def test_an_unknown_collision_model_is_named(tmp_path):
    path = tmp_path / "cup.stl"
    _open_cup().export(path)
    with pytest.raises(UnknownNameError, match="decompose"):
        load_mesh_object(path, collision="convex")
