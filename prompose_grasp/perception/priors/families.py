"""Parametric shape families: one canonical *mean* shape per family, with the texts that name it.

Each family builds one typical instance in metres in its canonical frame (origin anywhere; the prior
normalises it), +y up, the front conventions of docs/conventions.md and docs/sim.md:

- NOCS categories (bottle, bowl, camera, can, laptop, mug): +y up; mug handle towards +x; laptop hinge line
  along x, keyboard towards +z, screen behind at -z; camera lens towards +z, hand grip at -x, viewfinder
  hump on top.
- Objects lying down (tube, sack, parcel, pallet): their length along x.

These are retrieval templates, not random instances: no noise, no lumps, no random parameters. Parts are
watertight one by one; where parts meet (mug handle and wall, laptop base and screen, pallet boards and
blocks) they overlap or touch, so a few surface samples fall on touching faces.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np
import trimesh

from prompose_grasp.perception.priors.superquadric import superquadric_mesh

__all__ = ["FAMILIES", "ShapeFamily"]

#: Segments around a body of revolution: 64 keeps the chord error below 0.12 % of the radius
#: (1 - cos(pi / 64)), invisible after sampling 5000 points.
_SECTIONS = 64


@dataclass(frozen=True)
class ShapeFamily:
    """A shape family of the prior library.

    Attributes:
        name: the family's name ("mug").
        descriptions: short texts a user might say for it (synonyms, common kinds); the prompt is matched
            against each and the best one counts.
        symmetry: one of `prior.SYMMETRIES` (for the mean shape).
        frame: one line describing the canonical frame (for the docs and error messages).
        build: () -> the mean shape as a `trimesh.Trimesh` in metres, +y up.
        articulations: (label, build) pairs of other poses of an articulated family's parts (a laptop's
            screen opened to other angles), same frame and conventions as `build`; empty for rigid families.
            The fit tries them as extra hypotheses (`priors.library.articulated_variants`).
        round_body_axis_m: (x, z) [m] in the frame of `build` of the vertical axis of a round main body
            whose only asymmetric part is a small protrusion towards +x (a mug's handle), or None. When
            the protrusion is not seen, the fit turns it behind the body (`priors.library.round_body_axis`).
        aspect_weight_factors: how firmly the family's proportions hold, as factors on the fit's aspect
            prior (`FitConfig.aspect_weight`, which decides the extents the observation leaves free) for the
            extent pairs (x:y, y:z, x:z). 1 for most families, whose instances vary in proportion (a wine
            bottle and a soda bottle); more where the function fixes a pair (a laptop's screen folds onto
            its base, so the base is as deep as the screen is tall: y:z).
    """

    name: str
    descriptions: tuple[str, ...]
    symmetry: str
    frame: str
    build: Callable[[], trimesh.Trimesh]
    articulations: tuple[tuple[str, Callable[[], trimesh.Trimesh]], ...] = ()
    round_body_axis_m: tuple[float, float] | None = None
    aspect_weight_factors: tuple[float, float, float] = (1.0, 1.0, 1.0)


#: Other screen openings of the laptop family [deg] (the mean shape is 110).
_LAPTOP_OPENINGS_DEG = (97.5, 122.5, 135.0)

#: The laptop's `ShapeFamily.aspect_weight_factors` for y:z (screen height : base depth). With the fit's
#: default aspect weight, a laptop seen from behind its screen came out with its base 10 cm short (dev 22
#: scene 33: the screen's points alone leave the base's depth free, and the screen's lean set it wrong).
_LAPTOP_YZ_ASPECT_WEIGHT_FACTOR = 10.0

# ------------------------------------------------------------------------------------------------------------
# Mesh helpers


def _lathe(profile_r_y: Sequence[tuple[float, float]], sections: int = _SECTIONS) -> trimesh.Trimesh:
    """Solid of revolution about +y of a (radius, height) polyline [m] that starts and ends on the axis."""
    line = np.asarray(profile_r_y, dtype=np.float64)
    solid = trimesh.creation.revolve(line, sections=sections)  # trimesh revolves about its z axis
    z_to_y = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, -1.0, 0, 0], [0, 0, 0, 1.0]])
    solid.apply_transform(z_to_y)
    if solid.volume < 0.0:  # the polyline's direction decides which way the faces point
        solid.invert()
    return solid


def _cuboid(extents: Sequence[float], centre: Sequence[float]) -> trimesh.Trimesh:
    T = np.eye(4)
    T[:3, 3] = centre
    return trimesh.creation.box(extents=np.asarray(extents, dtype=np.float64), transform=T)


def _join(parts: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    joined = trimesh.util.concatenate(list(parts))
    assert isinstance(joined, trimesh.Trimesh)  # concatenating triangle meshes gives a triangle mesh
    return joined


def _bent_tube(centreline: np.ndarray, radius: float, sides: int = 20) -> trimesh.Trimesh:
    """A closed round tube of `radius` [m] around a planar (N, 3) centreline lying in a plane z = const."""
    n = len(centreline)
    d = np.gradient(centreline, axis=0)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    ez = np.array([0.0, 0.0, 1.0])
    side = np.cross(d, ez)  # in-plane normal of the centreline
    ang = 2.0 * math.pi * np.arange(sides) / sides
    offsets = np.cos(ang)[None, :, None] * side[:, None, :] + np.sin(ang)[None, :, None] * ez[None, None, :]
    rings = centreline[:, None, :] + radius * offsets  # (n, sides, 3)
    verts = np.vstack([rings.reshape(-1, 3), centreline[[0, -1]]])
    first, last = n * sides, n * sides + 1
    faces = []
    for i in range(n - 1):
        for j in range(sides):
            a, b = i * sides + j, i * sides + (j + 1) % sides
            faces += [[a, b + sides, b], [a, a + sides, b + sides]]
    for j in range(sides):
        faces.append([first, j, (j + 1) % sides])
        faces.append([last, (n - 1) * sides + (j + 1) % sides, (n - 1) * sides + j])
    tube = trimesh.Trimesh(verts, np.asarray(faces), process=True)
    if tube.volume < 0.0:
        tube.invert()
    return tube


# ------------------------------------------------------------------------------------------------------------
# Mean shapes (metres)


def _box() -> trimesh.Trimesh:
    # A product box (cereal, crackers, tea): ~ 0.15 wide, 0.20 tall, 0.07 deep.
    return _cuboid([0.15, 0.20, 0.07], [0.0, 0.0, 0.0])


def _carton() -> trimesh.Trimesh:
    # A shipping carton: 0.40 x 0.30 x 0.30 m, the common mid-size corrugated box.
    return _cuboid([0.40, 0.30, 0.30], [0.0, 0.0, 0.0])


def _can() -> trimesh.Trimesh:
    # 330 ml drink can: diameter 66 mm, height 115 mm; necked top with a recessed lid, rounded bottom edge.
    r, h = 0.033, 0.115
    return _lathe(
        [
            (0.0, 0.0),
            (0.8 * r, 0.0),
            (r, 0.008),
            (r, h - 0.012),
            (0.82 * r, h - 0.002),
            (0.82 * r, h),
            (0.76 * r, h),
            (0.76 * r, h - 0.005),
            (0.0, h - 0.005),
        ]
    )


def _bottle() -> trimesh.Trimesh:
    # 0.5 l plastic bottle: body radius 34 mm, 0.23 m tall, rounded shoulder, neck, cap.
    r, h = 0.034, 0.23
    profile = [(0.0, 0.0), (0.93 * r, 0.0), (r, 0.006), (r, 0.58 * h)]
    neck_r, shoulder_top = 0.4 * r, 0.82 * h
    for s in np.linspace(0.1, 0.9, 9):  # shoulder: a quarter ellipse from the body to the neck
        ang = s * math.pi / 2.0
        profile.append(
            (neck_r + (r - neck_r) * math.cos(ang), 0.58 * h + (shoulder_top - 0.58 * h) * math.sin(ang))
        )
    cap_r = 0.46 * r
    profile += [
        (neck_r, shoulder_top),
        (neck_r, 0.9 * h),
        (cap_r, 0.9 * h),
        (cap_r, h),
        (0.0, h),
    ]
    return _lathe(profile)


def _bowl() -> trimesh.Trimesh:
    # Cereal bowl: rim radius 80 mm, 65 mm tall, 5 mm wall, foot ring radius 35 mm.
    R, h, t, foot = 0.08, 0.065, 0.005, 0.035
    outer = [
        (foot + (R - foot) * math.sin(s * math.pi / 2.0), h * (1.0 - math.cos(s * math.pi / 2.0)))
        for s in np.linspace(0.0, 1.0, 14)
    ]
    inner = [
        (
            (foot - t) + (R - t - (foot - t)) * math.sin(s * math.pi / 2.0),
            t + (h - t) * (1.0 - math.cos(s * math.pi / 2.0)),
        )
        for s in np.linspace(1.0, 0.0, 14)
    ]
    return _lathe([(0.0, 0.0), *outer, *inner, (0.0, t)])


def _cup() -> trimesh.Trimesh:
    # Paper / plastic cup: bottom radius 27 mm, top 40 mm, 95 mm tall, 2 mm wall, 4 mm base.
    rb, rt, h, t, tb = 0.027, 0.040, 0.095, 0.002, 0.004
    r_inner_base = rb + (rt - rb) * tb / h - t
    return _lathe([(0.0, 0.0), (rb, 0.0), (rt, h), (rt - t, h), (r_inner_base, tb), (0.0, tb)])


def _mug() -> trimesh.Trimesh:
    # Mug: radius 41 mm, 95 mm tall, 5 mm wall, a C handle of 8 mm tube on the +x side (NOCS convention).
    r, h, t = 0.041, 0.095, 0.005
    body = _lathe([(0.0, 0.0), (r, 0.0), (r, h), (r - t, h), (r - t, 0.008), (0.0, 0.008)])
    reach, half_height, rho = 0.03, 0.032, 0.0045
    phi = np.linspace(-math.pi / 2.0, math.pi / 2.0, 31)
    # The handle's ends sink 1 mm into the wall so the two watertight parts overlap instead of gapping.
    centreline = np.stack(
        [r - 0.001 + reach * np.cos(phi), 0.52 * h + half_height * np.sin(phi), np.zeros_like(phi)], axis=1
    )
    return _join([body, _bent_tube(centreline, rho)])


def _laptop(opening_deg: float = 110.0) -> trimesh.Trimesh:
    # 13-14" laptop opened to 110 degrees: 0.32 wide (x), base 0.22 deep (z) and 18 mm thick, screen 7 mm.
    w, d, tb, ts = 0.32, 0.22, 0.018, 0.007
    base = _cuboid([w, tb, d], [0.0, tb / 2.0, d / 2.0])  # hinge line at z = 0, keyboard towards +z
    screen = _cuboid([w, d, ts], [0.0, d / 2.0, -ts / 2.0])  # upright, standing on the hinge line
    lean = math.radians(opening_deg - 90.0)
    screen.apply_transform(trimesh.transformations.rotation_matrix(-lean, [1.0, 0.0, 0.0]))  # back, to -z
    screen.apply_translation([0.0, tb, 0.0])
    return _join([base, screen])


def _camera() -> trimesh.Trimesh:
    # Compact system camera: body 0.12 x 0.075 x 0.045, lens radius 30 mm protruding 45 mm along +z,
    # a hand grip bulging forward at -x, a viewfinder hump on top.
    w, h, d = 0.12, 0.075, 0.045
    body = _cuboid([w, h, d], [0.0, 0.0, 0.0])
    lens = trimesh.creation.cylinder(radius=0.03, height=0.045, sections=_SECTIONS)  # along z
    lens.apply_translation([0.012, -0.004, d / 2.0 + 0.0225 - 0.001])
    grip = _cuboid([0.026, 0.068, 0.018], [-w / 2.0 + 0.015, -0.002, d / 2.0 + 0.009 - 0.001])
    hump = _cuboid([0.04, 0.018, 0.032], [0.012, h / 2.0 + 0.009 - 0.001, -0.002])
    return _join([body, lens, grip, hump])


def _ball() -> trimesh.Trimesh:
    # Radius 60 mm: between a tennis ball (33 mm) and a football (110 mm).
    return trimesh.creation.icosphere(subdivisions=4, radius=0.06)


def _tube() -> trimesh.Trimesh:
    # Cardboard mailing tube lying down, axis along x: 0.50 long, outer radius 40 mm, 3 mm wall.
    tube = trimesh.creation.annulus(r_min=0.037, r_max=0.040, height=0.50, sections=_SECTIONS)  # axis z
    tube.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2.0, [0.0, 1.0, 0.0]))  # z -> x
    return tube


def _pallet() -> trimesh.Trimesh:
    # EUR / EPAL 1 pallet, 1200 (x) x 144 (y) x 800 (z) mm: 3 bottom boards along x (100/145/100 mm wide),
    # 9 blocks 78 mm high (145 mm along x), 3 stringer boards across z (145 mm wide), 5 top deck boards
    # along x (145/100/145/100/145 mm wide, evenly spread). Boards 22 mm thick.
    L, W, board, block_h = 1.2, 0.8, 0.022, 0.078
    block_x = (-L / 2.0 + 0.0725, 0.0, L / 2.0 - 0.0725)
    row_z = (-W / 2.0 + 0.05, 0.0, W / 2.0 - 0.05)
    row_w = (0.100, 0.145, 0.100)
    parts = []
    for z, wz in zip(row_z, row_w):
        parts.append(_cuboid([L, board, wz], [0.0, board / 2.0, z]))  # bottom boards
        for x in block_x:
            parts.append(_cuboid([0.145, block_h, wz], [x, board + block_h / 2.0, z]))  # blocks
    y_stringer = board + block_h + board / 2.0
    for x in block_x:
        parts.append(_cuboid([0.145, board, W], [x, y_stringer, 0.0]))  # stringer boards across
    deck_w = (0.145, 0.100, 0.145, 0.100, 0.145)
    gap = (W - sum(deck_w)) / 4.0
    z = -W / 2.0
    for wz in deck_w:
        parts.append(_cuboid([L, board, wz], [0.0, board + block_h + board + board / 2.0, z + wz / 2.0]))
        z += wz + gap
    return _join(parts)


def _sack() -> trimesh.Trimesh:
    # A filled 25 kg sack lying flat: 0.70 long (x), 0.45 wide (z), 0.15 thick; boxy in plan (e2 0.4),
    # rounded in section (e1 0.7).
    return superquadric_mesh([0.70, 0.15, 0.45], e1=0.7, e2=0.4)


def _parcel() -> trimesh.Trimesh:
    # A soft-wrapped parcel (padded mailer, polybag) lying flat: 0.35 x 0.12 x 0.25 m, a rounded box.
    return superquadric_mesh([0.35, 0.12, 0.25], e1=0.3, e2=0.3)


def _plate() -> trimesh.Trimesh:
    # Dinner plate: radius 0.13, 22 mm tall, 4 mm thick, flat well up to 0.085, then a sloped rim.
    R, h, t = 0.13, 0.022, 0.004
    return _lathe(
        [
            (0.0, 0.0),
            (0.075, 0.0),
            (0.08, 0.004),
            (R, h - t / 2.0),
            (R, h),
            (0.085, t + 0.003),
            (0.0, t + 0.003),
        ]
    )


def _jar() -> trimesh.Trimesh:
    # Glass jar with a screw lid: radius 45 mm, 0.12 m tall, lid radius 40 mm, 15 mm tall.
    r = 0.045
    return _lathe(
        [
            (0.0, 0.0),
            (0.94 * r, 0.0),
            (r, 0.004),
            (r, 0.088),
            (0.84 * r, 0.1),
            (0.84 * r, 0.104),
            (0.89 * r, 0.104),
            (0.89 * r, 0.12),
            (0.0, 0.12),
        ]
    )


def _crate() -> trimesh.Trimesh:
    # Euro stacking container, open top: 0.60 x 0.32 (tall) x 0.40 m, 4 mm walls, 6 mm floor.
    L, H, W, t, tf = 0.60, 0.32, 0.40, 0.004, 0.006
    return _join(
        [
            _cuboid([L, tf, W], [0.0, tf / 2.0, 0.0]),
            _cuboid([t, H, W], [-L / 2.0 + t / 2.0, H / 2.0, 0.0]),
            _cuboid([t, H, W], [L / 2.0 - t / 2.0, H / 2.0, 0.0]),
            _cuboid([L - 2 * t, H, t], [0.0, H / 2.0, -W / 2.0 + t / 2.0]),
            _cuboid([L - 2 * t, H, t], [0.0, H / 2.0, W / 2.0 - t / 2.0]),
        ]
    )


def _book() -> trimesh.Trimesh:
    # A hardcover book lying flat: 0.16 wide (x), 0.03 thick (y), 0.24 long (z).
    return _cuboid([0.16, 0.03, 0.24], [0.0, 0.0, 0.0])


# ------------------------------------------------------------------------------------------------------------

_FAMILY_LIST = (
    ShapeFamily(
        "box",
        ("box", "product box", "cereal box", "cracker box", "tea box", "pasta box"),
        "box",
        "standing product box, width x, height y, depth z",
        _box,
    ),
    ShapeFamily(
        "carton",
        (
            "carton",
            "cardboard carton",
            "cardboard box",
            "shipping box",
            "moving box",
            "corrugated box",
            "package",
        ),
        "box",
        "shipping carton, width x, height y, depth z",
        _carton,
    ),
    ShapeFamily(
        "can",
        ("can", "soda can", "tin can", "drink can", "beer can", "food can", "aluminium can", "can of soup"),
        "y_continuous",
        "NOCS: axis along +y",
        _can,
    ),
    ShapeFamily(
        "bottle",
        (
            "bottle",
            "water bottle",
            "plastic bottle",
            "glass bottle",
            "wine bottle",
            "sauce bottle",
            "detergent bottle",
        ),
        "y_continuous",
        "NOCS: axis along +y, cap up",
        _bottle,
    ),
    ShapeFamily(
        "bowl",
        ("bowl", "salad bowl", "soup bowl", "cereal bowl", "mixing bowl", "serving bowl"),
        "y_continuous",
        "NOCS: axis along +y, opening up",
        _bowl,
    ),
    ShapeFamily(
        "mug",
        ("mug", "coffee mug", "tea mug", "ceramic mug", "cup with a handle", "beer stein"),
        "none",
        "NOCS: axis along +y, opening up, handle towards +x",
        _mug,
        round_body_axis_m=(0.0, 0.0),  # the body is lathed about the y axis
    ),
    ShapeFamily(
        "cup",
        ("cup", "paper cup", "plastic cup", "disposable cup", "drinking glass", "tumbler", "beaker"),
        "y_continuous",
        "tapered, open top, axis along +y",
        _cup,
    ),
    ShapeFamily(
        "laptop",
        ("laptop", "laptop computer", "notebook computer", "open laptop", "portable computer"),
        "none",
        "NOCS: base normal +y, hinge line along x, keyboard towards +z, screen at -z",
        _laptop,
        # Screens are used opened from ~90 to ~135 degrees; 110 is the mean shape, these span the rest in
        # 12.5-degree steps (the screen top then lies within ~2.5 cm of one of them).
        tuple((f"opening {a:g} deg", partial(_laptop, a)) for a in _LAPTOP_OPENINGS_DEG),
        aspect_weight_factors=(1.0, _LAPTOP_YZ_ASPECT_WEIGHT_FACTOR, 1.0),
    ),
    ShapeFamily(
        "camera",
        ("camera", "digital camera", "photo camera", "DSLR camera", "compact camera", "video camera"),
        "none",
        "top plate +y, lens towards +z, hand grip at -x",
        _camera,
    ),
    ShapeFamily(
        "ball",
        ("ball", "tennis ball", "football", "soccer ball", "basketball", "sphere"),
        "spherical",
        "sphere",
        _ball,
    ),
    ShapeFamily(
        "tube",
        (
            "tube",
            "cardboard tube",
            "mailing tube",
            "poster tube",
            "pipe",
            "paper roll core",
            "cardboard roll",
        ),
        "x_continuous",
        "hollow tube lying down, axis along x",
        _tube,
    ),
    ShapeFamily(
        "pallet",
        ("pallet", "wooden pallet", "EUR pallet", "euro pallet", "shipping pallet", "skid"),
        "y_2fold",
        "EUR pallet, 1200 mm along x, deck up (+y), 800 mm along z",
        _pallet,
    ),
    ShapeFamily(
        "sack",
        (
            "sack",
            "bag of flour",
            "flour sack",
            "grain sack",
            "cement bag",
            "sandbag",
            "feed sack",
            "big bag of rice",
        ),
        "box",
        "filled sack lying flat, length along x",
        _sack,
    ),
    ShapeFamily(
        "parcel",
        ("parcel", "soft parcel", "padded envelope", "bubble mailer", "polybag mailer", "wrapped package"),
        "box",
        "soft-wrapped parcel lying flat, length along x",
        _parcel,
    ),
    ShapeFamily(
        "plate",
        ("plate", "dinner plate", "dish", "saucer", "platter"),
        "y_continuous",
        "axis along +y, eating side up",
        _plate,
    ),
    ShapeFamily(
        "jar",
        ("jar", "glass jar", "jam jar", "mason jar", "jar with a lid", "peanut butter jar"),
        "y_continuous",
        "axis along +y, lid up",
        _jar,
    ),
    ShapeFamily(
        "crate",
        ("crate", "plastic crate", "tote", "storage bin", "stacking container", "open box"),
        "y_2fold",
        "open-top container, length along x, opening up",
        _crate,
    ),
    ShapeFamily(
        "book",
        ("book", "hardcover book", "paperback", "textbook", "novel"),
        "box",
        "book lying flat, cover up (+y), spine along z",
        _book,
    ),
)

#: The library's families by name.
FAMILIES: dict[str, ShapeFamily] = {f.name: f for f in _FAMILY_LIST}
