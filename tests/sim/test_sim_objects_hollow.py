"""The open containers' collision geometry is hollow: a finger fits inside a bowl, cup or mug and the rim's
wall is solid, as in the real object (the convex hull of the whole part would be a lid over the opening)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.objects import make_object


def _inside_convex(piece, point: np.ndarray) -> bool:
    """Point inside a convex watertight mesh: behind every face plane (0.1 mm: rounding of the faces)."""
    d = np.einsum("ij,ij->i", piece.face_normals, point - piece.triangles[:, 0])
    return bool(np.all(d <= 1e-4))


def _inside_any(asset, point) -> bool:
    return any(_inside_convex(p, np.asarray(point, dtype=np.float64)) for p in asset.collision)


@pytest.mark.parametrize("family", ["bowl", "cup", "mug"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_container_is_hollow_with_a_solid_wall(family, seed):
    asset = make_object(family, rng=np.random.default_rng(seed))
    p = asset.params
    assert all(c.is_convex and c.is_watertight and c.volume > 0 for c in asset.collision)
    # The axis: the base disc (the first piece) is centred on it; -x is away from a mug's handle and is a
    # sector boundary (24 sectors), where the pieces' corners lie on the true wall.
    base = asset.collision[0].vertices
    axis = np.array(
        [(base[:, 0].max() + base[:, 0].min()) / 2.0, 0.0, (base[:, 2].max() + base[:, 2].min()) / 2.0]
    )
    top = asset.size[1] / 2.0
    r_rim = {"bowl": p.get("radius_m"), "cup": p.get("top_radius_m"), "mug": p.get("radius_m")}[family]
    t = p["wall_m"]
    # 1 cm below the rim, halfway between the axis and the inner wall: empty (a pad fits there) ...
    cavity = axis + np.array([-(r_rim - t) / 2.0, top - 0.01, 0.0])
    assert not _inside_any(asset, cavity)
    assert _inside_convex(asset.mesh.convex_hull, cavity)  # ... where the whole part's hull was solid
    # ... and the middle of the wall 2 mm below the rim is solid (a pad pressing there meets the wall).
    wall = axis + np.array([-(r_rim - t / 2.0), top - 0.002, 0.0])
    assert _inside_any(asset, wall)
    # The pieces hold about the object's own volume (the hull held 4-8 x as much): within 15 % (the curved
    # bowl wall's bands are convex hulls over the curvature's chord, and neighbouring pieces overlap at
    # their joints).
    volume = sum(c.volume for c in asset.collision)
    assert volume == pytest.approx(asset.mesh.volume, rel=0.15)
