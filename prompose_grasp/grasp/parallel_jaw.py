"""Parallel-jaw grasp candidates: analytic grasps on the 9-DoF box, antipodal pairs on the scaled mesh, and
grasps across a container's rim.

Box grasps (parallel jaw). For each box axis i narrower than the stroke (less twice the clearance) the jaws
close along i; the approach runs along each other axis j, from either side, tilted by `approach_tilts_deg`
towards the third axis. The tcp (the pad centre) goes as deep towards the box centre as the palm allows
(palm at `palm_clearance_m` from the box's extent along the approach), slid along the face to `n_slide`
positions. Quality: 0.4 top-down (approach against the support normal), 0.3 centring (distance of the
closing line from the centre of mass), 0.2 depth (pad overlap), 0.1 width margin.

Antipodal grasps (parallel jaw, mesh). Surface points with normals are sampled; a pair (p1, p2) is a grasp
when the line p1 -> p2 lies inside both friction cones (half angle atan(mu)) and the pair is narrower than the
stroke. The object's family restricts where: mugs by the rim or the body, bowls by the rim, bottles (cans,
jars) by the body (rim: both contacts in the top band of the object and a horizontal closing line; body:
contacts in the middle band, closing line horizontal). The approach is perpendicular to the closing line, the
one nearest top-down, rotated about the closing line by `antipodal_approaches_deg`. Quality: 0.35 friction
margin, 0.3 top-down, 0.25 centring, 0.1 width margin.

Rim grasps (`rim_grasps`). An open container standing upright (a bowl, cup or mug) is held across its
rim's wall, the closing line radial through its axis, at angles around the rim (see the function).
"""

from __future__ import annotations

import math

import numpy as np

from prompose_grasp.geometry.distance import cross
from prompose_grasp.grasp.candidates import Candidates, Reasons, stack_transforms, support_up, tcp_frames
from prompose_grasp.grasp.grippers import ParallelJawGeometry
from prompose_grasp.grasp.types import GraspConfig, ObjectModel, Plane

__all__ = ["FAMILY_REGIONS", "antipodal_grasps", "box_grasps", "family_regions", "rim_grasps"]

#: Box axis names, in the reasons.
_AXES = "xyz"

#: Where each family may be grasped by the jaws ("rim", "body"); families not listed: anywhere.
FAMILY_REGIONS: dict[str, tuple[str, ...]] = {
    "mug": ("rim", "body"),
    "cup": ("rim", "body"),
    "bowl": ("rim",),
    "bottle": ("body",),
    "can": ("body",),
    "jar": ("body",),
}

#: Rim grasps (`rim_grasps`): angles around the rim; pad centre depths below the rim's top beyond half a pad
#: [m]; approach tilts about the closing line [deg]; the wide opening's clearance each side of the wall [m]
#: (an estimated centre ~3 cm off with a radius ~1.5 cm small puts the wall up to ~2.5 cm from where it is
#: planned along the radial closing line); the rim's annulus is the mesh's top this thick [m]; the container
#: stands upright within this angle of the support normal [deg].
_RIM_ANGLES = 16
_RIM_DEPTHS_M = (0.01, 0.004, -0.004)
#: ... and the wall's lean over the pad above which a rim grasp ranks lower (it wedges out) [deg].
_RIM_MAX_LEAN_DEG = 10.0
_RIM_TILTS_DEG = (0.0, -20.0, 20.0)
_RIM_WIDE_CLEARANCE_M = 0.025
_RIM_RING_BAND_M = 0.003
_RIM_UPRIGHT_DEG = 30.0
#: A closing line counts as horizontal within this angle of the object's horizontal plane [deg].
_HORIZONTAL_DEG = 25.0
#: The rim band is the top 15 % of the object's height, at least 15 mm; the body band the middle 70 %.
_RIM_FRACTION, _RIM_MIN_M, _BODY_FRACTION = 0.15, 0.015, 0.70


def family_regions(family: str) -> tuple[str, ...]:
    """Regions a family may be grasped in ("rim", "body"), or () for anywhere."""
    return FAMILY_REGIONS.get(family, ())


def box_grasps(
    target: ObjectModel, gripper: ParallelJawGeometry, config: GraspConfig, support: Plane | None = None
) -> Candidates:
    """Analytic parallel-jaw grasps on the target's 9-DoF box (see the module docstring)."""
    R, c, size = target.pose.R, target.pose.t, target.pose.size
    com = target.centre_of_mass
    up = support_up(support)
    pad_w, _, pad_l = gripper.pad_size_m
    reach = gripper.palm_to_tcp_m - config.palm_clearance_m  # deepest the box may reach above the tcp
    max_dim = float(np.max(size))
    # Every (closing axis i, approach axis j, side s, tilt) combination, as rows of arrays.
    combos = [
        (i, j, s, t)
        for i in range(3)
        for j in range(3)
        if j != i
        for s in (1.0, -1.0)
        for t in config.approach_tilts_deg
    ]
    I, J, S, TILT = (np.array(x) for x in zip(*combos))
    K = 3 - I - J
    th = np.radians(TILT)
    Ri, Rj, Rk = R[:, I].T, R[:, J].T, R[:, K].T  # (C, 3) axes in base
    a = -S[:, None] * Rj * np.cos(th)[:, None] + Rk * np.sin(th)[:, None]
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    y = Ri
    b = cross(y, a)  # slide direction on the face (tcp x)
    sj, sk = size[J], size[K]
    H = 0.5 * (np.abs(np.sum(a * Rj, axis=1)) * sj + np.abs(np.sum(a * Rk, axis=1)) * sk)
    Hb = 0.5 * (np.abs(np.sum(b * Rj, axis=1)) * sj + np.abs(np.sum(b * Rk, axis=1)) * sk)
    depth0 = np.minimum(H, reach)  # tcp depth below the box's extent towards the palm
    steps = np.asarray(config.depth_steps_m, dtype=np.float64)
    n_s = config.n_slide
    half_slide = np.maximum(Hb - pad_w / 2.0, 0.0)
    unit = np.linspace(-1.0, 1.0, n_s) if n_s > 1 else np.zeros(1)
    # Grid (C, depth steps, slides).
    D = np.broadcast_to(depth0[:, None, None] - steps[None, :, None], (len(combos), len(steps), n_s))
    Sl = np.broadcast_to(half_slide[:, None, None] * unit[None, None, :], D.shape)
    P = c + Sl[..., None] * b[:, None, None, :] - (H[:, None, None] - D)[..., None] * a[:, None, None, :]
    # The pads must press on the faces: the tcp (the pads' centre) inside the face rectangle (a steep tilt on
    # thin box can put it outside), deep enough for 3/4 of the pad, and each slide position once.
    lj = np.abs(np.sum((P - c) * Rj[:, None, None, :], axis=-1))
    lk = np.abs(np.sum((P - c) * Rk[:, None, None, :], axis=-1))
    keep = (lj <= sj[:, None, None] / 2 + 1e-12) & (lk <= sk[:, None, None] / 2 + 1e-12) & (D >= pad_l / 4.0)
    if n_s > 1:
        keep &= np.broadcast_to((half_slide > 0)[:, None, None] | (unit == 0)[None, None, :], D.shape)
    # Drop repeated depths (when depth0 - step collapses on another).
    ci, di, si = np.nonzero(keep)
    if ci.size == 0:
        return Candidates.empty()
    p = P[ci, di, si]
    depth = D[ci, di, si]
    yy, aa = y[ci], a[ci]
    d = com - p
    off = np.linalg.norm(d - np.sum(d * yy, axis=1)[:, None] * yy, axis=1)  # closing line to the com
    width = size[I[ci]]
    top = 0.5 * (1.0 - aa @ up)
    q = (
        0.4 * top
        + 0.3 * np.clip(1.0 - off / max_dim, 0.0, 1.0)
        + 0.2 * np.minimum(1.0, depth / max(pad_l, 1e-9))
        + 0.1 * np.clip(1.0 - width / gripper.stroke_m, 0.0, 1.0)
    )
    # Both flips of each grasp (the same jaws turned half a turn about the approach).
    m = len(p)
    Rf = np.stack([tcp_frames(aa, yy), tcp_frames(aa, -yy)], axis=1).reshape(-1, 3, 3)
    rep = np.repeat(np.arange(m), 2)
    too_wide = width + 2.0 * config.min_clearance_m > gripper.stroke_m
    opening = np.minimum(width + 2.0 * config.clearance_m, gripper.stroke_m)
    contacts = np.stack([p - yy * width[:, None] / 2.0, p + yy * width[:, None] / 2.0], axis=1)

    def box_reason(row: int) -> str:
        r = row // 2  # both flips share the text
        k = ci[r]
        return (
            f"box: close along obj {_AXES[I[k]]} ({width[r] * 1e3:.0f} mm, stroke "
            f"{gripper.stroke_m * 1e3:.0f} mm, open to {opening[r] * 1e3:.0f} mm), approach "
            f"{'-' if S[k] > 0 else '+'}obj {_AXES[J[k]]} tilted {TILT[k]:+.0f} deg, "
            f"{depth[r] * 1e3:.0f} mm deep, {off[r] * 1e3:.0f} mm from the centre of mass"
        )

    return Candidates(
        stack_transforms(Rf, p[rep]),
        opening[rep],
        width[rep],
        contacts[rep],
        np.clip(q[rep], 0.0, 1.0),
        np.full(2 * m, "box", dtype=object),
        Reasons.lazy(box_reason, 2 * m),
        np.zeros(2 * m, dtype=bool),
        np.where(too_wide[rep], "stroke", "").astype(object),
    )


def _region_mask(
    family: str, p1_obj: np.ndarray, p2_obj: np.ndarray, u_obj: np.ndarray, size: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(mask, label) of antipodal pairs allowed for the family, in the object frame (+y up)."""
    regions = family_regions(family)
    n = len(p1_obj)
    if not regions:
        return np.ones(n, dtype=bool), np.full(n, "surface", dtype=object)
    height = float(size[1])
    horizontal = np.abs(u_obj[:, 1]) <= math.sin(math.radians(_HORIZONTAL_DEG))
    rim_y = height / 2.0 - max(_RIM_FRACTION * height, _RIM_MIN_M)
    rim = horizontal & (p1_obj[:, 1] >= rim_y) & (p2_obj[:, 1] >= rim_y)
    body_half = _BODY_FRACTION * height / 2.0
    body = horizontal & (np.abs(p1_obj[:, 1]) <= body_half) & (np.abs(p2_obj[:, 1]) <= body_half)
    mask = np.zeros(n, dtype=bool)
    label = np.full(n, "", dtype=object)
    if "body" in regions:
        mask |= body
        label[body] = "body"
    if "rim" in regions:
        mask |= rim
        label[rim] = "rim"
    return mask, label


def antipodal_grasps(
    target: ObjectModel, gripper: ParallelJawGeometry, config: GraspConfig, support: Plane | None = None
) -> Candidates:
    """Antipodal parallel-jaw grasps on the target's scaled mesh (see the module docstring); empty without
    a mesh."""
    mesh = target.mesh
    if mesh is None or len(mesh.faces) == 0:
        return Candidates.empty()
    import trimesh

    regions = family_regions(target.family)
    # Families grasped only in some regions: draw 4x the samples and keep those in the regions' bands, so a
    # thin rim gets as many samples as a whole surface would (the pair count stays mesh_samples^2 / 2).
    n_draw = config.mesh_samples * (4 if regions else 1)
    points, face_idx = trimesh.sample.sample_surface(mesh, n_draw, seed=config.seed)
    normals = np.asarray(mesh.face_normals)[face_idx]
    P = np.asarray(points, dtype=np.float64)
    if regions:
        y_obj = (P - target.pose.t) @ target.pose.R[:, 1]
        height = float(target.pose.size[1])
        band = np.zeros(len(P), dtype=bool)
        if "rim" in regions:
            band |= y_obj >= height / 2.0 - max(_RIM_FRACTION * height, _RIM_MIN_M)
        if "body" in regions:
            band |= np.abs(y_obj) <= _BODY_FRACTION * height / 2.0
        idx = np.flatnonzero(band)
        idx = (
            idx[np.linspace(0, len(idx) - 1, min(len(idx), config.mesh_samples)).astype(np.int64)]
            if len(idx)
            else idx
        )
        P, normals = P[idx], normals[idx]
    cos_cone = math.cos(math.atan(config.friction_coefficient))
    max_dist = gripper.stroke_m - 2.0 * config.min_clearance_m
    # All pairs at once as n x n matrices (BLAS): with X = P - mean, |p_j - p_i|^2 and n_i . (p_j - p_i) are
    # entries of X X^T and N X^T. A loose pass (slack far above the rounding of these sums) keeps a superset
    # of the pairs; the exact tests below run on the survivors only.
    X = P - P.mean(axis=0)
    sq = np.einsum("ij,ij->i", X, X)
    G = X @ X.T
    D2 = np.maximum(sq[:, None] + sq[None, :] - 2.0 * G, 0.0)
    NX = normals @ X.T  # NX[i, j] = n_i . x_j
    nx = np.einsum("ij,ij->i", normals, X)  # n_i . x_i
    slack = 1e-9
    dist_m = np.sqrt(D2)
    loose = (dist_m > 1e-3 - slack) & (dist_m <= max_dist + slack)
    loose &= -(NX - nx[:, None]) >= cos_cone * dist_m - slack  # the pad at p_i pushes along +u, into it
    loose &= (nx[None, :] - NX.T) >= cos_cone * dist_m - slack  # n_j . (p_j - p_i)
    if regions:
        # The family's regions (`_region_mask`, applied exactly below): a horizontal closing line, both
        # contacts in the rim band or both in the body band.
        y = (P - target.pose.t) @ target.pose.R[:, 1]
        h = float(target.pose.size[1])
        loose &= np.abs(y[None, :] - y[:, None]) <= math.sin(math.radians(_HORIZONTAL_DEG)) * dist_m + slack
        rim = y >= h / 2.0 - max(_RIM_FRACTION * h, _RIM_MIN_M) - slack
        body = np.abs(y) <= _BODY_FRACTION * h / 2.0 + slack
        allowed = np.zeros_like(loose)
        if "rim" in regions:
            allowed |= rim[:, None] & rim[None, :]
        if "body" in regions:
            allowed |= body[:, None] & body[None, :]
        loose &= allowed
    R, c, size = target.pose.R, target.pose.t, target.pose.size
    com = target.centre_of_mass
    max_dim = float(np.max(size))
    mu_angle = math.atan(config.friction_coefficient)

    def quality(margin: np.ndarray, off: np.ndarray, dist: np.ndarray) -> np.ndarray:
        return (
            0.35 * margin + 0.25 * np.clip(1.0 - off / max_dim, 0, 1) + 0.1 * (1.0 - dist / gripper.stroke_m)
        )

    def exact(i1: np.ndarray, i2: np.ndarray):
        """The exact tests and quality of pairs (i1, i2), each pair computed on its own; `pos` are the
        survivors' positions in the input."""
        pos = np.arange(len(i1))
        d = P[i2] - P[i1]
        dist = np.linalg.norm(d, axis=1)
        ok = (dist > 1e-3) & (dist + 2.0 * config.min_clearance_m <= gripper.stroke_m)
        i1, i2, d, dist, pos = i1[ok], i2[ok], d[ok], dist[ok], pos[ok]
        u = d / dist[:, None]
        c1 = -np.einsum("ij,ij->i", normals[i1], u)  # the pad at p1 pushes along +u, into the surface
        c2 = np.einsum("ij,ij->i", normals[i2], u)
        ok = (c1 >= cos_cone) & (c2 >= cos_cone)
        i1, i2, u, dist, c1, c2, pos = i1[ok], i2[ok], u[ok], dist[ok], c1[ok], c2[ok], pos[ok]
        p1_obj, p2_obj = (P[i1] - c) @ R, (P[i2] - c) @ R
        mask, label = _region_mask(target.family, p1_obj, p2_obj, u @ R, size)
        i1, i2, u, dist, c1, c2, label, pos = (x[mask] for x in (i1, i2, u, dist, c1, c2, label, pos))
        mid = 0.5 * (P[i1] + P[i2])
        dm = com - mid
        off = np.linalg.norm(dm - np.einsum("ij,ij->i", dm, u)[:, None] * u, axis=1)
        margin = (np.arccos(np.clip(np.minimum(c1, c2), -1, 1)) / -mu_angle) + 1.0
        pair_q = (
            0.35 * margin + 0.25 * np.clip(1.0 - off / max_dim, 0, 1) + 0.1 * (1.0 - dist / gripper.stroke_m)
        )
        return i1, i2, u, dist, c1, c2, label, off, pair_q, pos

    # The same quality from the matrices (rounding aside), to rank the loose pairs: the exact tests then run
    # on the best ones only, enough of them that every pair of the exact top `antipodal_pairs` is among them
    # (their approximate quality is within 1e-9 of the exact one, far above the rounding).
    flat = np.flatnonzero(np.triu(loose, k=1))  # row-major: the order of the pairs' ties
    fi, fj = np.divmod(flat, len(P))
    dist_f = np.maximum(dist_m.ravel()[flat], 1e-300)
    c1_f = -(NX[fi, fj] - nx[fi]) / dist_f
    c2_f = (nx[fj] - NX[fj, fi]) / dist_f
    W = com - P  # (com - p_i) . (p_j - p_i) = w_i . x_j - w_i . x_i
    WX = W @ X.T
    wx = np.einsum("ij,ij->i", W, X)
    ww = np.einsum("ij,ij->i", W, W)
    t_f = (WX[fi, fj] - wx[fi]) / dist_f
    off_f = np.sqrt(np.maximum(ww[fi] - t_f**2, 0.0))
    margin_f = np.arccos(np.clip(np.minimum(c1_f, c2_f), -1, 1)) / -mu_angle + 1.0
    q_f = (
        0.35 * margin_f
        + 0.25 * np.clip(1.0 - off_f / max_dim, 0, 1)
        + 0.1 * (1.0 - dist_f / gripper.stroke_m)
    )
    K = config.antipodal_pairs
    S = len(q_f)
    m = min(S, 4 * K)
    while True:
        # The m best by approximate quality (any order; ties at the m-th value may fall either way, which
        # the stopping test below allows for), back in row-major order.
        sub = np.sort(np.argpartition(-q_f, m - 1)[:m]) if m < S else np.arange(S)
        res = exact(fi[sub], fj[sub])
        if m == S:
            break
        if len(res[0]) >= K:
            # The K-th best exact survivor's approximate quality: nothing outside the m can beat it.
            kth = -np.partition(-q_f[sub][res[-1]], K - 1)[K - 1]
            if q_f[sub].min() < kth - 1e-9:
                break
        m = min(S, 2 * m)
    i1, i2, u, dist, c1, c2, label, off, pair_q, _ = res
    if len(i1) == 0:
        return Candidates.empty()
    keep = np.argsort(-pair_q, kind="stable")[:K]
    mid = 0.5 * (P[i1] + P[i2])
    up = support_up(support)
    y = u[keep]  # (K, 3) closing lines
    # The approach nearest top-down, normal to the closing line (any normal one when the line is vertical).
    a0 = -up[None, :] - (y @ -up)[:, None] * y
    small = np.linalg.norm(a0, axis=1) < 1e-6
    if np.any(small):
        helper = np.where(np.abs(y[small, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        a0[small] = cross(y[small], helper)
    a0 /= np.linalg.norm(a0, axis=1, keepdims=True)
    b0 = cross(y, a0)
    th = np.radians(np.asarray(config.antipodal_approaches_deg, dtype=np.float64))  # (M,)
    a = np.cos(th)[None, :, None] * a0[:, None, :] + np.sin(th)[None, :, None] * b0[:, None, :]  # (K, M, 3)
    K, M = a.shape[:2]
    flips = np.array([1.0, -1.0])
    yk = flips[None, None, :, None] * y[:, None, None, :]  # (K, 1, 2, 3)
    ak = np.broadcast_to(a[:, :, None, :], (K, M, 2, 3))
    yk = np.broadcast_to(yk, (K, M, 2, 3))
    R = np.stack([cross(yk, ak), yk, ak], axis=-1).reshape(-1, 3, 3)
    p = np.broadcast_to(mid[keep][:, None, None, :], (K, M, 2, 3)).reshape(-1, 3)
    top = 0.5 * (1.0 - a @ up)  # (K, M)
    q = (pair_q[keep][:, None] + 0.3 * top)[:, :, None].repeat(2, axis=2).reshape(-1)
    width = np.broadcast_to(dist[keep][:, None, None], (K, M, 2)).reshape(-1)
    contacts = np.stack([P[i1[keep]], P[i2[keep]]], axis=1)  # (K, 2, 3)
    contacts = np.broadcast_to(contacts[:, None, None], (K, M, 2, 2, 3)).reshape(-1, 2, 3)
    used = np.degrees(np.arccos(np.clip(np.minimum(c1[keep], c2[keep]), -1.0, 1.0)))
    cone_deg = math.degrees(math.atan(config.friction_coefficient))
    rots = tuple(config.antipodal_approaches_deg)
    opening = np.minimum(width + 2.0 * config.clearance_m, gripper.stroke_m)

    def antipodal_reason(row: int) -> str:
        k, rot = divmod(row // 2, M)  # rows: pair k x approach rot x flip
        idx = keep[k]
        return (
            f"antipodal ({target.family or 'mesh'} {label[idx]}): width {dist[idx] * 1e3:.0f} mm, "
            f"open to {opening[row] * 1e3:.0f} mm, friction-cone margin {used[k]:.0f} of {cone_deg:.0f} "
            f"deg used, approach {rots[rot]:+.0f} deg from top-down, {off[idx] * 1e3:.0f} mm from the centre "
            "of mass"
        )

    m = len(p)
    return Candidates(
        stack_transforms(R, p),
        opening,
        width.copy(),
        contacts.copy(),
        np.clip(q, 0.0, 1.0),
        np.full(m, "antipodal", dtype=object),
        Reasons.lazy(antipodal_reason, m),
        np.ones(m, dtype=bool),
        np.full(m, "", dtype=object),
    )


def _rim_ring(target: ObjectModel) -> tuple[np.ndarray, float, float] | None:
    """(centre (2,) in the object's x-z plane, outer radius, wall thickness) [m] of the rim: from the mesh's
    vertices in the top 3 mm (the rim's annulus: outer and inner edge); without a mesh from the box (the
    narrower of x and z across, a wall of 5 % of the radius). None when the mesh has no ring up there."""
    size = np.asarray(target.pose.size, dtype=np.float64)
    top = size[1] / 2.0
    if target.mesh is None:
        r = float(min(size[0], size[2])) / 2.0
        return np.zeros(2), r, max(0.05 * r, 0.002)
    V = (np.asarray(target.mesh.vertices, dtype=np.float64) - target.pose.t) @ target.pose.R
    ring = V[V[:, 1] >= top - _RIM_RING_BAND_M][:, [0, 2]]
    if len(ring) < 6:
        return None
    centre = (ring.max(axis=0) + ring.min(axis=0)) / 2.0
    rad = np.linalg.norm(ring - centre, axis=1)
    r_out = float(rad.max())
    wall = float(np.clip(r_out - rad.min(), 0.002, 0.3 * r_out))
    return centre, r_out, wall


def rim_grasps(
    target: ObjectModel, gripper: ParallelJawGeometry, config: GraspConfig, support: Plane | None = None
) -> Candidates:
    """Parallel-jaw grasps across the rim's wall of an open container standing upright (families with a
    "rim" region: bowl, cup, mug), placed analytically.

    The closing line is radial through the axis; the pads' centre sits on the wall's middle (its outer face
    from a slice of the mesh at that height: a cup's wall leans in) at half a pad plus `_RIM_DEPTHS_M` below
    the rim's top, so all or most of the pad overlaps the wall (a pad centred at the top edge closes above
    it when the estimate is a centimetre high); where the wall leans more than `_RIM_MAX_LEAN_DEG` over the
    pad, as a bowl's does 25 mm down, the grasp ranks lower (squeezed there the wall wedges out of the
    pads). Approached top-down or tilted `_RIM_TILTS_DEG` about the closing line, at `_RIM_ANGLES` angles
    around the rim. Two openings each: the wall plus the planner's clearance either side, and the wall plus
    `_RIM_WIDE_CLEARANCE_M` either side (the wall may stand that far from where the estimate puts it: the
    estimated centre and radius are a few centimetres off; the wide grasp is preferred). Empty for other
    families, a container lying down, or a mesh with no rim. Quality: 0.3 top-down, 0.2 (a radial line
    through the axis meets the wall head-on), 0.25 centring, 0.1 wide opening, 0.1 + 0.05 an upright wall
    over the pad (measured on mesh slices at the pad's ends).
    """
    if "rim" not in family_regions(target.family):
        return Candidates.empty()
    up = support_up(support)
    R, c, size = target.pose.R, target.pose.t, np.asarray(target.pose.size, dtype=np.float64)
    y_obj = R[:, 1]
    if float(y_obj @ up) < math.cos(math.radians(_RIM_UPRIGHT_DEG)):
        return Candidates.empty()
    ring = _rim_ring(target)
    if ring is None:
        return Candidates.empty()
    centre, r_out, wall = ring
    pad_l = gripper.pad_size_m[2]
    top = size[1] / 2.0
    phi = 2.0 * math.pi * np.arange(_RIM_ANGLES) / _RIM_ANGLES
    depths = np.minimum(pad_l / 2.0 + np.asarray(_RIM_DEPTHS_M), 0.6 * size[1])
    tilts = np.radians(np.asarray(_RIM_TILTS_DEG, dtype=np.float64))
    openings = np.minimum(
        [wall + 2.0 * config.clearance_m, wall + 2.0 * _RIM_WIDE_CLEARANCE_M], gripper.stroke_m
    )
    if wall + 2.0 * config.min_clearance_m > gripper.stroke_m:
        return Candidates.empty()

    # The wall's outer face at each angle and pad depth, from a slice of the mesh at that height (a cup's
    # wall leans in 4 mm over the top 25 mm; planned at the top ring's radius the first pad to touch pushes
    # the light cup over instead of squeezing it); the top ring's radius where the slice has no point.
    def wall_radius(depth: float) -> np.ndarray:
        """(angles,) the outer face's radius `depth` below the top (the top ring's where no slice point)."""
        out = np.full(len(phi), r_out)
        if target.mesh is None:
            return out
        import trimesh

        seg = trimesh.intersections.mesh_plane(target.mesh, y_obj, c + (top - depth) * y_obj)
        if len(seg) == 0:
            return out
        q2 = ((np.asarray(seg).reshape(-1, 3) - c) @ R)[:, [0, 2]] - centre
        ang = np.arctan2(q2[:, 1], q2[:, 0])
        rad = np.linalg.norm(q2, axis=1)
        for i, f in enumerate(phi):
            near = np.abs(np.angle(np.exp(1j * (ang - f)))) <= math.pi / _RIM_ANGLES
            if np.any(near):
                out[i] = float(rad[near].max())
        return out

    r_wall = np.stack([wall_radius(float(d)) for d in depths], axis=1)  # (angles, depths)
    # How far the wall leans over the pad's length: a bowl's wall 25 mm down leans ~18 deg, and squeezed
    # there it wedges out of the pads (the bowl tilts and sinks); near the rim it stands upright.
    lean = np.stack(
        [
            np.abs(
                wall_radius(min(float(d) + pad_l / 2.0, 0.95 * size[1]))
                - wall_radius(max(float(d) - pad_l / 2.0, 0.001))
            )
            / pad_l
            for d in depths
        ],
        axis=1,
    )
    # Rows: angle x depth x tilt x opening x flip.
    F, D, T, O = np.meshgrid(
        np.arange(len(phi)), np.arange(len(depths)), np.arange(len(tilts)), [0, 1], indexing="ij"
    )
    F, D, T, O = (x.ravel() for x in (F, D, T, O))
    radial_obj = np.stack([np.cos(phi[F]), np.zeros(len(F)), np.sin(phi[F])], axis=1)
    tangent_obj = np.stack([-np.sin(phi[F]), np.zeros(len(F)), np.cos(phi[F])], axis=1)
    p_obj = (
        np.array([centre[0], 0.0, centre[1]])
        + (r_wall[F, D] - wall / 2.0)[:, None] * radial_obj
        + (top - depths[D])[:, None] * np.array([0.0, 1.0, 0.0])
    )
    p = c + p_obj @ R.T
    y = radial_obj @ R.T
    a = np.cos(tilts[T])[:, None] * -y_obj + np.sin(tilts[T])[:, None] * (tangent_obj @ R.T)
    opening = openings[O]
    com = target.centre_of_mass
    d = com - p
    off = np.linalg.norm(d - np.sum(d * y, axis=1)[:, None] * y, axis=1)
    max_dim = float(np.max(size))
    q = (
        0.3 * 0.5 * (1.0 - a @ up)
        + 0.2
        + 0.25 * np.clip(1.0 - off / max_dim, 0.0, 1.0)
        + 0.1 * O
        + 0.1 * (lean[F, D] <= math.tan(math.radians(_RIM_MAX_LEAN_DEG)))
        + 0.05 * np.clip(1.0 - lean[F, D] / math.tan(math.radians(_RIM_MAX_LEAN_DEG)), 0.0, 1.0)
    )
    m = len(p)
    Rf = np.stack([tcp_frames(a, y), tcp_frames(a, -y)], axis=1).reshape(-1, 3, 3)
    rep = np.repeat(np.arange(m), 2)
    contacts = np.stack([p - y * wall / 2.0, p + y * wall / 2.0], axis=1)

    def rim_reason(row: int) -> str:
        r = row // 2
        return (
            f"rim ({target.family}): across the {wall * 1e3:.0f} mm wall at "
            f"{math.degrees(phi[F[r]]):.0f} deg around, "
            f"pads {depths[D[r]] * 1e3:.0f} mm below the top, open to {opening[r] * 1e3:.0f} mm, approach "
            f"{math.degrees(tilts[T[r]]):+.0f} deg from top-down"
        )

    return Candidates(
        stack_transforms(Rf, p[rep]),
        opening[rep],
        np.full(2 * m, wall),
        contacts[rep],
        np.clip(q[rep], 0.0, 1.0),
        np.full(2 * m, "rim", dtype=object),
        Reasons.lazy(rim_reason, 2 * m),
        np.ones(2 * m, dtype=bool),  # the fingers may meet the container elsewhere (a mug's handle)
        np.full(2 * m, "", dtype=object),
    )
