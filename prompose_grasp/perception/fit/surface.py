"""The object's seen surface next to the fitted box, and the box grown out to it (`FitConfig`'s `grow_*`
fields): the observed extents are lower bounds on the box that a mismatched prior may leave out."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from prompose_grasp.geometry.pointcloud import back_project, masked_median_depth
from prompose_grasp.geometry.pose9d import Pose9D
from prompose_grasp.perception.fit.observation import SceneView
from prompose_grasp.perception.fit.types import FitConfig

__all__ = ["grow_to_seen", "seen_surface"]


def seen_surface(
    pose: Pose9D, plane: tuple[np.ndarray, float] | None, config: FitConfig, scene: SceneView | None
) -> np.ndarray:
    """(M, 3) camera-frame points of the object's seen surface next to the fitted box `pose` [m]; (0, 3)
    without a `scene`.

    Which points count (the `grow_*` settings of `FitConfig`):

    - the points of the scene's mask at its own median depth (`grow_median_px`), not the raw points: depth
      noise along the rays moves silhouette points sideways, out of the true box by up to a centimetre on a
      far object;
    - with a support plane, only points more than `grow_plane_clearance_m` above it (table pixels that a
      mask took in);
    - points with more than `grow_density_min` neighbours within the link radius (`grow_density_radius_m`,
      or `grow_density_spacings` times the points' median spacing where they are sparser): a flying pixel or
      a stray mask pixel has none;
    - the pieces connected (through such points, at the link radius) to the box's inside: a strip of the
      background or of another object that the mask bled onto lies apart from the object.

    At most about 4096 points (an even stride over the mask): the extents and the shape seen from above,
    not every pixel.
    """
    empty = np.zeros((0, 3))
    if scene is None:
        return empty
    points = back_project(masked_median_depth(scene.depth_m, scene.mask, config.grow_median_px),
                          scene.intrinsics)  # fmt: skip
    pts = points[:: max(1, len(points) // 4096)]
    if plane is not None:
        pts = pts[pts @ plane[0] + plane[1] > config.grow_plane_clearance_m]
    if len(pts) < 2:
        return empty
    tree = cKDTree(pts)
    # the points' own spacing sets the link radius: a far or small object is sampled sparsely
    spacing = float(np.median(tree.query(pts, k=2)[0][:, 1]))
    link = max(config.grow_density_radius_m, config.grow_density_spacings * spacing)
    # one neighbour query serves both tests: a point's neighbours are its pairs (and itself)
    pairs = tree.query_pairs(link, output_type="ndarray")
    dense = np.bincount(pairs.ravel(), minlength=len(pts)) + 1 > config.grow_density_min
    if not np.any(dense):
        return empty
    pairs = pairs[dense[pairs[:, 0]] & dense[pairs[:, 1]]]  # the surface links through dense points only
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(pts), len(pts)))
    _, label = connected_components(graph, directed=False)
    inside = dense & np.all(np.abs((pts - pose.t) @ pose.R) <= 0.5 * pose.size, axis=1)
    return pts[dense & np.isin(label, np.unique(label[inside]))]


def grow_to_seen(
    pose: Pose9D,
    symmetry: str,
    plane: tuple[np.ndarray, float] | None,
    config: FitConfig,
    scene: SceneView | None,
    surface: np.ndarray | None = None,
) -> Pose9D:
    """`pose` with each face moved out to the seen surface beyond it (never in).

    The seen surface lies inside the true box, so the extents of the observed points are lower bounds on the
    box. The fit's containment term holds only points within `contain_cap_m` of the box (mask bleed lies
    farther), so where the prior's shape differs from the instance's (a hammer's head, a curved banana, a
    teapot's spout on a superquadric) the fit leaves whole parts of the seen object outside.

    The surface is `seen_surface(pose, plane, config, scene)` (pass it as `surface` where it is already
    computed; without either nothing moves). A face moves out when at least `grow_min_points` of its points
    lie beyond it by more than `grow_margin_m`, to the `grow_min_points`-th farthest less that margin (the
    band the noise of the median depth spans). A round section (`y_continuous`) grows its radius about the
    fitted axis; an upright box's bottom stays on the plane. `grow_min_points` 0 turns it off.
    """
    k = config.grow_min_points
    if k <= 0:
        return pose
    if surface is None:
        surface = seen_surface(pose, plane, config, scene)
    if len(surface) < max(k, 2):
        return pose
    half = 0.5 * pose.size
    local = (surface - pose.t) @ pose.R
    lo, hi = -half.copy(), half.copy()
    margin = config.grow_margin_m

    def reach(excess: np.ndarray) -> float:
        """How far out the face goes: the k-th largest excess, less the margin (the noise band), or 0."""
        beyond = excess[excess > margin]
        if len(beyond) < k:
            return 0.0
        return float(np.partition(beyond, len(beyond) - k)[len(beyond) - k]) - margin

    axes = (1,) if symmetry == "y_continuous" else (0, 1, 2)
    for a in axes:
        hi[a] += reach(local[:, a] - half[a])
        lo[a] -= reach(-half[a] - local[:, a])
    if plane is not None and pose.R[:, 1] @ plane[0] > 0.9:
        lo[1] = -half[1]  # an upright box's bottom rests on the plane; only points above it are seen
    if symmetry == "y_continuous":
        radius = max(half[0], half[2])
        grown = radius + reach(np.hypot(local[:, 0], local[:, 2]) - radius)
        lo[[0, 2]], hi[[0, 2]] = -grown, grown
    if np.all(lo == -half) and np.all(hi == half):
        return pose
    return Pose9D(pose.R, pose.t + pose.R @ (0.5 * (lo + hi)), hi - lo)
